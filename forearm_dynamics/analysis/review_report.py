"""Markdown tables of the robustness sections of results.json (torque axes, windows,
statistics, leave-one-movement-out, body proportions, body-size trend). Every number is
read from results.json; test_review.py checks tables.md and docs/paper.md against it."""

from __future__ import annotations

import math

from .formatting import nm, pc
from .placement import HEADLINE


def _ci(row: dict, key: str = "ci95_mean_difference") -> str:
    lo, hi = row[key]
    return f"[{pc(lo)}, {pc(hi)}]"


def _p(x) -> str:
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.2g}"


def _case(r: dict, reading: str, window: str) -> dict:
    return r["review"]["cases"][f"{reading}/{window}"]


def _ms(s: dict) -> str:
    return f"{pc(s['mean'])} / {pc(s['median'])}"


def axes_table(r: dict) -> str:
    rv = r["review"]
    other = rv["axes"]["other_lines"]["ulna_origin"]
    lines = [("| model | generalised force about MoBL's pro/sup axis (headline) | joint wrench on the "
             "ulna-parallel line through the radioulnar joint | same, line through the elbow centre |"),
             "|---|---|---|---|"]
    for n in HEADLINE:
        g = _case(r, "generalised", "whole")["summary"][n]["prosup_nrmse"]
        u = _case(r, "ulna_axis", "whole")["summary"][n]["prosup_nrmse"]
        o = other.get(n)
        lines.append(f"| `{n}` | {_ms(g)} | {_ms(u)} | {_ms(o) if o else '–'} |")
    ax = rv["axes"]
    lines += ["", (f"Pro/sup NRMSE mean / median (%), 50th percentile, whole window, 65 movements "
                   f"(floor as in the headline). The ulna's long axis (ulna frame y) is "
                   f"{ax['ulna_to_prosup_angle_deg']:.2f}° from MoBL's pro/sup axis; the wrench "
                   f"projected on the pro/sup axis equals the generalised force to "
                   f"{ax['wrench_on_prosup_axis_minus_generalised_max_nm']:.1e} N·m.")]
    return "\n".join(lines)


def stats_headline_table(r: dict) -> str:
    c = _case(r, r["review"]["headline"]["reading"], r["review"]["headline"]["window"])
    lines = [("| model | pro/sup NRMSE mean (%) | difference to `solid` (points) "
              "| 95 % CI (cluster bootstrap) | wins / N | Wilcoxon p "
              "| pro/sup NRMSE global, difference [CI] | wins / N |"),
             "|---|---|---|---|---|---|---|---|"]
    for n in HEADLINE:
        s = c["summary"][n]["prosup_nrmse"]
        if n == "solid":
            lines.append(f"| `{n}` | {pc(s['mean'])} | – | – | – | – | – | – |")
            continue
        a = c["vs_solid"]["prosup_nrmse"][n]
        g = c["vs_solid"]["prosup_nrmse_global"][n]
        lines.append(f"| `{n}` | {pc(s['mean'])} | {pc(a['mean_difference'])} | {_ci(a)} | "
                     f"{a['wins_a']} / {a['n']} | {_p(a['wilcoxon_p'])} | "
                     f"{pc(g['mean_difference'])} {_ci(g)} | {g['wins_a']} / {g['n']} |")
    lines += ["", ("Generalised reading, whole window. Difference = model − solid per movement "
                   "(negative: the model is closer to the anatomical torque); CI: 95 % percentile "
                   "bootstrap of the mean difference resampling the 13 hand movements (each with its 5 "
                   "elbow conditions), 4000 resamples, fixed seed; wins: movements where the model's "
                   "error is smaller; Wilcoxon: scipy.stats.wilcoxon, two-sided, paired movements "
                   "(treats them as independent, the bootstrap does not). Per-movement NRMSE leaves "
                   f"out {c['excluded_prosup']} movements under the floor; global NRMSE uses all 65.")]
    return "\n".join(lines)


