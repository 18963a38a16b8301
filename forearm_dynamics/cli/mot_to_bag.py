"""mot_to_bag MOTION.mot OUT.mcap: an OpenSim motion or states file as a joint_states bag.

    mot_to_bag MOTION.mot|STATES.sto OUT.mcap [--start SEC] [--in-degrees yes|no]
               [--map config/opensim_coordinates.yaml] [--side right|left]
               [--topic joint_states] [--overwrite]

Columns are mapped by coordinate name through config/opensim_coordinates.yaml (MoBL-ARMS,
ARMS hand and Rajagopal/Hamner full-body names -> our joints, with sign and offset; the
full-body `_r` columns for --side right, `_l` for left); angles in degrees or radians as
the header's inDegrees says; any sample rate. A map given with --map is strict: an entry
naming no column of the file is an error. Joints the file does not give are held at the
map's posture, said in one warning line; columns that map to nothing are listed (not
modelled / unknown / the other arm). The angles are checked against the joints' ranges
(forearm_dynamics/ranges.py): far outside (degrees read as radians) or all within +-3 deg
while moving (radians read as degrees) is refused naming units (exit 2), moderately
outside is warned once per joint. Each
row becomes one JointState stamped start + time (log time = stamp), velocities from a
states file's speeds when every mapped coordinate has one. The bag records where it came
from (metadata 'forearm_dynamics/mot_to_bag': source, start_ns, mapping), which bag_export
uses to write the file's own time column back. Exit 0 written, 2 bad input (one line).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..bag import BagWriter, TopicQos
from ..codec.jointstate import tidy
from ..codec.ros import message, serialize
from ..description import JOINT_NAMES
from ..errors import MotionError
from ..exit_codes import OK, USAGE
from ..formats.opensim import SIDES, CoordinateMap, map_motion, read_motion
from ..formats.opensim_shoulder import shoulder_columns
from ..ranges import check_recording
from .common import die, guarded

PROG = "mot_to_bag"
METADATA = "forearm_dynamics/mot_to_bag"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("motion", type=Path, help="OpenSim .mot (motion) or .sto (states) file")
    ap.add_argument("output", type=Path, help="MCAP bag to write (refused if it exists)")
    ap.add_argument("--start", type=float, default=None, metavar="SEC",
                    help="stamp of time 0, s since the epoch (default: now, to the ms)")
    ap.add_argument("--in-degrees", choices=("yes", "no"), default=None,
                    help="override (or supply) the header's inDegrees")
    ap.add_argument("--map", type=Path, default=None, metavar="YAML",
                    help="coordinate map (default: the package's config/opensim_coordinates.yaml)")
    ap.add_argument("--side", choices=SIDES, default="right",
                    help="the arm whose full-body columns (_r / _l) are used (default right)")
    ap.add_argument("--topic", default="joint_states")
    ap.add_argument("--frame-id", default="")
    ap.add_argument("--overwrite", action="store_true")
    return ap.parse_args(argv)


def run(args: argparse.Namespace) -> int:
    cmap = CoordinateMap.load(args.map)
    deg = None if args.in_degrees is None else args.in_degrees == "yes"
    motion = read_motion(args.motion, deg)
    mm = map_motion(motion, cmap, args.side)
    shoulder, shoulder_note = shoulder_columns(motion, args.side)
    if shoulder_note:
        mm.notes.append(shoulder_note)
    if shoulder is not None:  # the humerus moves: its columns go in as the shoulder's joints
        used = set(shoulder.columns)
        mm.not_modelled = [c for c in mm.not_modelled if c not in used]
        mm.unknown = [c for c in mm.unknown if c not in used]
    measured = [j in mm.mapped for j in JOINT_NAMES]
    units = "inDegrees=" + ("yes" if motion.in_degrees else "no")
    check = check_recording(mm.q, JOINT_NAMES, source=f"{args.motion} ({units})", measured=measured,
                            as_given=mm.as_given)
    if check.refusal:
        raise MotionError(check.refusal + "; nothing written")
    start_ns = round((time.time() if args.start is None else args.start) * 1e3) * 1_000_000
    stamps = [start_ns + round(float(t) * 1e9) for t in mm.time]
    if stamps[0] <= 0:
        return die(f"{PROG}: error: time {mm.time[0]:g} s with --start {start_ns / 1e9:g} gives a "
                   "stamp <= 0 (stamp 0 means 'missing' to the torque node); give a later --start", USAGE)
    info = {"source": str(args.motion), "kind": motion.kind, "in_degrees": motion.in_degrees,
            "start_ns": start_ns, "mapped": mm.mapped, "held_rad": mm.held,
            "not_modelled": mm.not_modelled, "unknown": mm.unknown, "side": args.side,
            "shoulder": None if shoulder is None else dict(zip(shoulder.names, shoulder.columns))}
    with BagWriter(args.output, overwrite=args.overwrite) as w:
        w.add_metadata(METADATA, {k: json.dumps(v) for k, v in info.items()})
        ch = w.add_topic("/" + args.topic.strip("/"), "sensor_msgs/msg/JointState", TopicQos(depth=1000))
        msg = message("JointState")()
        msg.header.frame_id = args.frame_id
        msg.name = list(JOINT_NAMES) + ([] if shoulder is None else list(shoulder.names))
        for k, stamp in enumerate(stamps):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            msg.position = mm.q[k].tolist() + ([] if shoulder is None else shoulder.q[k].tolist())
            # velocities only when every joint has one (the shoulder's come from no speed column)
            msg.velocity = [] if mm.qd is None or shoulder is not None else mm.qd[k].tolist()
            w.write(ch, tidy(serialize(msg)), stamp)
    dt = float(mm.time[-1] - mm.time[0]) / max(len(mm.time) - 1, 1)
    print(f"{PROG}: {len(stamps)} rows of {motion.kind} file {args.motion} ("
          f"{'degrees' if motion.in_degrees else 'radians'}, {1 / dt if dt > 0 else 0:.1f} Hz, "
          f"{mm.time[-1] - mm.time[0]:.3f} s) -> {args.output} ({args.topic}"
          f"{', with velocities' if mm.qd is not None else ''})")
    print(f"  mapped ({len(mm.mapped)}): " + ", ".join(f"{c} -> {j}" if c != j else j
                                                       for j, c in mm.mapped.items()))
    if shoulder is not None:
        print(f"  shoulder ({shoulder.convention}, the humerus moves): "
              + ", ".join(f"{c} -> {n}" for n, c in zip(shoulder.names, shoulder.columns)))
    if mm.held:
        print(f"{PROG}: warning: {len(mm.held)} of {len(JOINT_NAMES)} model joints not in the file, "
              "held at the map's posture: " + ", ".join(f"{j} {v:g} rad" for j, v in mm.held.items()),
              file=sys.stderr)
    for w in check.warnings:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    if mm.other_arm:
        print(f"  the other arm's columns, not used (--side {'left' if args.side == 'right' else 'right'}"
              f" for them) ({len(mm.other_arm)}): {', '.join(mm.other_arm)}")
    if mm.not_modelled:
        print(f"  not modelled, not used ({len(mm.not_modelled)}): {', '.join(mm.not_modelled)}")
    if mm.unknown:
        print(f"  unknown columns, not used ({len(mm.unknown)}): {', '.join(mm.unknown)}")
    for note in mm.notes:
        print(f"  note: {note}")
    return OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return guarded(PROG, run, args, f"{args.motion}: cannot convert")


if __name__ == "__main__":
    sys.exit(main())
