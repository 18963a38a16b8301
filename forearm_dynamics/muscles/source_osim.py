"""Rebuild the muscle surrogates from a user's own OpenSim model (.osim), e.g. MoBL-ARMS.

    pip install -e '.[reference]'             # OpenSim 4.6 (the optional extra)
    python -m forearm_dynamics.muscles.source_osim MODEL.osim -o my_muscles.json
    ros2 run forearm_dynamics muscle_node --ros-args -p muscle_model:=my_muscles.json

Why: the shipped file is derived from MyoArm (Apache-2.0), the only source our BSD-3
package may carry; a user who holds another model (MoBL-ARMS is non-commercial) may build
the same file (format forearm_dynamics.muscles/1) from it on their own machine. Nothing
derived from their model is shipped; the file says where it came from (path, SHA-256) and
that its licence is the one their model states.

What it does (`osim_source.OsimSource`, then fit.build with a smaller posture budget):

1. Loads the model with the `opensim` Python API (lazy: without it, one line and exit 2).
2. Maps its coordinates onto our joints with config/opensim_coordinates.yaml (the map
   mot_to_bag uses for .mot files; coordinate_map.CoordinateMap, --map for a file of the
   user's): our angle = sign × theirs + offset, so a moment arm about our joint is sign ×
   theirs. The mapped coordinates are unlocked and unclamped (MoBL locks its wrist by
   default; we sample our joints' full ranges, which may pass the source's). Every other
   independent coordinate is held: at 0 where 0 is inside its range (arm at the side, as
   the shipped MyoArm fit), else at its default; locked ones at their default. Dependent
   coordinates (CoordinateCouplerConstraints: MoBL's proximal carpal row) follow through
   `Model.assemble` at each posture. All are listed in the file's provenance.
3. Per posture: each muscle's muscle-tendon length (`getLength`) and, per mapped coordinate
   it crosses, the source's own moment arm `Muscle.computeMomentArm(state, coordinate)`:
   not −dL/dq, which on MoBL's coupled wrist differs by up to 6 mm, and which jumps where
   MoBL's wrapping makes the length jump (computeMomentArm stays smooth there). A muscle
   crosses a coordinate where its moment arm exceeds SPAN_MIN_M at any of SPAN_POSTURES
   postures; a muscle crossing none of ours (shoulder-only) is dropped and listed.
4. Parameters as the file states them: max isometric force, optimal fibre length, tendon
   slack length, pennation at optimal; one absent from the file, not finite or out of range
   is refused naming the muscle and the parameter. Max contraction velocity: the file's,
   or DEFAULT_VMAX (10 optimal lengths/s, OpenSim's DeGrooteFregly2016Muscle default) where
   it is 0 or absent (MoBL-ARMS: 0 in 48 muscles); the muscles replaced are listed.
5. The fit's box: our joints' ranges cut to the model's own coordinate ranges (mapped to
   ours; `--box ours`: the full ranges): past them a model's geometry is untested (MoBL's
   FCU wrapping fails past 70° of wrist flexion; ours reaches 80°); the surrogate holds its
   edge value outside its box (surrogate.py).
6. fit.build fits the same polynomials with the same sign rules, jump detection and
   held-out errors as the shipped file (FitSizes: fewer postures, since computeMomentArm
   costs ~1 ms a pair: MoBL-ARMS' 98 pairs 70-140 ms a posture on 2 cores at load 3-8).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..coordinate_map import CoordinateMap
from ..description import JOINT_NAMES
from ..errors import ForearmDynamicsError, exit_code_of
from .fit import SIGN_CHECKS, FitSizes, build, joint_box
from .osim_source import DEFAULT_VMAX, OsimSource, sha256  # noqa: F401 (the module's API)

OSIM_SIZES = FitSizes(n_fit=1500, n_test=375, n_edge_base=15, jump_bases=1, n_envelope=300)


def action_checks(src: OsimSource) -> tuple[list[str], list[str]]:
    """fit.SIGN_CHECKS (anatomical actions: PT pronates, ECU deviates ulnarly ...) for the
    muscles of the model that carry those names (MoBL-ARMS: 10), at the middle of our
    ranges: (as expected, not as expected) as 'muscle joint +x.xx mm' lines. A check of
    the mapping's signs, reported, not enforced: a user's model may name muscles otherwise."""
    lo, hi = joint_box()
    _, R = src.evaluate(0.5 * (lo + hi)[None])
    good, bad = [], []
    for muscle, joint, sgn in SIGN_CHECKS:
        if muscle in src.names and any(mp.joint == joint for mp in src.mapped):
            r = R[0, src.names.index(muscle), JOINT_NAMES.index(joint)]
            (good if np.sign(r) == sgn else bad).append(f"{muscle} {joint} {r * 1e3:+.2f} mm")
    return good, bad


def build_osim(model: str | Path, out: str | Path, *, side: str = "right",
               cmap: CoordinateMap | None = None, seed: int = 0, sizes: FitSizes = OSIM_SIZES,
               progress=print, exclude: tuple[str, ...] = (),
               source_box: bool = True) -> tuple[dict, OsimSource]:
    """Fit the surrogates of `model`'s muscles; write the muscle model file `out`.
    source_box: fit inside the model's own coordinate ranges (False: our joints' full
    ranges, the model's geometry past its ranges included)."""
    src = OsimSource(model, side, cmap, progress, exclude)
    if not source_box:
        src.box = joint_box()
    src.box_rule = ("our joints' ranges cut to the model's coordinate ranges (mapped); the "
                    "surrogate holds its edge value outside" if source_box
                    else "our joints' full ranges (--box ours)")
    if progress:
        progress(f"{src.path}: {len(src.names)} muscles at our joints "
                 f"({sum(map(len, src._pairs))} pairs), dropped (cross none of ours): "
                 f"{', '.join(src.dropped) or 'none'}", flush=True)
        progress(src.unmapped_line, flush=True)
        good, bad = action_checks(src)
        progress(f"anatomical actions (mid-range): {len(good)} as expected ({', '.join(good)})"
                 + (f"; NOT as expected, check the map's signs: {', '.join(bad)}" if bad else ""),
                 flush=True)
    doc = build(Path(out), seed, None, src=src, source=src.source(), sizes=sizes, box=src.box)
    return doc, src


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path, help="the OpenSim model (.osim)")
    ap.add_argument("-o", "--output", type=Path, required=True,
                    help="the muscle model file to write (muscle_node's muscle_model)")
    ap.add_argument("--map", type=Path, default=None,
                    help="a coordinate map of your own (config/opensim_coordinates.yaml's format)")
    ap.add_argument("--side", choices=("right", "left"), default="right")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--box", choices=("source", "ours"), default="source",
                    help="fit inside the model's own coordinate ranges (default) or over our "
                         "joints' full ranges (the model's geometry past its ranges included)")
    ap.add_argument("--exclude", default="", metavar="M1,M2",
                    help="muscles to leave out (e.g. ones whose path wrapping fails: the report "
                         "lists pairs above 1 mm)")
    ap.add_argument("--samples", type=int, default=OSIM_SIZES.n_fit,
                    help="uniform fitting postures (held-out: a quarter as many)")
    args = ap.parse_args(argv)
    sizes = FitSizes(n_fit=args.samples, n_test=max(50, args.samples // 4),
                     n_edge_base=OSIM_SIZES.n_edge_base, jump_bases=OSIM_SIZES.jump_bases,
                     n_envelope=OSIM_SIZES.n_envelope)
    t0 = time.perf_counter()
    try:
        cmap = CoordinateMap.load(args.map) if args.map is not None else None
        doc, src = build_osim(args.model, args.output, side=args.side, cmap=cmap,
                              seed=args.seed, sizes=sizes,
                              exclude=tuple(n for n in args.exclude.split(",") if n),
                              source_box=args.box == "source")
    except ForearmDynamicsError as exc:
        print(f"source_osim: {exc}", file=sys.stderr)
        return exit_code_of(exc)
    pairs = sorted(((m["fit"]["moment_arm_rms_mm"][j], m["fit"]["moment_arm_max_mm"][j],
                     m["name"], j) for m in doc["muscles"] for j in m["spans"]), reverse=True)
    print(f"wrote {args.output}: {len(doc['muscles'])} muscles, {len(pairs)} pairs, "
          f"{src.n_evaluated} postures evaluated in {time.perf_counter() - t0:.0f} s; "
          f"{sum(r <= 1.0 for r, *_ in pairs)}/{len(pairs)} pairs <= 1 mm RMS on "
          f"{doc['fit']['held_out']} held-out postures; worst (RMS / max mm):")
    for r, mx, n, j in pairs[:10]:
        print(f"  {n} {j}: {r:.3f} / {mx:.2f}")
    if src.repaired:
        print("NaN paths repaired (postures): " + ", ".join(f"{n} {len(v)}" for n, v in
                                                           src.repaired.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