def pairs_table(r: dict) -> str:
    rv = r["review"]
    lines = [("| comparison (A vs B) | reading | window | A mean / B mean (%) | A − B [95 % CI] | "
             "A wins / N | Wilcoxon p | verdict |"), "|---|---|---|---|---|---|---|---|"]
    for c in rv["cases"].values():
        for row in c["pairs"]["prosup_nrmse"]:
            lo, hi = row["ci95_mean_difference"]
            verdict = ("A better" if hi < 0 else "B better" if lo > 0 else "not resolved")
            lines.append(f"| `{row['a']}` vs `{row['b']}` | {c['reading']} | {c['window']} | "
                         f"{pc(row['mean_a'])} / {pc(row['mean_b'])} | {pc(row['mean_difference'])} "
                         f"{_ci(row)} | {row['wins_a']} / {row['n']} | {_p(row['wilcoxon_p'])} | "
                         f"{verdict} |")
    lines += ["", ("Pro/sup per-movement NRMSE. Verdict from the cluster-bootstrap CI of the mean "
                   "difference: \"A better\" when it lies below 0, \"B better\" above, otherwise not "
                   "resolved.")]
    return "\n".join(lines)


def windows_table(r: dict) -> str:
    lines = [("| model | whole (1.5 s) mean / median | transition (0.5 s) mean / median | "
             "ulna axis, whole | ulna axis, transition |"), "|---|---|---|---|---|"]
    for n in HEADLINE:
        cells = [_ms(_case(r, rd, w)["summary"][n]["prosup_nrmse"])
                 for rd, w in (("generalised", "whole"), ("generalised", "transition"),
                               ("ulna_axis", "whole"), ("ulna_axis", "transition"))]
        lines.append(f"| `{n}` | " + " | ".join(cells) + " |")
    rank = {k: " < ".join(f"`{n}`" for n in c["ranking"]["prosup_nrmse"])
            for k, c in r["review"]["cases"].items()}
    lines += ["", "Ranking by mean pro/sup NRMSE (best first):", ""]
    lines += [f"- {k}: {v}" for k, v in rank.items()]
    lines += ["", ("Pro/sup NRMSE (%), 50th percentile. The window picks the samples of the RMSE and of "
                   "the normalising peak-to-peak; the 6 Hz filter runs over the whole movement. The "
                   "headline is the generalised reading over the whole window.")]
    return "\n".join(lines)


def lomo_table(r: dict) -> str:
    lo = r["lomo"]
    st = lo["statistics"]
    lines = [("| placement | all-65 fit from neutral: objective | pro/sup NRMSE held out (13 folds) mean / "
             "median | same movements, all-65 fit | held out − all-65 [CI] | movements where held out is "
             "worse |"), "|---|---|---|---|---|---|"]
    for n, v in lo["variants"].items():
        d = st["held_out_vs_all_65"][n]
        lines.append(f"| `{n}` | {pc(v['all_65_fit_from_neutral']['objective'])} | "
                     f"{_ms(v['prosup_nrmse_held_out'])} | {_ms(v['prosup_nrmse_all_65_fit'])} | "
                     f"{pc(d['mean_difference'])} {_ci(d)} | {d['wins_b']} / {d['n']} movements |")
    for p in st["pairs"]:
        lines.append(f"| held out: `{p['a']}` − `{p['b']}` | | {pc(p['mean_a'])} vs {pc(p['mean_b'])} | | "
                     f"{pc(p['mean_difference'])} {_ci(p)} | `{p['a']}` better in {p['wins_a']} / "
                     f"{p['n']} (Wilcoxon p {_p(p['wilcoxon_p'])}) |")
    lines += ["", (f"%, {lo['rate_hz']:.0f} Hz samples. Fold k fits on every hand movement except k and "
                   "its mirror (1↔2, 3↔4, 5↔6, 7↔10, 8↔9, 11↔12; 13 alone) and scores k's 5 elbow "
                   f"conditions; every fit starts from {lo['start']}. The all-65 column scores the same "
                   "movements with the fit on all 65 (also from neutral).")]
    return "\n".join(lines)


