"""reproduce_paper: the three models at three body sizes against the OpenSim reference."""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

from .. import build_model, get_movement
from ..analysis.comparison import Trials, compare, reference_filtered
from ..analysis.filtering import analysis_config, lowpass
from ..analysis.placement import Placement, error_surface, objective, optimise
from ..analysis.report import errors_json, tables_markdown, write_json
from ..reference import load_reference
from .common import die

SIZES = (5, 50, 95)
KINDS = ("anatomical", "solid", "segmented")
FIG3_MOVEMENT = 3  # movement 1 (wrist pronation) at elbow 90 deg, as the paper's Fig. 3
OPT_RATE_HZ = 100.0  # the placement search samples at 100 Hz: same optimum as 250 Hz, 2.5x faster


class Progress:
    """A one-line progress bar on stderr."""

    def __init__(self, total: int, width: int = 30):
        self.total, self.done, self.width, self.t0 = total, 0, width, time.perf_counter()

    def step(self, label: str = "", n: int = 1) -> None:
        self.done = min(self.total, self.done + n)
        filled = int(self.width * self.done / self.total)
        sys.stderr.write(f"\r[{'#' * filled}{'.' * (self.width - filled)}] "
                         f"{100 * self.done / self.total:3.0f}% {time.perf_counter() - self.t0:5.1f}s "
                         f"{label:<34.34}")
        sys.stderr.flush()

    def close(self) -> None:
        sys.stderr.write("\n")


def machine() -> str:
    import os

    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def placement_study(ref, bar: Progress) -> tuple[dict, Placement]:
    trials = Trials.sample(OPT_RATE_HZ)
    r50 = reference_filtered(ref, trials, 50)
    tick = lambda: bar.step("placement search", 0)
    variants = []

    def add(label, placement, obj):
        m = build_model("segmented" if placement.split else "solid", **_ov(placement))
        e = compare(m, r50, trials)
        variants.append({"label": label, "placement": placement.as_dict(), "objective": obj,
                         "prosup_nrmse_mean": float(np.nanmean(e.nrmse[:, 1])),
                         "elbow_nrmse_global_mean": float(np.nanmean(e.nrmse_global[:, 0]))})
        bar.step(label)

    base = Placement()
    add("solid (paper: own axis)", base, objective(base, r50, trials))
    p, f, _ = optimise(r50, trials, ("split",), base, callback=tick)
    add("split alone (axis on centreline)", p, f)
    p, f, _ = optimise(r50, trials, ("proximal", "distal"), Placement(0.0, (0.0, 0.015), (-0.015, 0.0)),
                       callback=tick)
    add("placement alone (solid, axis moved)", p, f)
    start = Placement(0.6, (0.0, 0.015), (-0.015, 0.002))
    best, f, nfev = optimise(r50, trials, ("split", "proximal", "distal"), start, callback=tick)
    add("both (segmented optimum)", best, f)
    ablation = Placement(0.0, best.axis_offset_proximal, best.axis_offset_distal)
    add("ablation: solid with the optimum's axis", ablation, objective(ablation, r50, trials))
    splits = np.linspace(0.0, 1.0, 11)
    dant = best.axis_offset_distal[0] + np.linspace(-0.015, 0.015, 7)
    surface = error_surface(r50, trials, best, splits, dant, callback=lambda: bar.step("error surface", 0))
    bar.step("error surface")
    checks = []
    for size in (5, 95):
        rs = reference_filtered(ref, trials, size)
        re_p, re_f, _ = optimise(rs, trials, ("split", "proximal", "distal"), best, body_size=size,
                                 callback=tick)
        checks.append({"body_size": f"p{size}", "objective_at_p50_optimum": objective(best, rs, trials, size),
                       "objective_reoptimised": re_f, "placement_reoptimised": re_p.as_dict()})
        bar.step(f"optimum at p{size}")
    from ..analysis.placement import __doc__ as objective_doc

    study = {
        "objective": " ".join(objective_doc.split("\n\n")[1].split()),
        "rate_hz": OPT_RATE_HZ, "optimum": best.as_dict(), "optimum_evaluations": nfev,
        "variants": variants, "body_size_check": checks,
        "surface": {"splits": splits, "distal_anterior_offset_m": dant, "objective": surface},
    }
    return study, best


