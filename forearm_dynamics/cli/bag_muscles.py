"""bag_muscles IN OUT: muscle forces for every joint_torques message of a bag, offline.

    bag_muscles IN.mcap OUT.mcap [--body-size 50] [--side right|left] [--muscle-model FILE]
                [--decimation N] [--input-topic joint_torques] [--overwrite]

OUT holds every message of IN plus `muscle_forces` (name = muscles, position = activation,
velocity = muscle-tendon lengthening speed m/s, effort = force N), `muscle_reserves` (name =
joints, effort = reserve N·m) and `muscle_node/config`: what muscle_node publishes given the
same torques (same header, same numbers). The arm (body size, side) is the one IN's
torque_node/config names, else the arguments'. Make the torques first with bag_torques.
Exit codes: 0 written; 2 bad arguments or an input that cannot be used (one line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..exit_codes import OK
from ..offline.muscles import bag_muscles
from .common import body_size_arg, guarded

PROG = "bag_muscles"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("input", type=Path, help="bag with joint_torques (torque_node or bag_torques)")
    ap.add_argument("output", type=Path, help="new bag to write (refused if it exists)")
    ap.add_argument("--body-size", type=body_size_arg, default=50,
                    help="when IN has no torque_node/config: percentile 5, 50, 95 or "
                         "stature_m,body_mass_kg (default 50)")
    ap.add_argument("--side", default="right", choices=("right", "left"))
    ap.add_argument("--muscle-model", default=None, metavar="FILE",
                    help="muscle model file (default: the shipped MyoArm-derived model)")
    ap.add_argument("--decimation", type=int, default=1, help="solve one message in N (as the node)")
    ap.add_argument("--reserve-optimal-torque", type=float, default=1.0, metavar="NM")
    ap.add_argument("--no-force-velocity", dest="force_velocity", action="store_false")
    ap.add_argument("--passive", action="store_true")
    ap.add_argument("--input-topic", default="joint_torques")
    ap.add_argument("--topic", default="muscle_forces", help="output topic")
    ap.add_argument("--reserves-topic", default="muscle_reserves")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    if args.decimation < 1:
        ap.error("--decimation must be >= 1")
    if not args.reserve_optimal_torque > 0:
        ap.error("--reserve-optimal-torque must be > 0 N·m")
    return args


def run(args: argparse.Namespace) -> int:
    res, counts, config = bag_muscles(
        args.input, args.output, muscle_model=args.muscle_model, body_size=args.body_size,
        side=args.side, input_topic=args.input_topic, output_topic=args.topic,
        reserves_topic=args.reserves_topic, reserve_optimal_torque=args.reserve_optimal_torque,
        force_velocity=args.force_velocity, passive=args.passive, decimation=args.decimation,
        overwrite=args.overwrite)
    for w in res.warnings:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    m = config["muscles"]
    print(f"{PROG}: {len(res.stamps_ns)} samples solved ({res.dropped} dropped, {res.decimated} "
          f"decimated), {len(m['muscles'])} muscles, {m['body_size']} {m['side']} arm (from "
          f"{config['model_source']}), {int(res.infeasible.sum())} infeasible; wrote "
          f"{sum(counts.values())} messages to {args.output}")
    return OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return guarded(PROG, run, args, f"{args.input}: cannot compute muscles")


if __name__ == "__main__":
    sys.exit(main())
