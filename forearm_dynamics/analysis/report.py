"""results.json and tables.md of the paper's comparison."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..description import DOF_GROUPS, JOINT_NAMES
from ..movements import movement_library
from .errors import ErrorSet, summarize

_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
METRICS = ("nrmse", "nrmse_global", "rmse")


def _clean(x):
    """JSON has no NaN: None where a value was left out."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    return x


def group_summaries(errors: ErrorSet) -> dict:
    out = {}
    for group, names in DOF_GROUPS.items():
        cols = [_IDX[n] for n in names]
        out[group] = {m: summarize(getattr(errors, m)[:, cols]) for m in METRICS}
    return out


def errors_json(errors: ErrorSet, movement_ids) -> dict:
    lib = movement_library()
    movements = []
    for k, mid in enumerate(movement_ids):
        mv = lib[mid - 1]
        movements.append({
            "id": mid, "name": mv.name, "elbow": mv.elbow,
            **{m: dict(zip(JOINT_NAMES, getattr(errors, m)[k], strict=True)) for m in METRICS},
        })
    return {"left_out": errors.left_out, "summary": group_summaries(errors), "movements": movements}


def write_json(path: Path, results: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(_clean(results), indent=1, sort_keys=False), encoding="utf-8")
    tmp.replace(path)


def _pct(s: dict) -> str:
    if not s["n"]:
        return "–"
    return f"{100 * s['mean']:.2f} [{100 * s['q1']:.2f}–{100 * s['q3']:.2f}] ≤{100 * s['max']:.1f}"


def tables_markdown(results: dict) -> str:
    models, sizes = results["models"], results["body_sizes"]
    lines = ["# forearm_dynamics: the paper's comparison, reproduced", "",
             f"Machine: {results['machine']}. Command: `{results['command']}`.", "",
             ("Errors of each simplified model against the anatomical OpenSim reference, torques "
             f"low-pass filtered at {results['filter']['cutoff_hz']} Hz (zero-phase Butterworth, "
             f"order {results['filter']['order']} per pass). Cells: mean [interquartile range] "
             "≤max over movements (and DOFs of the group), in %."), ""]
    for metric, title in (("nrmse", "NRMSE, normalised per movement (the paper's metric)"),
                          ("nrmse_global", ("NRMSE, normalised by the DOF's peak-to-peak over all "
                                           "65 movements"))):
        lines += [f"## {title}", "", "| body size | group | solid | segmented |", "|---|---|---|---|"]
        for size in sizes:
            for group in DOF_GROUPS:
                cells = [_pct(models[k][size]["summary"][group][metric]) for k in ("solid", "segmented")]
                lines.append(f"| {size} | {group} | {cells[0]} | {cells[1]} |")
        lines.append("")
    lines += ["## Absolute RMSE (N·m), 50th percentile", "",
              "| group | solid mean | solid max | segmented mean | segmented max |", "|---|---|---|---|---|"]
    for group in DOF_GROUPS:
        s = [models[k]["p50"]["summary"][group]["rmse"] for k in ("solid", "segmented")]
        lines.append(f"| {group} | {s[0]['mean']:.2e} | {s[0]['max']:.2e} | "
                     f"{s[1]['mean']:.2e} | {s[1]['max']:.2e} |")
    left = {f"{k} {s}": models[k][s]["left_out"] for k in models for s in sizes}
    lines += ["", (f"Per-movement NRMSE left out (reference peak-to-peak < "
              f"{results['ptp_floor_nm']} N·m): {left}"), ""]
    pl = results["placement"]
    lines += ["## Joint placement (50th percentile)", "", pl["objective"], "",
              ("| variant | split | axis offset proximal (mm) | axis offset distal (mm) | objective | "
              "pro/sup NRMSE mean (per movement) | elbow NRMSE mean (global) |"),
              "|---|---|---|---|---|---|---|"]
    for v in pl["variants"]:
        p = v["placement"]
        mm = [f"{1000 * a:.1f}, {1000 * b:.1f}" for a, b in (p["axis_offset_proximal"],
                                                            p["axis_offset_distal"])]
        lines.append(f"| {v['label']} | {p['split']:.3f} | {mm[0]} | {mm[1]} | "
                     f"{v['objective']:.4f} | {100 * v['prosup_nrmse_mean']:.2f} % | "
                     f"{100 * v['elbow_nrmse_global_mean']:.2f} % |")
    lines += ["", ("Does the 50th-percentile optimum hold at other sizes? (objective with the "
              "50th optimum vs re-optimised at that size)"), "",
              "| body size | objective at 50th optimum | re-optimised | re-optimised split |",
              "|---|---|---|---|"]
    for c in pl["body_size_check"]:
        lines.append(f"| {c['body_size']} | {c['objective_at_p50_optimum']:.4f} | "
                     f"{c['objective_reoptimised']:.4f} | {c['placement_reoptimised']['split']:.3f} |")
    return "\n".join(lines) + "\n"
