"""Every (muscle, joint) pair's surrogate error, from the fit file, as a block of
docs/muscles.md (`python -m forearm_dynamics.muscles.fit --docs`): one source for the
numbers the docs quote (the fit's own held-out records)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DOCS_BEGIN = "<!-- fit-pairs:begin (python -m forearm_dynamics.muscles.fit --docs) -->"
DOCS_END = "<!-- fit-pairs:end -->"


def pairs_markdown(doc: dict) -> str:
    """Every (muscle, joint) pair's errors from the fit file, as a markdown block: a summary
    over the full ranges and the movements' box, the worst pairs, and one row per muscle."""
    rows = [(m["fit"]["moment_arm_rms_mm"][j], m["fit"]["moment_arm_max_mm"][j],
             m["fit"]["movement_box_moment_arm_rms_mm"][j],
             m["fit"].get("sign_violations", {}).get(j, 0), m["name"], j)
            for m in doc["muscles"] for j in m["spans"]]
    full = np.array([r[0] for r in rows])
    box = np.array([r[2] for r in rows])
    worst = sorted(rows, reverse=True)
    n_terms = sum(len(m["surrogate"]["exponents"]) * (1 + len(m["spans"])) for m in doc["muscles"])
    f = doc["fit"]
    recorded = all("sign_violations" in m["fit"] for m in doc["muscles"])
    out = [
        (f"Fit: {f['samples']} uniform + {f.get('edge_samples', 0)} face/corner postures, "
        f"checked on {f['held_out']} held-out + {f.get('edge_held_out', 0)} face/corner "
        f"postures; {len(rows)} pairs, {n_terms} coefficients; seed {f['seed']}."),
        "",
        "| domain | pairs ≤ 1 mm RMS | median | p95 | worst |",
        "|---|---|---|---|---|",
        (f"| our joints' full ranges | {int((full <= 1.0).sum())} / {len(rows)} | "
        f"{np.median(full):.2f} mm | {np.percentile(full, 95):.2f} mm | "
        f"{worst[0][4]} {worst[0][5]} {worst[0][0]:.2f} |"),
    ]
    raw = [(m["fit"]["moment_arm_rms_unrepaired_mm"][j], m["name"], j)
           for m in doc["muscles"] if "moment_arm_rms_unrepaired_mm" in m["fit"]
           for j in m["spans"]]
    if raw:
        rv = np.array([r[0] for r in raw])
        rw = max(raw)
        out.append(f"| the same, against the raw source where the repair changed nothing | "
                   f"{int((rv <= 1.0).sum())} / {len(raw)} | {np.median(rv):.2f} mm | "
                   f"{np.percentile(rv, 95):.2f} mm | {rw[1]} {rw[2]} {rw[0]:.2f} |")
    bw = max(rows, key=lambda r: r[2])
    out.append(f"| the library's movements' box | {int((box <= 1.0).sum())} / {len(rows)} | "
               f"{np.median(box):.2f} mm | {np.percentile(box, 95):.2f} mm | "
               f"{bw[4]} {bw[5]} {bw[2]:.2f} |")
    out += ["", "Pairs above 1 mm RMS over the full ranges (RMS / max mm): " + (", ".join(
        f"{n} {j} {r:.2f} / {mx:.1f}" for r, mx, _, _, n, j in worst if r > 1.0) or "none") + ".",
        "Wrapping jumps past the source's own joint limits, repaired (wrap_repair.py; "
        "held-out uniform postures repaired, and the surrogate against the raw source there, "
        "RMS mm: the artefact's size): " + (", ".join(
            f"{m['name']} {m['fit']['repaired']['held_out']} of {f['held_out']} ("
            + ", ".join(f"{j} {v:.1f}" for j, v in
                        m["fit"]["moment_arm_rms_vs_artefact_mm"].items() if v >= 1.0) + ")"
            for m in doc["muscles"] if m["fit"].get("repaired", {}).get("held_out"))
            or "none") + ".",
        "Sign errors (held-out postures where |r| > 1 mm, or a one-signed pair, and the "
        "surrogate has the other sign): " + ((", ".join(
            f"{n} {j} {v}" for _, _, _, v, n, j in rows if v) or "none") if recorded
            else "not recorded in this file") + ".", "",
        ("<details><summary>Every pair: RMS / max over the full ranges, RMS in the movements' "
        "box (mm)</summary>"), "",
        ("Degree: the muscle's total degree; `joint: + a × b to D`: that pair's own basis adds "
         "every monomial of degree ≤ D in joints a, b (fit_core.refine_pairs)."), "",
        "| muscle | degree | pairs: joint full RMS / max, box RMS |", "|---|---|---|"]
    for m in doc["muscles"]:
        fit = m["fit"]
        cells = "; ".join(f"{j} {fit['moment_arm_rms_mm'][j]:.2f} / {fit['moment_arm_max_mm'][j]:.1f}, "
                          f"{fit['movement_box_moment_arm_rms_mm'][j]:.2f}" for j in m["spans"])
        own = "".join(f"; {j}: + {' × '.join(b['joints'])} to {b['degree']}"
                      for j, b in fit.get("pair_bases", {}).items())
        out.append(f"| {m['name']} | {fit['degree']}{own} | {cells} |")
    out += ["", "</details>"]
    return "\n".join(out)


def write_docs(doc: dict, path: Path) -> None:
    """Replace the block between DOCS_BEGIN and DOCS_END in path with pairs_markdown."""
    text = path.read_text(encoding="utf-8")
    a, b = text.index(DOCS_BEGIN) + len(DOCS_BEGIN), text.index(DOCS_END)
    path.write_text(text[:a] + "\n" + pairs_markdown(doc) + "\n" + text[b:], encoding="utf-8")
