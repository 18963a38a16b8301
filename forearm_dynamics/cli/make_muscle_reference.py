"""make_muscle_reference: regenerate the cached muscle reference (OpenSim SO + exact geometry).

    make muscle-reference        # = python -m forearm_dynamics.cli.make_muscle_reference

Needs OpenSim (`reference` extra) and, for the exact-geometry solve, MuJoCo + myo_sim
(`muscles-fit` extra; without them `--no-exact` leaves that part out). Writes
forearm_dynamics/data/muscle_so_reference.npz (analysis/muscle_reference.py says what it
holds). Takes ~10 min on 2 cores (OpenSim's SO: ~0.5-1.5 s per frame).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..dynamics import build_model
from ..exit_codes import OK, USAGE
from ..movements import get_movement
from ..muscle_validation import opensim_so as so_mod
from ..muscle_validation.reference import REFERENCE_FILE, MuscleReference, bvls_solve, save_reference
from ..muscles import load_muscle_model
from .common import die

PROG = "make_muscle_reference"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, default=REFERENCE_FILE)
    ap.add_argument("--movements", type=lambda s: tuple(int(x) for x in s.split(",")),
                    default=so_mod.MOVEMENT_IDS, help="comma-separated movement ids")
    ap.add_argument("--rate", type=float, default=so_mod.RATE_HZ, help="SO frames per second")
    ap.add_argument("--no-exact", dest="exact", action="store_false",
                    help="leave out the exact-geometry (MuJoCo) solve")
    args = ap.parse_args(argv)
    try:
        import opensim
    except ImportError:
        return die(f"{PROG}: needs OpenSim: pip install '.[reference]' (opensim==4.6)", USAGE)
    src = None
    if args.exact:
        try:
            from ..muscles.fit import MyoArm

            src = MyoArm()
        except ImportError:
            return die(f"{PROG}: the exact-geometry solve needs MuJoCo and myo_sim: pip install "
                       "-e '.[muscles-fit]' (or --no-exact)", USAGE)
    mm = load_muscle_model()
    arm = build_model("segmented", 50)
    t0 = time.perf_counter()
    model = so_mod.build_so_model(arm.tree, mm)
    offsets, times, act, frc, res, ex_a, ex_r, seconds = [0], [], [], [], [], [], [], {}
    for mid in args.movements:
        mv = get_movement(mid)
        r = so_mod.opensim_movement(model, mm, mv, args.rate)
        seconds[str(mid)] = round(r.seconds, 2)
        times.append(r.times)
        act.append(r.activations)
        frc.append(r.forces)
        res.append(r.reserves)
        offsets.append(offsets[-1] + len(r.times))
        if src is not None:
            q, qd, qdd = mv.evaluate(r.times)
            tau = arm.inverse_dynamics_batch(q, qd, qdd)
            L, R = src.evaluate(q)
            for k in range(len(q)):
                V = -(R[k] @ qd[k])
                a, rr = bvls_solve(mm, R[k], L[k], V, tau[k])
                ex_a.append(a)
                ex_r.append(rr)
        print(f"{PROG}: movement {mid} ({mv.name}): {len(r.times)} frames, OpenSim SO "
              f"{r.seconds:.1f} s", file=sys.stderr)
    meta = {
        "engine": "opensim", "engine_version": str(opensim.__version__),
        "analysis": "AnalyzeTool + StaticOptimization (activation exponent 2, muscle physiology, "
                    "model force set), DeGrooteFregly2016Muscle rigid tendon, FunctionBasedPath "
                    "= the shipped surrogate polynomials, CoordinateActuator reserves 1 N·m",
        "model": "segmented", "body_size": "p50", "side": "right",
        "muscle_model": mm.source.get("name"), "muscle_model_sha256": so_mod.model_digest(mm),
        "rate_hz": args.rate, "coordinates_rate_hz": so_mod.COORDINATES_RATE_HZ,
        "edge_s": so_mod.EDGE_S, "reserve_optimal_torque": so_mod.RESERVE_OPTIMAL_TORQUE,
        "opensim_seconds": seconds,
        "exact": None if src is None else {"engine": "mujoco", **src.version,
                                           "solver": "scipy lsq_linear bvls, tol 1e-14"},
        "generator": "make muscle-reference (forearm_dynamics.cli.make_muscle_reference)",
        "total_s": round(time.perf_counter() - t0, 1),
    }
    ref = MuscleReference(
        np.asarray(args.movements), np.asarray(offsets), np.concatenate(times), mm.names,
        np.vstack(act), np.vstack(frc), np.vstack(res),
        np.asarray(ex_a) if ex_a else None, np.asarray(ex_r) if ex_r else None, meta)
    save_reference(args.output, ref)
    print(f"{PROG}: wrote {args.output} ({offsets[-1]} frames, {meta['total_s']} s)")
    return OK


if __name__ == "__main__":
    sys.exit(main())
