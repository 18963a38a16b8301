"""Open-loop round trip of the virtual arm: the model's own inverse-dynamics torques of a
library movement, fed to forward dynamics (RK4, fixed step), should reproduce the movement.

    python benchmarks/sim_roundtrip.py [--out benchmarks/sim.json] [--hand N ...]

For each body size and movement: the angle error |q_FD(t) - q_movement(t)| over the
movement's 1.5 s, max over joints; the time at which it first exceeds 1e-4 rad (the
issue's target); which joint is worst. The torque function is evaluated at every RK4 stage
(a continuous input, as Simulink does), damping 0 and no limits (the ID torques know
neither), from the movement's exact initial state. A dt sweep on one movement shows what
the error is: RK4's 4th-order step error (16x smaller per halving of dt), amplified by the
open-loop arm's unstable modes (the fingers are inverted multi-pendulums at many
postures), not roundoff. No ROS; deterministic (the numbers do not depend on the load,
the wall times do). Section `roundtrip` of the output file.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.stats import loadavg, machine_info, save_sections
from forearm_dynamics.dynamics import build_model
from forearm_dynamics.movements import movement_library
from forearm_dynamics.simulation import simulate

SIZES = ("male_5", "male_50", "male_95", "female_5", "female_50", "female_95")
TARGET = 1e-4


def round_trip(arm, movement, dt: float) -> dict:
    def torque(t, _q, _qd):
        a, b, c = movement.evaluate([t])
        return arm.inverse_dynamics(a[0], b[0], c[0])

    q0, qd0, _ = movement.evaluate([0.0])
    r = simulate(arm, q0[0], qd0[0], torque, dt=dt, duration=movement.duration, damping=0.0,
                 joint_limits=False)
    q_ref, _, _ = movement.evaluate(r.t)
    err = np.abs(r.q - q_ref)
    worst = err.max(axis=1)
    over = np.flatnonzero(worst > TARGET)
    return {"max_rad": float(worst.max()),
            "first_over_target_s": None if over.size == 0 else float(r.t[over[0]]),
            "worst_joint": arm.joint_names[int(err.max(axis=0).argmax())],
            "elbow_max_rad": float(err[:, 0].max()),
            "at_1s_rad": float(worst[round(1.0 / dt)])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/sim.json"))
    ap.add_argument("--hand", type=int, nargs="*", default=list(range(1, 14)),
                    help="hand movements 1-13 (each at the library's first elbow condition)")
    ap.add_argument("--dt", type=float, default=1e-3)
    args = ap.parse_args(argv)
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    load_before = loadavg()
    lib = movement_library()
    movements = [m for m in lib if m.hand_number in args.hand and m.elbow == lib[0].elbow]
    t0 = time.perf_counter()
    per_size = {}
    for size in SIZES:
        arm = build_model("segmented", size)
        rows = {m.id: round_trip(arm, m, args.dt) for m in movements}
        errs = np.array([r["max_rad"] for r in rows.values()])
        firsts = [r["first_over_target_s"] for r in rows.values()]
        per_size[size] = {
            "median_max_rad": float(np.median(errs)), "worst_max_rad": float(errs.max()),
            "met_target": int(sum(e <= TARGET for e in errs)), "movements": len(errs),
            "median_first_over_target_s": float(np.median([f if f is not None else 1.5 for f in firsts])),
            "per_movement": rows}
        print(f"{size:10s} max angle error over 1.5 s: median {np.median(errs):.3g} rad, worst "
              f"{errs.max():.3g} rad; <= {TARGET:g} rad in {per_size[size]['met_target']}/{len(errs)}"
              f"; error passes {TARGET:g} rad at median t = "
              f"{per_size[size]['median_first_over_target_s']:.3f} s", flush=True)
    arm = build_model("segmented", "male_50")
    sweep = {}
    for dt in (2e-3, 1e-3, 5e-4, 2.5e-4):
        row = sweep[f"{dt:g}"] = round_trip(arm, movements[0], dt)
        print(f"dt {dt * 1e3:g} ms, movement {movements[0].id}, male_50: max {row['max_rad']:.3g} "
              f"rad, at 1 s {row['at_1s_rad']:.3g} rad", flush=True)
    wall = time.perf_counter() - t0
    out = {"roundtrip": {
        "what": "segmented model, ID torques of library movements -> RK4 forward dynamics, "
                "damping 0, no limits; angle error max over joints and the 1.5 s",
        "dt": args.dt, "target_rad": TARGET, "sizes": per_size, "dt_sweep_male_50": sweep,
        "wall_s": wall, "loadavg_before": load_before, "loadavg_after": loadavg(),
        "machine": machine_info()}}
    save_sections(args.out, out, "benchmarks/sim_roundtrip.py", argv, started)
    print(f"wrote {args.out} (section roundtrip); {wall:.0f} s, load {load_before} -> {loadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