def bodies_table(r: dict) -> str:
    import numpy as np

    models = ("solid", "paper", "parallel", "oblique")
    lines = ["| body | forearm / hand length / hand breadth / mass ratio to male p50 | "
             + " | ".join(f"`{m}` pro/sup mean / median" for m in models) + " |",
             "|---|---|" + "---|" * len(models)]
    for body, b in r["body_proportions"].items():
        rt = b["ratios"]
        cells = []
        for m in models:
            v = np.array([np.nan if x is None else x for x in b["models"][m]["prosup_nrmse"]], float)
            cells.append(f"{pc(float(np.nanmean(v)))} / {pc(float(np.nanmedian(v)))}")
        lines.append(f"| {body} | {rt['forearm']:.3f} / {rt['hand_length']:.3f} / {rt['hand_breadth']:.3f}"
                     f" / {rt['mass']:.3f} | " + " | ".join(cells) + " |")
    lines += ["", ("%, 200 Hz samples, shipped placements (fitted at the male 50th), not refitted. "
                   "Bodies combine ANSUR II 2012 men's 5th/95th percentiles of forearm length, hand "
                   "size and body mass in proportions similarity scaling never makes; women's sizes "
                   "from the same survey. Anatomical torques: Pinocchio's MoBL model of that body.")]
    return "\n".join(lines)


def trend_table(r: dict) -> str:
    t = r["body_size_trend"]
    lines = [("| model | DOF group | mean NRMSE p5 / p50 / p95 (%) | p95 − p5, elbow-moving movements "
             "[CI] | p95 worse / N |"), "|---|---|---|---|---|"]
    for n, rows in t["models"].items():
        if n == "paper":
            continue
        for g, row in rows.items():
            d = row["p95_minus_p5_elbow_moving"]
            lines.append(f"| `{n}` | {g} | {pc(row['p5_mean'])} / {pc(row['p50_mean'])} / "
                         f"{pc(row['p95_mean'])} | {pc(d['mean_difference'])} {_ci(d)} | "
                         f"{d['wins_b']} / {d['n']} |")
    lines += ["", (f"{t['rate_hz']:.0f} Hz samples, against the OpenSim reference at each size. Negative "
                   "p95 − p5: errors shrink with size.")]
    return "\n".join(lines)


def dof_table(r: dict) -> str:
    d = r["review"]["dof_groups"]
    lines = [("| model | DOFs with mean NRMSE < 5 % (of 20) | CI upper bound < 5 % | over 5 % | "
             "elbow mean [CI] | pro/sup mean [CI] |"), "|---|---|---|---|---|---|"]
    for n, v in d["per_dof"].items():
        el, ps = v["dofs"]["elbow_flexion"], v["dofs"]["pro_sup"]
        lines.append(f"| `{n}` | {v['mean_under_5pc']} | {v['ci_upper_under_5pc']} | "
                     f"{', '.join(v['over_5pc']) or '–'} | {pc(el['mean'])} {_ci(el, 'ci95_mean')} | "
                     f"{pc(ps['mean'])} {_ci(ps, 'ci95_mean')} |")
    lines += ["", ("Architecture effect per DOF group (solid − oblique, per-movement NRMSE, all DOFs of "
              "the group pooled, clustered by hand movement):"), "",
              "| DOF group | mean difference (points) [CI] | oblique better / N |", "|---|---|---|"]
    for g, row in d["architecture_effect"].items():
        lines.append(f"| {g} | {pc(row['mean_difference'])} {_ci(row)} | {row['wins_b']} / {row['n']} |")
    return "\n".join(lines)



def _summ(r, name, size="p50", group="pro_sup", metric="nrmse"):
    return r["models"][name][size]["summary"][group][metric]


def _pair(r, a, b, reading="generalised", window="whole", metric="prosup_nrmse") -> dict:
    c = _case(r, reading, window)
    return next(p for p in c["pairs"][metric] if p["a"] == a and p["b"] == b)


