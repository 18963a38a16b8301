"""bag_export BAG --format csv|sto: joint_torques (and states) as CSV or an OpenSim table.

    bag_export BAG --format csv|sto [--out FILE] [--topic joint_torques] [--states]
               [--names ours|opensim] [--map config/opensim_coordinates.yaml]

    bag_export BAG --format csv|sto --muscles [--topic muscle_forces]

One row per joint_torques message, in stamp order. Columns: `time` (s; for a bag made by
mot_to_bag the source file's own time, else from the first stamp), `stamp_ns` (CSV only),
`<joint>_moment` (N·m) per joint, and with --states `<joint>` (rad) and `<joint>_speed`
(rad/s): the state the torques were computed for; when the bag has `<topic>_std` (the
torque σ: torque_node publish_std, bag_torques), `<joint>_moment_std` (N·m, 1σ) unless
--no-std. A value that is not known (the σ while the estimate warms up, inf on the topic; no
σ message of that stamp) is `NaN` in a .sto and an empty cell in CSV, never `inf`; the .sto
header says so (`note_std=`), as it says `truncated=` for a cut bag (its complete chunks
are exported; the summary line says "truncated" too). `.sto` is what OpenSim's Inverse
Dynamics tool writes (header, `inDegrees=no`, `endheader`, tab-separated), readable by
OpenSim's tools; `--names opensim` labels columns with the MoBL-ARMS/ARMS coordinate names
of config/opensim_coordinates.yaml (moments and states in the OpenSim coordinate's sign).
--muscles: one row per muscle_forces message (muscle_node, bag_muscles) instead: columns
`<muscle>_activation` (0..1), `<muscle>_force` (N) per muscle, and `<joint>_reserve` (N·m)
from `muscle_reserves` (matched by stamp; NaN where none), the muscles in the message's order.
Exit 0 written, 2 bad input (one line).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..bag import open_bag
from ..codec.jointstate import read_joint_series
from ..description import JOINT_NAMES
from ..errors import ForeignBag
from ..exit_codes import OK, USAGE
from ..formats.opensim import CoordinateMap, write_table
from .common import die, guarded
from .mot_to_bag import METADATA

PROG = "bag_export"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", type=Path)
    ap.add_argument("--format", choices=("csv", "sto"), required=True)
    ap.add_argument("--out", type=Path, default=None, help="output file (default BAG with .csv/.sto)")
    ap.add_argument("--topic", default=None, help="default joint_torques (muscle_forces with --muscles)")
    ap.add_argument("--muscles", action="store_true",
                    help="export muscle activations and forces (muscle_forces) and the reserves")
    ap.add_argument("--states", action="store_true", help="also the joint positions and velocities")
    ap.add_argument("--names", choices=("ours", "opensim"), default="ours")
    ap.add_argument("--map", type=Path, default=None, metavar="YAML")
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--no-std", dest="std", action="store_false",
                    help="leave out the <joint>_moment_std columns (added when the bag has <topic>_std)")
    return ap.parse_args(argv)


def _source_start(bag) -> int | None:
    for name, data in bag.info.metadata:
        if name == METADATA and "start_ns" in data:
            try:
                return int(json.loads(data["start_ns"]))
            except (ValueError, TypeError):
                return None
    return None


def _std_columns(bag, topic: str, stamps: np.ndarray) -> np.ndarray:
    """(N, J) σ (N·m, never negative: no sign change) of each torque row, matched by stamp;
    NaN where the σ topic has no message of that stamp, inf where it says warming up."""
    sd = read_joint_series(bag, topic, JOINT_NAMES, effort=True)
    out = np.full((len(stamps), len(JOINT_NAMES)), np.nan)
    order = np.argsort(sd.stamp_ns, kind="stable")
    s_st = sd.stamp_ns[order]
    if len(s_st):
        pos = np.minimum(np.searchsorted(s_st, stamps), len(s_st) - 1)
        hit = s_st[pos] == stamps
        out[hit] = sd.effort[order][pos[hit]]
    return out


def _muscle_table(bag, args: argparse.Namespace) -> tuple[list[str], np.ndarray, np.ndarray, str]:
    """(labels, stamps, data, topic) of muscle_forces (+ the reserves of the same stamps)."""
    s = read_joint_series(bag, args.topic, None, effort=True)
    order = np.argsort(s.stamp_ns, kind="stable")
    stamps = s.stamp_ns[order]
    labels = [f"{m}_activation" for m in s.joint_names] + [f"{m}_force" for m in s.joint_names]
    cols = [s.position[order], s.effort[order]]
    res_topic = s.topic.rsplit("/", 1)[0] + "/muscle_reserves"
    if bag.info.find_topic(res_topic) is not None:
        r = read_joint_series(bag, res_topic, JOINT_NAMES, effort=True)
        table = np.full((len(stamps), len(JOINT_NAMES)), np.nan)
        ro = np.argsort(r.stamp_ns, kind="stable")
        rs = r.stamp_ns[ro]
        if len(rs):
            pos = np.minimum(np.searchsorted(rs, stamps), len(rs) - 1)
            hit = rs[pos] == stamps
            table[hit] = r.effort[ro][pos[hit]]
        labels += [f"{j}_reserve" for j in JOINT_NAMES]
        cols.append(table)
    return labels, stamps, np.hstack(cols), s.topic


def run(args: argparse.Namespace) -> int:
    out = args.out or args.bag.with_suffix("." + args.format)
    if out.exists() and not args.overwrite:
        return die(f"{PROG}: error: {out} exists already; refusing to overwrite it "
                   "(--overwrite replaces it)", USAGE)
    bag = open_bag(args.bag)
    if args.muscles:
        args.topic = args.topic or "muscle_forces"
        labels, stamps, data, topic = _muscle_table(bag, args)
        start = _source_start(bag)
        t = (stamps - (start if start is not None else stamps[0])) / 1e9
        if args.format == "csv":
            write_table(out, "", labels, t, data, sep=",", opensim=False, stamps_ns=stamps)
        else:
            write_table(out, "Muscle activations and forces (forearm_dynamics bag_export)", labels, t, data)
        print(f"{PROG}: {len(stamps)} rows of {topic} ({len(labels)} columns) -> {out}")
        return OK
    args.topic = args.topic or "joint_torques"
    s = read_joint_series(bag, args.topic, JOINT_NAMES, effort=True)
    if not np.isfinite(s.effort).any(axis=0).all():
        missing = [j for j, ok in zip(JOINT_NAMES, np.isfinite(s.effort).any(axis=0), strict=True) if not ok]
        raise ForeignBag(f"{args.bag}: {s.topic} carries no effort for {', '.join(missing[:4])}"
                       f"{' ...' if len(missing) > 4 else ''}: not joint torques of this model")
    order = np.argsort(s.stamp_ns, kind="stable")
    stamps = s.stamp_ns[order]
    start = _source_start(bag)
    t = (stamps - (start if start is not None else stamps[0])) / 1e9
    names, signs = list(JOINT_NAMES), np.ones(len(JOINT_NAMES))
    if args.names == "opensim":
        cmap = CoordinateMap.load(args.map)
        pairs = [cmap.opensim_name(j) for j in JOINT_NAMES]
        names, signs = [p[0] for p in pairs], np.array([p[1] for p in pairs])
    labels = [f"{n}_moment" for n in names]
    cols = [s.effort[order] * signs]
    if args.states:
        labels += names + [f"{n}_speed" for n in names]
        cols += [s.position[order] * signs, s.velocity[order] * signs]
    std_topic = s.topic.rstrip("/") + "_std"
    notes: dict[str, str] = {}
    unknown = 0
    if args.std and bag.info.find_topic(std_topic) is not None:
        labels += [f"{n}_moment_std" for n in names]
        sd = _std_columns(bag, std_topic, stamps)
        cols.append(sd)
        unknown = int((~np.isfinite(sd)).any(axis=1).sum())
        if unknown:
            notes["note_std"] = (f"NaN in a _moment_std column: no torque sigma known for that row "
                                 f"({unknown} rows: the estimate warming up, or no sigma message of "
                                 "that stamp)")
    truncated = not bag.info.complete
    if truncated:
        notes["truncated"] = (f"yes: {args.bag.name} was cut ({bag.info.problem}); the rows of its "
                              f"{bag.info.message_count} messages in complete chunks")
    data = np.hstack(cols)
    if args.format == "csv":
        write_table(out, "", labels, t, data, sep=",", opensim=False, stamps_ns=stamps)
    else:
        write_table(out, "Inverse Dynamics Generalized Forces (forearm_dynamics bag_export)", labels, t, data,
                    notes=notes)
    empty = "empty" if args.format == "csv" else "NaN"
    print(f"{PROG}: {len(stamps)} rows of {s.topic} ({len(labels)} columns) -> {out}"
          + (f"; {unknown} rows without a known σ ({empty} cells: warming up)" if unknown else "")
          + (" (truncated input: its complete chunks only)" if truncated else ""))
    if truncated:
        print(f"{PROG}: warning: {args.bag} is truncated ({bag.info.problem}); exported its complete chunks",
              file=sys.stderr)
    return OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return guarded(PROG, run, args, f"{args.bag}: cannot export")


if __name__ == "__main__":
    sys.exit(main())