def _ov(p: Placement) -> dict:
    ov = p.overrides()
    if not p.split:
        ov.pop("split")
    return ov


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="reproduce_paper", description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("out/paper"), help="output folder")
    ap.add_argument("--no-placement", action="store_true", help="skip the joint placement search")
    args = ap.parse_args(argv)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / ".write_test").write_text("ok")
        (args.out / ".write_test").unlink()
    except OSError as exc:
        return die(f"reproduce_paper: cannot write to {args.out}: {exc.strerror or exc}")
    t0 = time.perf_counter()
    bar = Progress(total=len(SIZES) * len(KINDS) + (0 if args.no_placement else 8) + 4)
    ref = load_reference()
    trials = Trials.sample(ref.rate_hz)
    cfg = analysis_config()
    results = {
        "command": "reproduce_paper " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": machine(), "rate_hz": ref.rate_hz, "filter": cfg["filter"],
        "ptp_floor_nm": cfg["ptp_floor_nm"], "body_sizes": [f"p{s}" for s in SIZES],
        "reference": ref.meta, "models": {k: {} for k in KINDS},
    }
    nrmse = {k: {} for k in KINDS}
    for size in SIZES:
        r = reference_filtered(ref, trials, size)
        for kind in KINDS:
            e = compare(build_model(kind, body_size=size), r, trials)
            results["models"][kind][f"p{size}"] = errors_json(e, trials.movement_ids)
            nrmse[kind][f"p{size}"] = e.nrmse
            bar.step(f"{kind} p{size}")
    if not args.no_placement:
        results["placement"], _ = placement_study(ref, bar)
    results["placement_default"] = Placement(*_default_placement()).as_dict()
    _figures(args.out, results, nrmse, bar)
    results["wall_time_s"] = time.perf_counter() - t0
    write_json(args.out / "results.json", results)
    if "placement" in results:
        (args.out / "tables.md").write_text(tables_markdown(results), encoding="utf-8")
    bar.step("done")
    bar.close()
    print(f"wrote {args.out}/results.json, tables.md, fig3.png, fig4.png, fig5.png "
          f"in {results['wall_time_s']:.1f} s")
    return 0


def _default_placement():
    from ..description import load_description

    s = load_description().simplified
    return s.split, tuple(s.axis_offset_proximal), tuple(s.axis_offset_distal)


def _figures(out: Path, results: dict, nrmse: dict, bar: Progress) -> None:
    from ..analysis import plots

    mv = get_movement(FIG3_MOVEMENT)
    t = mv.sample_times(1000.0)
    q, qd, qdd = mv.evaluate(t)
    torques = {f"p{s}": {k: lowpass(build_model(k, body_size=s).inverse_dynamics(q, qd, qdd), 1000.0)
                         for k in KINDS} for s in SIZES}
    plots.figure3(out / "fig3.png", t, q, qd, torques,
                  f"Movement {mv.id}: {mv.name}, {mv.elbow} (filtered at 6 Hz)")
    bar.step("fig3")
    plots.error_figure(out / "fig4.png", {k: nrmse[k]["p50"] for k in ("solid", "segmented")},
                       "NRMSE against the anatomical model, 50th percentile (one dot per movement)")
    bar.step("fig4")
    plots.error_figure(out / "fig5.png", {s: nrmse["segmented"][s] for s in ("p5", "p50", "p95")},
                       "Segmented model NRMSE by body size")
    bar.step("fig5")
    if "placement" in results:
        s = results["placement"]["surface"]
        opt = results["placement"]["optimum"]
        plots.surface_figure(out / "placement_surface.png", np.asarray(s["splits"]),
                             np.asarray(s["distal_anterior_offset_m"]), np.asarray(s["objective"]),
                             (opt["split"], opt["axis_offset_distal"][0]))


if __name__ == "__main__":
    sys.exit(main())
