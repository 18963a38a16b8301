"""bag_torques IN OUT: joint torques for every joint_states of a bag, offline, in batch.

    bag_torques IN.mcap OUT.mcap [--model segmented] [--body-size 50 | 1.80,75]
                [--side right|left] [--payload-mass KG [--payload-com X,Y,Z]]
                [--shoulder auto|none|mobl|fullbody]
                [--estimator kalman|butterworth|savgol|backward|zero_phase]
                [--setting NAME=VALUE ...] [--accel-cutoff HZ] [--velocity-cutoff HZ]
                [--cutoff HZ] [--max-stamp-gap S] [--input-topic T] [--topic T] [--overwrite]

OUT holds every message of IN plus `joint_torques` and a `torque_node/config` naming the
model and estimator (so `check_bag OUT` rebuilds the same model). The torque node's
estimators (default: the node's default) give the same numbers as the node given the same
stream; `--setting NAME=VALUE` sets one of the estimator's settings (the node's
`estimator.NAME`). 'zero_phase' is the offline practice (6 Hz forward-backward low-pass,
derivatives of the filtered positions). With a delay (`--setting delay_s=0.05`) each
estimate is stamped with the sample it estimates, as the node stamps it; every sample gets
one row (the last delay_s at the end). The stamp rule is the node's (--max-stamp-gap 0:
adaptive). OUT's chunks hold 0.5 s of log time each: a cut OUT keeps all but its last second.
Exit codes: 0 written; 2 bad arguments or an input that cannot be used (one line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..bag.reader import open_bag
from ..builders import MODEL_KINDS
from ..codec.jointstate import JointStateReader, find_joint_topic
from ..dynamics import build_model
from ..estimation import DEFAULT_ESTIMATOR, make_estimator
from ..exit_codes import OK, USAGE
from ..offline.torques import ESTIMATORS, bag_torques
from ..shoulder import SHOULDER_CHOICES, detect_convention
from .common import body_size_arg, die, guarded

PROG = "bag_torques"


def _xyz(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: give x,y,z in m, e.g. 0.01,-0.08,0.02")
    return values


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("input", type=Path, help="bag with joint_states (any rosbag2 MCAP)")
    ap.add_argument("output", type=Path, help="new bag to write (refused if it exists)")
    ap.add_argument("--model", default="segmented", choices=MODEL_KINDS)
    ap.add_argument("--body-size", type=body_size_arg, default=50,
                    help="percentile 5, 50, 95 or stature_m,body_mass_kg (default 50)")
    ap.add_argument("--side", default="right", choices=("right", "left"),
                    help="which arm (the left is the mirror image; same joint names and signs), "
                         "as the node's side")
    ap.add_argument("--payload-mass", type=float, default=0.0, metavar="KG",
                    help="an object held in the hand (0 = empty hand), as the node's payload_mass")
    ap.add_argument("--payload-com", type=_xyz, default=None, metavar="X,Y,Z",
                    help="the object's centre of mass in the hand frame, m (default: the "
                         "power-grasp point in the palm), as the node's payload_com")
    ap.add_argument("--shoulder", default="auto", choices=("auto", *SHOULDER_CHOICES),
                    help="the humerus' orientation as three more joints (docs/shoulder.md): auto "
                         "(default) = the convention whose three angles the bag's joint_states "
                         "carry (mot_to_bag writes them), none = welded vertical, as the node's "
                         "shoulder")
    ap.add_argument("--estimator", default=DEFAULT_ESTIMATOR, choices=ESTIMATORS,
                    help=f"default {DEFAULT_ESTIMATOR} (the torque node's default)")
    ap.add_argument("--setting", action="append", default=[], metavar="NAME=VALUE",
                    help="an estimator setting (the node's estimator.NAME), e.g. "
                         "kalman_jerk_psd=3000; repeatable")
    ap.add_argument("--accel-cutoff", type=float, default=0.0, metavar="HZ",
                    help="backward: first-order low-pass on qdd (0 = off, as the node's default)")
    ap.add_argument("--velocity-cutoff", type=float, default=0.0, metavar="HZ",
                    help="backward: low-pass on velocities estimated from positions (0 = off)")
    ap.add_argument("--cutoff", type=float, default=None, metavar="HZ",
                    help="zero_phase: low-pass cutoff (default config/analysis.yaml, 6 Hz)")
    ap.add_argument("--max-stamp-gap", type=float, default=0.0, metavar="S",
                    help="stamp steps beyond this restart the estimator (the node's max_stamp_gap; "
                         "0, the default, = the node's adaptive rule: 0.1 s and 5 x the stream's "
                         "step)")
    ap.add_argument("--input-topic", default="joint_states")
    ap.add_argument("--topic", default="joint_torques", help="output topic")
    ap.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    ap.add_argument("--no-std", dest="std", action="store_false",
                    help="do not write <topic>_std (1σ per torque; written by default for estimators "
                         "with a covariance: kalman)")
    ap.add_argument("--subject-std", default="none", choices=("none", "ansur"),
                    help="the σ's subject part, as the node's subject_std: ansur adds the ANSUR II "
                         "spread of forearm and hand at this stature and body mass "
                         "(docs/uncertainty.md part 4; default none)")
    return ap.parse_args(argv)


def _bag_shoulder(path: Path, topic: str) -> str:
    """The shoulder convention of the first joint_states message's names ('none' without).
    A bag that cannot be read says so later, in bag_torques' own words."""
    try:
        bag = open_bag(path)
        ch = find_joint_topic(bag, topic)
        reader = JointStateReader(None, False, f"{path}: {ch.topic}")
        for _ch, msg in bag.messages([ch.topic]):
            reader.add(msg.data, msg.log_time)
            break
        names = reader.series(ch.topic).joint_names if len(reader) else ()
    except Exception:  # noqa: BLE001 - reported by bag_torques itself with its exit code
        return "none"
    return detect_convention(names) or "none"