def _diff(p: dict) -> str:
    return (f"{pc(p['mean_a'])} vs {pc(p['mean_b'])} %, Δ {pc(p['mean_difference'])} "
            f"{_ci(p)}, {p['wins_a']}/{p['n']} wins, Wilcoxon p {_p(p['wilcoxon_p'])}")


def size_trend_grows(r: dict) -> bool:
    """Does any wrist/finger error of solid or oblique grow p5 -> p95 (CI above 0)?"""
    t = r["body_size_trend"]["models"]
    return any(t[n][g]["p95_minus_p5_elbow_moving"]["ci95_mean_difference"][0] > 0
               for n in ("solid", "oblique") for g in ("wrist", "fingers"))


def elbow_effect_small(r: dict) -> bool:
    """Is the architecture's effect on the elbow unresolved or smaller than on any hand group?"""
    eff = r["review"]["dof_groups"]["architecture_effect"]
    hand_min = min(eff[g]["mean_difference"] for g in ("wrist", "thumb", "fingers"))
    return eff["elbow"]["ci95_mean_difference"][0] < 0 or eff["elbow"]["mean_difference"] < hand_min


def claims_table(r: dict) -> str:
    """The paper's claims, what we find (with the statistics) and the evidence of each row."""
    el = r["elbow"]
    ob, pa, pl, so = "oblique", "paper", "parallel", "solid"
    d = r["review"]["dof_groups"]
    eff = d["architecture_effect"]
    sol = d["per_dof"][so]["dofs"]
    under15 = sum(1 for m in r["review"]["cases"]["generalised/whole"]["movements"][so]["prosup_nrmse"]
                  if m is not None and m < 0.15)
    n_ps = r["review"]["cases"]["generalised/whole"]["summary"][so]["prosup_nrmse"]["n"]
    tr = r["body_size_trend"]["models"]
    ranked = sorted(eff, key=lambda g: -eff[g]["mean_difference"])
    grow_word = "**Partly.**" if size_trend_grows(r) else "**No.**"
    paper_pair = _pair(r, pa, so)
    paper_wins = paper_pair["ci95_mean_difference"][1] < 0
    seg_word = "Yes, even with the paper's placement" if paper_wins else "**Not with the paper's placement**"
    elbow_over = all(d["per_dof"][n]["dofs"]["elbow_flexion"]["mean"] >= 0.05 for n in d["per_dof"])
    elbow_over_word = ("**The elbow is over 5 % in every model**" if elbow_over
                       else "The elbow is under 5 % in some models")
    solid_word = "**No: worse.**" if sol["pro_sup"]["mean"] > 0.15 else "Yes."
    split_word = "Yes." if paper_wins else "**No.**"
    elbow_word = "**The elbow: no**" if elbow_effect_small(r) else "The elbow: yes"
    u = lambda a, b: _pair(r, a, b, reading="ulna_axis")
    best_u = min(s["prosup_nrmse"]["mean"] for s in _case(r, "ulna_axis", "whole")["summary"].values())
    t = lambda a, b: _pair(r, a, b, window="transition")
    rows = [
        ("The segmented model beats the solid one at pro/sup",
         (f"{seg_word}: `paper` vs `solid` {_diff(paper_pair)}. "
          f"With the axis off the centreline and equal freedom, yes: `parallel` vs "
          f"`solid_parallel_axis` {_diff(_pair(r, pl, 'solid_parallel_axis'))}; `oblique` vs "
          f"`solid_fitted_axis` {_diff(_pair(r, ob, 'solid_fitted_axis'))}. Transition window: "
          f"{_diff(t(pl, 'solid_parallel_axis'))}; {_diff(t(ob, 'solid_fitted_axis'))}. Ulna-axis "
          f"reading: the best model's mean error is {pc(best_u)} % and `paper` vs `solid` is "
          f"{_diff(u(pa, so))}"),
         "statistics, pairs, axes, windows tables; fig4; leave-one-out table (held out)"),
        ("Mean errors < 5 % for most DOFs",
         (f"Holds for the hand only: DOFs with mean per-movement NRMSE < 5 %: solid "
          f"{d['per_dof'][so]['mean_under_5pc']}/20, `paper` {d['per_dof'][pa]['mean_under_5pc']}/20, "
          f"`oblique` {d['per_dof'][ob]['mean_under_5pc']}/20. {elbow_over_word}: "
          f"solid {pc(sol['elbow_flexion']['mean'])} % {_ci(sol['elbow_flexion'], 'ci95_mean')}, "
          f"`oblique` {pc(d['per_dof'][ob]['dofs']['elbow_flexion']['mean'])} %; so is pro/sup in "
          f"solid/`paper` ({pc(sol['pro_sup']['mean'])} %)"),
         "dofs table; group tables (p50); elbow table"),
        ("The solid model can be wrong by up to 15 %",
         (f"{solid_word} Solid pro/sup NRMSE is under 15 % in {under15} of {n_ps} movements; mean "
          f"{pc(sol['pro_sup']['mean'])} % {_ci(sol['pro_sup'], 'ci95_mean')}, median "
          f"{pc(_summ(r, so)['median'])} %, max {pc(_summ(r, so)['max'])} % (global "
          f"{pc(_summ(r, so, metric='nrmse_global')['mean'])} %)"),
         "dofs table; statistics table; fig4"),
        ("The split matching the radius's inertia gives the smallest errors",
         (f"{split_word} The rule gives split {r['variants'][pa]['placement']['split']:.3f} on the "
          f"centreline and there it changes nothing (`paper` vs `solid` {_diff(_pair(r, pa, so))}); the best "
          f"fitted split (oblique axis) is {r['variants'][ob]['placement']['split']:.3f}"),
         "placements table; pairs table"),
        ("Errors grow with body size (at the wrist and fingers, elbow moving): numerical integration",
         (f"{grow_word} Against OpenSim at each size, p95 − p5 in elbow-moving movements: `oblique` wrist "
          f"{pc(tr[ob]['wrist']['p95_minus_p5_elbow_moving']['mean_difference'])} "
          f"{_ci(tr[ob]['wrist']['p95_minus_p5_elbow_moving'])}, fingers "
          f"{pc(tr[ob]['fingers']['p95_minus_p5_elbow_moving']['mean_difference'])} "
          f"{_ci(tr[ob]['fingers']['p95_minus_p5_elbow_moving'])} points; solid wrist "
          f"{pc(tr[so]['wrist']['p95_minus_p5_elbow_moving']['mean_difference'])} "
          f"{_ci(tr[so]['wrist']['p95_minus_p5_elbow_moving'])}: flat or shrinking. "
          + _rk4_sentence(r)),
         "size-trend table" + ("; RK4 table" if "rk4" in r else "")),
        ("Forearm architecture affects pro/sup and the elbow most",
         (f"Pro/sup, yes: solid − `oblique` {pc(eff['pro_sup']['mean_difference'])} "
          f"{_ci(eff['pro_sup'])} points. {elbow_word} — "
          f"{pc(eff['elbow']['mean_difference'])} {_ci(eff['elbow'])} points (ranking of the effect: "
          f"{', '.join(ranked)}): its error is the uniform cylinder's COM, not the pro/sup joint "
          f"(elbow RMSE solid {nm(el['rmse']['solid_uniform']['elbow_rmse_mean'])} N·m, mass-matched "
          f"{nm(el['rmse']['solid_mass_matched']['elbow_rmse_mean'])}, `oblique` "
          f"{nm(el['rmse']['oblique_uniform']['elbow_rmse_mean'])}, mass-matched `oblique` "
          f"{nm(el['rmse']['oblique_mass_matched']['elbow_rmse_mean'])})"),
         "dofs table (architecture effect); elbow table"),
    ]
    lines = ["| the paper claims | we find | evidence |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines += ["", ("Generalised reading and whole window unless said; Δ = A − B in points of NRMSE "
                   "with its 95 % cluster-bootstrap CI, the wins of A and the paired Wilcoxon p.")]
    return "\n".join(lines)


