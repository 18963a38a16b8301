"""results.json and tables.md of the paper's comparison."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..description import DOF_GROUPS, JOINT_NAMES
from ..movements import movement_library
from .errors import ErrorSet, summarize
from .formatting import mm, nm, pc
from .placement import HEADLINE
from .review_report import REVIEW_TABLES, claims_table

_IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
METRICS = ("nrmse", "nrmse_all", "nrmse_global", "rmse")


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


def errors_json(errors: ErrorSet, movement_ids, per_movement: bool = True) -> dict:
    """Summaries per DOF group; per_movement adds every movement's values (4 significant
    digits: enough to plot, and results.json stays small enough to commit)."""
    out = {"excluded": dict(zip(JOINT_NAMES, errors.excluded.tolist(), strict=True)),
           "summary": group_summaries(errors)}
    if per_movement:
        lib = movement_library()
        out["movements"] = [{
            "id": mid, "name": lib[mid - 1].name, "elbow": lib[mid - 1].elbow,
            **{m: dict(zip(JOINT_NAMES, (float(f"{x:.4g}") for x in getattr(errors, m)[k]), strict=True))
               for m in ("nrmse", "nrmse_global", "rmse")},
        } for k, mid in enumerate(movement_ids)]
    return out


def write_json(path: Path, results: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(_clean(results), indent=1, sort_keys=False) + "\n", encoding="utf-8")
    tmp.replace(path)


def _s(results, name, size="p50", group="pro_sup", metric="nrmse"):
    return results["models"][name][size]["summary"][group][metric]


# -- generated tables (README blocks and tables.md) ------------------------------------------

def headline_table(r: dict) -> str:
    lines = [("| model | fitted parameters | pro/sup NRMSE mean | median | global "
              "| paper's metric, no floor (mean) "
             "| elbow RMSE (N·m) | wrist NRMSE mean |"),
             "|---|---|---|---|---|---|---|---|"]
    for name in HEADLINE:
        v = r["variants"][name]
        lines.append(
            f"| {v['label']} (`{name}`) | {v['fitted_parameters']} | {pc(_s(r, name)['mean'])} | "
            f"{pc(_s(r, name)['median'])} | {pc(_s(r, name, metric='nrmse_global')['mean'])} | "
            f"{pc(_s(r, name, metric='nrmse_all')['mean'])} | "
            f"{nm(_s(r, name, group='elbow', metric='rmse')['mean'])} | "
            f"{pc(_s(r, name, group='wrist')['mean'])} |")
    exc = r["models"]["solid"]["p50"]["excluded"]
    lines += ["", (f"NRMSE in %, 50th percentile, {r['rate_hz']:.0f} Hz, 65 movements. Per-movement NRMSE "
                   f"leaves out movements whose reference peak-to-peak is under "
                   f"{pc(r['ptp_floor_fraction'])} % of the DOF's range over all movements "
                   f"(pro/sup: {exc['pro_sup']} left out, elbow: {exc['elbow_flexion']}, wrist: "
                   f"{exc['wrist_flexion']} + {exc['wrist_deviation']}); global = RMSE / that range. "
                   f"Run: {r['machine']}, load average {r['load_average']['start'][0]:.1f} at the start, "
                   f"{r['wall_time_s']:.0f} s inside reproduce_paper (cache: {r['cache']['hits']} "
                   f"results reused, {r['cache']['misses']} computed).")]
    return "\n".join(lines)


def placements_table(r: dict) -> str:
    lines = [("| placement | split | split rule | axis offset at the elbow (mm, ant, lat) "
              "| at the wrist (mm) "
              "| axis to the cylinder's | axis to MoBL's pro/sup | fitted parameters |"),
             "|---|---|---|---|---|---|---|---|"]
    for name in ("paper", "parallel", "oblique"):
        v = r["variants"][name]
        p = v["placement"]
        default = " **(default)**" if name == r["default_placement"] else ""
        lines.append(f"| `{name}`{default} | {p['split']:.3f} | {p['split_rule']} | "
                     f"{mm(p['axis_offset_proximal'])} | {mm(p['axis_offset_distal'])} | "
                     f"{v['axis_angle_to_cylinder_deg']:.2f}° | {v['axis_angle_to_mobl_deg']:.2f}° | "
                     f"{v['fitted_parameters']} |")
    return "\n".join(lines)


def heldout_table(r: dict) -> str:
    v = r["validation"]
    lines = [("| fit on → scored on | placement | objective in-sample | objective held out | "
             "pro/sup NRMSE mean / median, in-sample | held out |"), "|---|---|---|---|---|---|"]

    def row_line(label: str, name: str, row: dict) -> str:
        i, h = row["in_sample"], row["held_out"]
        return (f"| {label} | `{name}` | {pc(i['objective'])} | {pc(h['objective'])} | "
                f"{pc(i['prosup_nrmse']['mean'])} / {pc(i['prosup_nrmse']['median'])} | "
                f"{pc(h['prosup_nrmse']['mean'])} / {pc(h['prosup_nrmse']['median'])} |")

    for split, rows in v["halves"].items():
        a, b = split.split("_to_")
        lines += [row_line(f"{a} → {b} ({len(row['scored_on'])} movements)", name, row)
                  for name, row in rows.items()]
    for size, rows in v["body_sizes"].items():
        lines += [row_line(f"p50 → {size} (65 movements)", name, row) for name, row in rows.items()]
    lines += ["", (f"%, {v['rate_hz']:.0f} Hz samples. Objective = pro/sup + elbow NRMSE, global "
                   "normalisation over all 65 movements. In-sample: the placement fitted on the "
                   "scored movements themselves (the best that placement family can do there); held out: "
                   "fitted on the other half (or at the 50th percentile).")]
    return "\n".join(lines)


SENS_MODELS = ("solid", "paper", "parallel", "oblique")


def sensitivity_table(r: dict) -> str:
    s = r["sensitivity"]
    head = " | ".join(f"`{n}` pro/sup mean / median" for n in SENS_MODELS)
    lines = [f"| case | {head} | `oblique` pro/sup global | elbow RMSE solid / mass-matched (N·m) |",
             "|---|" + "---|" * (len(SENS_MODELS) + 2)]
    for c in s["cases"]:
        n = c["numbers"]
        cells = [f"{pc(n[k]['prosup_mean'])} / {pc(n[k]['prosup_median'])}" for k in SENS_MODELS]
        lines.append(f"| {c['case']} | {' | '.join(cells)} | {pc(n['oblique']['prosup_global'])} | "
                     f"{nm(n['solid']['elbow_rmse'])} / {nm(n['solid_mass_matched']['elbow_rmse'])} |")
    for name in ("parallel", "oblique"):
        rows = [p["numbers"] for p in s["placement"] if p["variant"] == name]
        if not rows:
            continue

        def rng(key, rows=rows):
            vals = [x[key] for x in rows]
            return f"{pc(min(vals))}–{pc(max(vals))}"

        cells = ["" for _ in SENS_MODELS]
        cells[SENS_MODELS.index(name)] = f"{rng('prosup_mean')} / {rng('prosup_median')}"
        glob = rng("prosup_global") if name == "oblique" else ""
        lines.append(f"| `{name}` placement, each coordinate ±1 mm ({len(rows)} cases) | "
                     f"{' | '.join(cells)} | {glob} | |")
    lines += ["", (f"%, 50th percentile, {s['rate_hz']:.0f} Hz samples (the baseline row is at this rate "
                   "too). Cases that change the movements or the hand use anatomical torques from "
                   "Pinocchio's anatomical model (equal to the OpenSim reference to 1e-11 N·m); "
                   "placements as configured, not refitted.")]
    return "\n".join(lines)


def elbow_table(r: dict) -> str:
    e = r["elbow"]
    c = e["com"]
    d = e["static_difference_nm"]
    angles = list(d["solid"])
    lines = ["| model | " + " | ".join(f"Δτ elbow, gravity, {a.replace('elbow_', '')}° (N·m)"
                                       for a in angles) + " | elbow RMSE, 65 movements (N·m) |",
             "|---|" + "---|" * (len(angles) + 1)]
    rm = {"solid": "solid_uniform", "solid_mass_matched": "solid_mass_matched",
          "oblique": "oblique_uniform"}
    for name in ("solid", "solid_mass_matched", "paper", "oblique"):
        rmse = nm(e["rmse"][rm[name]]["elbow_rmse_mean"]) if name in rm else \
            nm(_s(r, name, group="elbow", metric="rmse")["mean"])
        cells = [f"{d[name][a]:+.3f}".replace("-0.000", "+0.000") for a in angles]
        lines.append(f"| `{name}` | " + " | ".join(cells) + f" | {rmse} |")
    lines.append(f"| `oblique`, mass-matched cylinder | – | – | – | "
                 f"{nm(e['rmse']['oblique_mass_matched']['elbow_rmse_mean'])} |")
    st = e["still_elbow_reference_ptp_nm"]
    lines += ["", (f"Δτ = model − anatomical at rest in the neutral posture. The uniform cylinder's COM is "
                   f"{c['uniform_com_along_mm']:.1f} mm from the elbow along its axis; the ulna + radius "
                   f"composite's is {c['composite_com_along_mm']:.1f} mm along it, "
                   f"{c['composite_com_anterior_mm']:.1f} mm anterior and "
                   f"{c['composite_com_lateral_mm']:.1f} mm "
                   f"lateral of it. Reference elbow peak-to-peak in the {st['n']} still-elbow movements: "
                   f"min {st['min']:.2g}, median {st['median']:.2g}, max {st['max']:.2g} N·m.")]
    return "\n".join(lines)


GENERATED = {"paper-placements": placements_table, "paper-headline": headline_table,
             "paper-claims": claims_table, "paper-heldout": heldout_table,
             "paper-sensitivity": sensitivity_table, "paper-elbow": elbow_table}
#: Every generated table: the README/docs blocks and tables.md sections.
ALL_TABLES = {**GENERATED, **REVIEW_TABLES}


def group_table(r: dict, size: str, metric: str) -> str:
    names = [n for n in HEADLINE if size in r["models"][n]]
    lines = ["| group | " + " | ".join(f"`{n}`" for n in names) + " |", "|---|" + "---|" * len(names)]
    for group in DOF_GROUPS:
        cells = []
        for n in names:
            s = _s(r, n, size=size, group=group, metric=metric)
            cells.append(nm(s["mean"]) if metric == "rmse" else f"{pc(s['mean'])} / {pc(s['median'])}")
        lines.append(f"| {group} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def tables_markdown(results: dict) -> str:
    r = results
    out = ["# forearm_dynamics: the paper's comparison, reproduced", "",
           (f"Machine: {r['machine']}; load average at start {r['load_average']['start'][0]:.1f}. "
           f"Command: `{r['command']}`; {r['wall_time_s']:.1f} s."), "",
           (f"Torques of every model low-pass filtered at {r['filter']['cutoff_hz']} Hz (zero-phase "
            f"Butterworth, order {r['filter']['order']} per pass), against the anatomical OpenSim reference. "
            f"Fits: {r['objective']}; {r['fit_rate_hz']:.0f} Hz samples."), ""]
    for key, fn in ALL_TABLES.items():
        out += [f"## {key.replace('paper-', '')}", "", fn(r), ""]
    for size in r["body_sizes"]:
        for metric, title in (("nrmse", "per-movement NRMSE, mean / median (%)"),
                              ("nrmse_global", "NRMSE global, mean / median (%)"),
                              ("rmse", "RMSE mean (N·m)")):
            out += [f"## {size}: {title}", "", group_table(r, size, metric), ""]
    return "\n".join(out)


def _block(key: str) -> tuple[str, str]:
    return f"<!-- generated:{key} (reproduce_paper --readme) -->", f"<!-- /generated:{key} -->"


def readme_blocks(results: dict) -> dict[str, str]:
    return {key: fn(results) for key, fn in ALL_TABLES.items()}


def update_readme(path: Path, results: dict) -> None:
    """Replace every generated block of the README with the tables of these results."""
    text = Path(path).read_text(encoding="utf-8")
    for key, body in readme_blocks(results).items():
        start, end = _block(key)
        a, b = text.find(start), text.find(end)
        if a < 0 or b < a:
            continue
        text = text[:a + len(start)] + "\n" + body + "\n" + text[b:]
    Path(path).write_text(text, encoding="utf-8")
