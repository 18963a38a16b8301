"""Units mistakes, counted: every library movement given in the wrong units, on each path.

    python -m benchmarks.units_matrix [--rate 100] [--json benchmarks/units_matrix.json]

Mistakes: `deg_as_rad` (angles in degrees where radians are read: inDegrees=no on a file in
degrees, a JointState stream in degrees) and `rad_twice` (radians read as degrees and
converted again: inDegrees=yes on a file in radians; values 57.3 x too small). Paths, each
with the code the tool runs:
- mot: forearm_dynamics.ranges.check_recording on the mapped angles, as mot_to_bag calls it
  (refused = exit 2);
- bag: offline.score.analyse_markerless on a recording of those angles with the torques a
  node without the check would have computed from them (inverse dynamics of the wrong angles
  with their analytic derivatives), as check_bag runs it (FAIL naming "check units");
- api: ArmModel.inverse_dynamics of the (N, 20) recording: by default a UserWarning naming
  units (api_warned), with check_ranges="raise" a ValueError (api); the radians-twice rule
  is not applied there;
- live: ranges.SampleGuard, sample by sample, as torque_node.compute calls it: refused at
  the first sample (deg_as_rad), or said once after the stream's first 1 s (rad_twice: a
  warning, the stream is not refused: a still neutral posture is legitimate).
The correct units are run too (the false alarms). Each movement is sampled at --rate Hz.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
import warnings
from pathlib import Path

import numpy as np

from forearm_dynamics import JOINT_NAMES, movement_library
from forearm_dynamics.codec.jointstate import JointSeries
from forearm_dynamics.model_config import model_from_config
from forearm_dynamics.offline.recording import Recording
from forearm_dynamics.offline.score import analyse_markerless
from forearm_dynamics.offline.thresholds import Thresholds
from forearm_dynamics.ranges import SampleGuard, check_recording

SCALES = {"correct": 1.0, "deg_as_rad": 180.0 / math.pi, "rad_twice": math.pi / 180.0}


def series(topic: str, t_ns: np.ndarray, q: np.ndarray, qd: np.ndarray, effort=None) -> JointSeries:
    return JointSeries(topic, tuple(JOINT_NAMES), t_ns, t_ns, [""] * len(t_ns), q, qd, effort)


def run(rate: float) -> dict:
    choice = model_from_config(None)
    arm = choice.arm
    th = Thresholds.load()
    out = {k: {"mot": 0, "bag": 0, "live": 0, "live_first_sample": 0, "api": 0, "api_warned": 0,
               "n": 0,
               "one_line_names_units": 0} for k in SCALES}
    bag_pass_correct = []
    for mv in movement_library():
        t = mv.sample_times(rate)
        q0, qd0, qdd0 = mv.evaluate(t)
        t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
        for kind, s in SCALES.items():
            q, qd, qdd = q0 * s, qd0 * s, qdd0 * s
            row = out[kind]
            row["n"] += 1
            mot = check_recording(q, JOINT_NAMES, source=f"movement {mv.id}")
            row["mot"] += mot.refusal is not None
            with warnings.catch_warnings(record=True) as said:  # the Python API, default
                warnings.simplefilter("always")
                arm.inverse_dynamics(q, qd, qdd)  # (N, 20): a recording
            row["api_warned"] += any("check units" in str(w.message) for w in said)
            try:
                arm.inverse_dynamics_batch(q, qd, qdd, check_ranges="raise")
            except ValueError as exc:
                row["api"] += "check units" in str(exc)
            # what a node without the check sent
            tau = arm.inverse_dynamics_batch(q, qd, qdd, check_ranges="off")
            rec = Recording(series("/joint_states", t_ns, q, qd),
                            series("/joint_torques", t_ns, q, qd, tau), [])
            rep = analyse_markerless(rec, choice, th)
            units = [f for f in rep.failures if "check units" in f]
            row["bag"] += bool(units)
            if kind == "correct" and not rep.failures:
                bag_pass_correct.append(mv.id)
            guard = SampleGuard(JOINT_NAMES)
            refused_first = guard.check(q[0]) is not None
            said = refused_first
            for k in range(len(t)):
                if guard.check(q[k]) is not None:
                    said = True
                    break
                if guard.observe(int(t_ns[k]), q[k]):
                    said = True
                    break
            row["live"] += said
            row["live_first_sample"] += refused_first
            lines = [x for x in (mot.refusal, *units) if x]
            row["one_line_names_units"] += bool(lines) and all(
                "\n" not in x and "check units" in x for x in lines)
    out["correct"]["bag_pass"] = len(bag_pass_correct)
    return out


def guard_cost(n: int = 100_000) -> dict:
    """The node's per-sample price of the check (SampleGuard.check on an in-range sample)
    beside pin.rnea of the same model in the same run (median of 5 repeats, us)."""
    import timeit

    import pinocchio as pin

    arm = model_from_config(None).arm
    q, z = np.full(20, 0.3), np.zeros(20)
    guard = SampleGuard(JOINT_NAMES)
    check = sorted(timeit.repeat(lambda: guard.check(q), number=n, repeat=5))[2] / n * 1e6
    rnea = sorted(timeit.repeat(lambda: pin.rnea(arm.model, arm.data, q, z, z), number=n,
                                repeat=5))[2] / n * 1e6
    return {"guard_check_us": check, "rnea_us": rnea, "ratio": check / rnea,
            "load_average": list(os.getloadavg())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = run(args.rate)
    print(f"{'case':<12} {'n':>4} {'mot refused':>12} {'bag FAIL units':>15} {'live said':>10} "
          f"{'live 1st':>9} {'API warned':>11} {'API raise':>10}")
    for kind, r in res.items():
        print(f"{kind:<12} {r['n']:>4} {r['mot']:>12} {r['bag']:>15} {r['live']:>10} "
              f"{r['live_first_sample']:>9} {r['api_warned']:>11} {r['api']:>10}")
    print(f"correct units, check_bag PASS: {res['correct']['bag_pass']} of {res['correct']['n']}; "
          f"{time.perf_counter() - t0:.1f} s")
    cost = res["node_cost"] = guard_cost()
    print(f"torque_node's check per sample: {cost['guard_check_us']:.2f} us, pin.rnea "
          f"{cost['rnea_us']:.2f} us in the same run (ratio {cost['ratio']:.2f}); load "
          f"{cost['load_average'][0]:.1f}")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