def _rk4_sentence(r: dict) -> str:
    k = r.get("rk4")
    if not k:
        return "The integration error itself: not measured in this run."
    return k["summary_sentence"]


def rk4_table(r: dict) -> str:
    k = r["rk4"]
    lines = [("| model | DOF group | torque NRMSE from the RK4 drift, p5 / p50 / p95 (%) | max drift "
              "p5 / p50 / p95 (rad) | p95 − p5 [CI] | p95 worse / N |"), "|---|---|---|---|---|---|"]
    for n, rows in k["groups"].items():
        for g, row in rows.items():
            d = row["p95_minus_p5_torque_nrmse"]
            nr = " / ".join(f"{100 * row[f'p{s}_torque_nrmse_mean']:.2g}" for s in (5, 50, 95))
            dr = " / ".join(f"{row[f'p{s}_drift_max_rad']:.1e}" for s in (5, 50, 95))
            lo, hi = (100 * x for x in d["ci95_mean_difference"])
            lines.append(f"| `{n}` | {g} | {nr} | {dr} | {100 * d['mean_difference']:.2g} "
                         f"[{lo:.2g}, {hi:.2g}] | {d['wins_b']} / {d['n']} |")
    lines += ["", (f"RK4, dt = {1000 * k['dt']:g} ms, forearm_dynamics.simulation.simulate, driven by "
                   "each model's own inverse-dynamics torques (evaluated at every stage), no damping or "
                   f"limits, {len(k['movements'])} movements (elbow moving, and elbow at 90°). Torque "
                   "NRMSE = RMSE of "
                   "ID(drifted state) − ID(movement) / the movement's torque peak-to-peak. "
                   + k["summary_sentence"])]
    return "\n".join(lines)


