"""What a reviewer asks of the comparison, computed in one place for reproduce_paper:
both torque readings and scoring windows with statistics (review), leave-one-movement-out
fits and bodies that are not scaled copies (heldout), the RK4 integration error per body
size (integration) and the moving-axis reference (moving_axis). Expensive parts live in
the FitCache.
"""

from __future__ import annotations

import numpy as np

from .axes import LINES, axis_angle_deg
from .comparison import Trials, filtered_torques, reference_filtered
from .errors import global_range, movement_errors, summarize
from .heldout import body_proportions, lomo
from .integration import rk4_trend
from .moving_axis import moving_axis_comparison
from .placement import VARIANTS, FitCache, Scorer
from .review import PRO_SUP, review, ulna_reference
from .statistics import clusters_of, paired

VERSION = 2  # part of the cache keys: bump when what is computed here changes
SIZES = (5, 50, 95)
SIZE_MODELS = ("solid", "paper", "parallel", "oblique")


def _review(ref, overrides: dict, cache: FitCache) -> dict:
    spec = {"what": "review", "version": VERSION, "overrides": overrides, "rate_hz": ref.rate_hz}

    def compute():
        trials = Trials.sample(ref.rate_hz)
        r = reference_filtered(ref, trials, 50)
        scorer = Scorer(r, trials, global_range(list(r)), 50)
        ulna, worst = ulna_reference(trials)
        out = review(scorer, overrides, ulna)
        out["axes"] = {"ulna_to_prosup_angle_deg": axis_angle_deg(),
                       "wrench_on_prosup_axis_minus_generalised_max_nm": worst,
                       "line": LINES[0], "other_lines": _other_lines(scorer, overrides, trials)}
        return out

    return cache.get_or_compute(spec, compute)


def _other_lines(scorer: Scorer, overrides: dict, trials: Trials) -> dict:
    """Reading 2 about the other ulna-parallel line: pro/sup NRMSE summary per model."""
    out = {}
    for line in LINES[1:]:
        ref, _ = ulna_reference(trials, through=line)
        rows = {}
        for n in ("solid", "paper", "parallel", "oblique"):
            e = movement_errors(list(filtered_torques(scorer.model(VARIANTS[n], **overrides.get(n, {})),
                                                      trials)), list(ref))
            rows[n] = summarize(e.nrmse[:, PRO_SUP])
        out[line] = rows
    return out


def body_size_trend(ref, overrides: dict, cache: FitCache, rate_hz: float = 200.0) -> dict:
    """Per-movement errors at p5 / p50 / p95 against the OpenSim reference, and paired p95 -
    p5 per DOF group (the paper: errors grow with size, most at the wrist and fingers in
    elbow-moving movements)."""
    spec = {"what": "body_size_trend", "version": VERSION, "overrides": overrides, "rate_hz": rate_hz}

    def compute():
        from ..description import DOF_GROUPS, JOINT_NAMES
        from ..movements import movement_library

        trials = Trials.sample(rate_hz)
        clusters = clusters_of(trials.movement_ids)
        moving = np.array([m.start[0] != m.stop[0] for m in movement_library()])
        idx = {n: i for i, n in enumerate(JOINT_NAMES)}
        errs = {}
        for s in SIZES:
            r = reference_filtered(ref, trials, s)
            sc = Scorer(r, trials, global_range(list(r)), s)
            for n in SIZE_MODELS:
                errs[(n, s)] = sc.errors(VARIANTS[n], **overrides.get(n, {}))
        out = {}
        for n in SIZE_MODELS:
            rows = {}
            for group, names in DOF_GROUPS.items():
                cols = [idx[x] for x in names]
                cl = np.repeat(clusters[:, None], len(cols), axis=1)
                row = {f"p{s}_mean": float(np.nanmean(errs[(n, s)].nrmse[:, cols])) for s in SIZES}
                for subset, mask in (("all", np.ones(65, bool)), ("elbow_moving", moving)):
                    a = errs[(n, 95)].nrmse[mask][:, cols].reshape(-1)
                    b = errs[(n, 5)].nrmse[mask][:, cols].reshape(-1)
                    row[f"p95_minus_p5_{subset}"] = paired(a, b, cl[mask].reshape(-1))
                rows[group] = row
            out[n] = rows
        return {"rate_hz": rate_hz, "models": out}

    return cache.get_or_compute(spec, compute)


def lomo_statistics(lo: dict) -> dict:
    """Held out vs the all-65 fit per variant, and the equal-freedom pairs held out (pro/sup
    NRMSE of the 65 held-out movements, clustered by hand movement)."""
    clusters = np.repeat(np.arange(1, 14), 5)
    held = {n: np.concatenate([f["held_out_errors"]["prosup_nrmse"] for f in v["folds"]]).astype(float)
            for n, v in lo["variants"].items()}
    full = {n: np.concatenate([f["all_65_fit_errors"]["prosup_nrmse"] for f in v["folds"]]).astype(float)
            for n, v in lo["variants"].items()}
    out = {"held_out_vs_all_65": {n: paired(held[n], full[n], clusters) for n in held}, "pairs": []}
    for a, b in (("parallel", "solid_parallel_axis"), ("oblique", "solid_fitted_axis")):
        if a in held and b in held:
            out["pairs"].append({"a": a, "b": b, **paired(held[a], held[b], clusters)})
    return out


def robustness(ref, overrides: dict, cache: FitCache, fit_rate_hz: float, tick=None) -> dict:
    """results.json sections: review, lomo, body_proportions, body_size_trend, rk4, moving_axis."""
    out = {"review": _review(ref, overrides, cache)}
    if tick:
        tick("review")
    trials = Trials.sample(fit_rate_hz)
    r = reference_filtered(ref, trials, 50)
    scorer = Scorer(r, trials, global_range(list(r)), 50)
    out["lomo"] = lomo(scorer, cache, fit_rate_hz, tick=(lambda: tick("leave one out")) if tick else None)
    out["lomo"]["statistics"] = lomo_statistics(out["lomo"])
    out["body_proportions"] = body_proportions(overrides, cache, 200.0,
                                               tick=(lambda: tick("bodies")) if tick else None)
    out["body_size_trend"] = body_size_trend(ref, overrides, cache)
    out["rk4"] = rk4_trend(cache, tick=(lambda: tick("RK4 round trips")) if tick else None)
    out["moving_axis"] = moving_axis_comparison(
        overrides, cache, fit_rate_hz, tick=(lambda: tick("moving-axis reference")) if tick else None)
    return out