def run(args: argparse.Namespace) -> int:
    if args.payload_com is not None and not args.payload_mass:
        return die(f"{PROG}: error: --payload-com needs --payload-mass", USAGE)
    payload = {"payload_mass": args.payload_mass, "payload_com": args.payload_com} \
        if args.payload_mass else {}
    shoulder = args.shoulder
    if shoulder == "auto":
        try:
            shoulder = _bag_shoulder(args.input, args.input_topic)
        except ValueError as exc:
            return die(f"{PROG}: error: {args.input}: {exc}", USAGE)
    try:
        arm = build_model(args.model, args.body_size, side=args.side, shoulder=shoulder, **payload)
    except ValueError as exc:
        return die(f"{PROG}: error: --model/--body-size/--side/--payload-mass: {exc}", USAGE)
    settings: dict[str, float] = {}
    for item in args.setting:
        name, sep, value = item.partition("=")
        try:
            settings[name.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            return die(f"{PROG}: error: --setting {item!r}: give NAME=VALUE (a number)", USAGE)
    if args.accel_cutoff or args.velocity_cutoff:
        if args.estimator != "backward":
            return die(f"{PROG}: error: --accel-cutoff/--velocity-cutoff belong to the backward "
                       "estimator (zero_phase takes --cutoff, the others --setting)", USAGE)
        settings.update(accel_cutoff_hz=args.accel_cutoff, velocity_cutoff_hz=args.velocity_cutoff)
    if args.estimator == "zero_phase" and settings:
        return die(f"{PROG}: error: zero_phase takes --cutoff, not estimator settings", USAGE)
    if args.estimator != "zero_phase":
        try:
            make_estimator(args.estimator, 1, settings)
        except ValueError as exc:
            return die(f"{PROG}: error: --setting: {exc}", USAGE)
    res, counts = bag_torques(args.input, args.output, arm, estimator=args.estimator,
                              settings=settings, input_topic=args.input_topic, output_topic=args.topic,
                              max_gap_s=args.max_stamp_gap, cutoff_hz=args.cutoff,
                              overwrite=args.overwrite, std=args.std and shoulder == "none",
                              subject=args.subject_std)
    for w in res.warnings:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    n = len(res.stamps_ns)
    rate = n / res.compute_s if res.compute_s > 0 else float("inf")
    print(f"{PROG}: {n} samples ({res.dropped} dropped by the stamp rules, {res.segments} "
          f"segment(s)), model {arm.kind} {arm.body_size.label} {arm.side} arm"
          f"{f', payload {arm.payload.mass:g} kg' if arm.payload is not None else ''}"
          f"{f', shoulder {shoulder} (the humerus moves)' if shoulder != 'none' else ''}, "
          f"estimator {args.estimator}: "
          f"computed in {res.compute_s:.3f} s ({rate:,.0f} samples/s); wrote "
          f"{sum(counts.values())} messages to {args.output}")
    if res.std is not None:
        warming = int(np.isinf(res.std).any(axis=1).sum())
        delayed = settings.get("delay_s", 0.0) > 0
        print(f"{PROG}: {args.topic.rstrip('/')}_std: 1σ per torque ({warming} samples without a "
              f"known σ: inf; warming up{', or the last delay_s output at the end' if delayed else ''})")
    elif args.std and shoulder != "none":
        print(f"{PROG}: no {args.topic.rstrip('/')}_std: the torque σ is the 20-joint model's "
              "(not with a shoulder yet)")
    elif args.std:
        print(f"{PROG}: no {args.topic.rstrip('/')}_std: {res.std_config['why']}")
    return OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return guarded(PROG, run, args, f"{args.input}: cannot compute")


if __name__ == "__main__":
    sys.exit(main())