def moving_axis_table(r: dict) -> str:
    m = r["moving_axis"]
    lines = [("| model | pro/sup NRMSE mean / median vs MoBL (fixed axis) | vs the moving-axis "
              "reference | global, moving axis |"), "|---|---|---|---|"]
    fixed = _case(r, "generalised", "whole")["summary"]
    for n, row in m["models"].items():
        lines.append(f"| `{n}` | {_ms(fixed[n]['prosup_nrmse'])} | {_ms(row['prosup_nrmse'])} | "
                     f"{pc(row['prosup_nrmse_global']['mean'])} |")
    for n, row in m["refit"].items():
        lines.append(f"| `{n}` refitted to the moving-axis reference | | {_ms(row['prosup_nrmse'])} | |")
    lines += ["", "| comparison (A vs B) | A − B [95 % CI] | A wins / N | Wilcoxon p |", "|---|---|---|---|"]
    for p in m["pairs"]:
        lines.append(f"| `{p['a']}` vs `{p['b']}` | {pc(p['mean_difference'])} {_ci(p)} | "
                     f"{p['wins_a']} / {p['n']} | {_p(p['wilcoxon_p'])} |")
    lines += ["", (f"%, {m['rate_hz']:.0f} Hz samples, 50th percentile. The reference: MoBL with its "
                   f"radioulnar CustomJoint's axis tilting {m['tilt_total_deg']:g}° and translating "
                   f"{m['translation_total_mm']:g} mm along the ulna over the pro/sup range (OpenSim "
                   f"LinearFunctions of pro_sup). Tilt: {m['sources']['tilt']}. Translation: "
                   f"{m['sources']['translation']}.")]
    return "\n".join(lines)


def _optional(key: str, fn):
    return lambda r: fn(r) if key in r else "not computed in this run"


REVIEW_TABLES = {"paper-axes": axes_table, "paper-statistics": stats_headline_table,
                 "paper-pairs": pairs_table, "paper-windows": windows_table,
                 "paper-lomo": lomo_table, "paper-bodies": bodies_table,
                 "paper-size-trend": trend_table, "paper-dofs": dof_table,
                 "paper-rk4": _optional("rk4", rk4_table),
                 "paper-moving-axis": _optional("moving_axis", moving_axis_table)}
