"""Cost of the muscle layer per sample, in process (no ROS): `python -m benchmarks.muscles`.

Replays the library's movements at 1 kHz through the pieces muscle_node's callback runs:
surrogate geometry (moment arms, lengths, path velocities), force-length-velocity scaling,
the warm-started QP, and all of them together (the compute part of the callback: its
decode/publish is the node's), numpy's way; then `node_path`, the node's own call
(StaticOptimizer.solve_sample_into: the same, in two compiled calls around daqp's where
muscles/muscle_step.py is built; `compiled_step` says whether it was). Beside them, in the
same run, the inverse dynamics of the same samples (the torque node's compute) as a
baseline, so a loaded machine shows in both.
Writes benchmarks/muscles.json (median, p99 in µs, the load average before and after).

    python -m benchmarks.muscles [--movements 1,4,13,24,33,62] [--rate 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from forearm_dynamics import build_model, movement_library
from forearm_dynamics.muscles import StaticOptimizer, load_muscle_model
from forearm_dynamics.muscles.curves import UnitForces

OUT = Path(__file__).resolve().parent / "muscles.json"


def stats(ns: np.ndarray) -> dict:
    us = np.asarray(ns, float) / 1e3
    return {"p50_us": round(float(np.median(us)), 1), "p99_us": round(float(np.percentile(us, 99)), 1),
            "n": len(us)}


def run(movements: list[int] | None, rate: float) -> dict:
    mm = load_muscle_model()
    arm = build_model("segmented")
    so = StaticOptimizer(mm)
    forces = UnitForces(mm.params())
    geo = mm.geometry_outputs()
    so_node, geo_node = StaticOptimizer(mm), mm.geometry_outputs()  # the node's path, its own
    outs = (np.empty(mm.n), np.empty(mm.n), np.empty(len(mm.joint_names)))
    lib = movement_library()
    chosen = [m for m in lib if movements is None or m.id in movements]
    clock = time.perf_counter_ns
    parts = {k: [] for k in ("geometry", "forces", "qp", "callback", "node_path",
                                   "inverse_dynamics")}
    infeasible = 0
    total = 0
    load0 = os.getloadavg()
    for mv in chosen:
        q, qd, qdd = mv.evaluate(mv.sample_times(rate))
        so.reset()
        so_node.reset()
        for k in range(len(q)):
            t0 = clock()
            tau = arm.inverse_dynamics(q[k], qd[k], qdd[k])
            t1 = clock()
            R, L, V = mm.geometry(q[k], qd[k], geo)  # the node's path: into arrays made once
            t2 = clock()
            forces(L, V)
            t3 = clock()
            s = so.solve_geometry(R, L, V, tau)
            t4 = clock()
            so_node.solve_sample_into(q[k], qd[k], tau, geo_node, *outs)
            t5 = clock()
            parts["node_path"].append(t5 - t4)
            parts["inverse_dynamics"].append(t1 - t0)
            parts["geometry"].append(t2 - t1)
            parts["forces"].append(t3 - t2)
            parts["qp"].append(s.solve_time * 1e9)
            # the callback's compute = geometry + solve_geometry (which includes the forces)
            parts["callback"].append((t2 - t1) + (t4 - t3))
            infeasible += s.infeasible
            total += 1
    load1 = os.getloadavg()
    return {
        "what": "muscle layer per sample, in process, 2 cores",
        "muscles": mm.n, "monomials": mm.surrogate.n_monomials, "nnz": int(mm.surrogate.coef.nnz),
        "movements": [m.id for m in chosen], "rate_hz": rate, "samples": total,
        "infeasible_samples": int(infeasible),
        "compiled_step": so_node._step is not None and so_node._step[1] is not None,
        "loadavg_before": [round(x, 2) for x in load0], "loadavg_after": [round(x, 2) for x in load1],
        **{k: stats(v) for k, v in parts.items()},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--movements", default="", help="comma-separated ids (default: all 65)")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    ids = [int(x) for x in args.movements.split(",") if x] or None
    res = run(ids, args.rate)
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
