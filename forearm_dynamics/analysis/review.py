"""The comparison under both torque readings and both scoring windows, with statistics.

Readings (analysis.axes): the generalised pro/sup force (headline) and the joint wrench on
the ulna's long axis. Windows: "whole" (1.5 s: 0.5 s holds either side of the movement,
the headline) and "transition" (the 0.5 s the paper's movements last). The filter always
runs over the whole movement (its edges need the holds); the window only picks the samples
an RMSE and a peak-to-peak are taken over, and the normalising ranges come from the same
window. Every model keeps the placement fitted under the headline reading and window.
"""

from __future__ import annotations

import numpy as np

from ..description import DOF_GROUPS, JOINT_NAMES
from ..filtering import lowpass
from ..movements import movement_library
from .axes import READINGS, ulna_axis_torques
from .comparison import Trials, filtered_torques
from .errors import ErrorSet, global_range, movement_errors, summarize
from .placement import HEADLINE, VARIANTS, Scorer
from .statistics import cluster_bootstrap_mean, clusters_of, one_sample, paired

WINDOWS = ("whole", "transition")
HEADLINE_READING, HEADLINE_WINDOW = "generalised", "whole"
#: (A, B, why): the comparisons every table row rests on. A - B < 0: A better.
PAIRS = (
    ("paper", "solid", "the paper's claim, literally (0 vs 0 fitted)"),
    ("parallel", "solid_parallel_axis", "equal freedom: 2 vs 2 fitted"),
    ("oblique", "solid_fitted_axis", "near-equal freedom: 5 vs 4 fitted"),
    ("oblique", "solid", "the extension against the paper's solid model"),
    ("solid_mass_matched", "solid", "the mass-matched cylinder against the uniform one"),
)
_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
PRO_SUP, ELBOW = _IDX["pro_sup"], _IDX["elbow_flexion"]


def window_samples(name: str, rate_hz: float) -> slice:
    if name == "whole":
        return slice(None)
    if name != "transition":
        raise ValueError(f"window must be one of {WINDOWS}, got {name!r}")
    m = movement_library()[0]
    a = round(m.hold_before * rate_hz)
    return slice(a, a + round(m.transition * rate_hz) + 1)


def ulna_reference(trials: Trials, body_size=50, through: str = "radioulnar_origin"
                   ) -> tuple[np.ndarray, float]:
    """(M, N, 20) filtered anatomical torques, pro/sup = joint wrench on the ulna axis."""
    parts, worst = [], 0.0
    for q, qd, qdd in zip(trials.split(trials.q), trials.split(trials.qd), trials.split(trials.qdd),
                          strict=True):
        t, w = ulna_axis_torques(q, qd, qdd, body_size, through=through)
        parts.append(t)
        worst = max(worst, w)
    return lowpass(np.stack(parts), trials.rate_hz, axis=1), worst


def windowed_errors(test: np.ndarray, ref: np.ndarray, window: slice) -> ErrorSet:
    t, r = test[:, window], ref[:, window]
    return movement_errors(list(t), list(r), global_ptp=global_range(list(r)))


def _per_movement(e: ErrorSet) -> dict:
    return {"prosup_nrmse": e.nrmse[:, PRO_SUP], "prosup_nrmse_global": e.nrmse_global[:, PRO_SUP],
            "elbow_nrmse": e.nrmse[:, ELBOW], "elbow_nrmse_global": e.nrmse_global[:, ELBOW],
            "elbow_rmse": e.rmse[:, ELBOW]}


METRICS = ("prosup_nrmse", "prosup_nrmse_global", "elbow_nrmse_global")


def review(scorer: Scorer, overrides: dict, ulna_ref: np.ndarray, tests: dict | None = None) -> dict:
    """Errors, rankings and paired statistics for every reading x window.

    scorer: the 50th-percentile scorer at the reference rate (its reference = generalised).
    tests: name -> (M, N, 20) filtered model torques (computed here when None).
    """
    trials = scorer.trials
    clusters = clusters_of(trials.movement_ids)
    tests = tests or {n: filtered_torques(scorer.model(VARIANTS[n], **overrides.get(n, {})), trials)
                      for n in HEADLINE}
    refs = {"generalised": scorer.reference, "ulna_axis": ulna_ref}
    out = {"readings": list(READINGS), "windows": list(WINDOWS),
           "headline": {"reading": HEADLINE_READING, "window": HEADLINE_WINDOW},
           "pairs": [{"a": a, "b": b, "why": why} for a, b, why in PAIRS], "cases": {}}
    errors = {}
    for reading in READINGS:
        for window in WINDOWS:
            w = window_samples(window, trials.rate_hz)
            es = {n: windowed_errors(tests[n], refs[reading], w) for n in HEADLINE}
            errors[(reading, window)] = es
            per = {n: _per_movement(e) for n, e in es.items()}
            summary = {n: {k: {**summarize(v), "ci95_mean": list(cluster_bootstrap_mean(v, clusters))}
                           for k, v in p.items()} for n, p in per.items()}
            ranking = {k: sorted(HEADLINE, key=lambda n, k=k: summary[n][k]["mean"]) for k in METRICS}
            stats = {k: [{"a": a, "b": b, **paired(per[a][k], per[b][k], clusters)}
                         for a, b, _ in PAIRS] for k in METRICS}
            vs_solid = {k: {n: paired(per[n][k], per["solid"][k], clusters)
                            for n in HEADLINE if n != "solid"} for k in METRICS}
            out["cases"][f"{reading}/{window}"] = {
                "reading": reading, "window": window,
                "samples": int(tests["solid"][:, w].shape[1]),
                "excluded_prosup": int(es["solid"].excluded[PRO_SUP]),
                "summary": summary, "ranking": ranking, "pairs": stats, "vs_solid": vs_solid,
                "movements": {n: {k: np.round(v, 6).tolist() for k, v in per[n].items()}
                              for n in ("solid", "paper", "parallel", "oblique")},
            }
    out["dof_groups"] = dof_group_claims(errors[(HEADLINE_READING, HEADLINE_WINDOW)], clusters)
    return out


def dof_group_claims(es: dict[str, ErrorSet], clusters) -> dict:
    """'Mean errors < 5 % for most DOFs': per DOF, mean per-movement NRMSE with its cluster CI,
    per model; and the architecture effect per DOF group (solid - oblique, paired)."""
    out = {"per_dof": {}, "architecture_effect": {}}
    for n in ("solid", "paper", "parallel", "oblique"):
        rows = {}
        for j, joint in enumerate(JOINT_NAMES):
            rows[joint] = one_sample(es[n].nrmse[:, j], clusters, threshold=0.05)
        under = [j for j, r in rows.items() if r["mean"] is not None and r["mean"] < 0.05]
        out["per_dof"][n] = {"dofs": rows, "mean_under_5pc": len(under),
                             "ci_upper_under_5pc": sum(1 for r in rows.values()
                                                       if r["ci95_mean"][1] < 0.05),
                             "over_5pc": [j for j in JOINT_NAMES if j not in under]}
    for group, names in DOF_GROUPS.items():
        cols = [_IDX[x] for x in names]
        a = es["solid"].nrmse[:, cols]
        b = es["oblique"].nrmse[:, cols]
        cl = np.repeat(clusters[:, None], len(cols), axis=1)
        out["architecture_effect"][group] = paired(a.reshape(-1), b.reshape(-1), cl.reshape(-1))
    return out
