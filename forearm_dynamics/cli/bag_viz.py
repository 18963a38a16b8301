"""bag_viz: a copy of a bag with the arm drawn in it (arm_markers, robot_description).

    bag_viz IN.mcap OUT.mcap [--rate-hz 30] [--arrows] [--arrow-scale M_PER_NM] [--overwrite]

Every message of IN is copied as it is (same channels, schemas, QoS metadata, log times);
added: `arm_markers` (visualization_msgs/MarkerArray, as arm_viz draws it) at most every
1/rate_hz of joint_torques header time — the first joint_torques at or after each
1/rate_hz step gets one, at its own log time and stamped with its stamp, so every
joint_torques has a MarkerArray within 1/rate before it — and `robot_description` (the
URDF, transient local) at the start and whenever the model changes. The model is the one
of the torque node's config in force at each stamp (live changes followed), or the
default model when the bag has none (said). The new topics go beside joint_torques
(/ns/joint_torques -> /ns/arm_markers). Open OUT in Foxglove with
config/foxglove_layout.json (docs/visualisation.md).

Exit codes: 0 written; 2 (USAGE) unreadable IN, no joint_torques, OUT exists (without
--overwrite) or is IN: one line, no traceback, OUT never left half-written.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import time
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from zstandard import ZstdError

from ..bag import BagWriter, TopicQos, open_bag
from ..bag.augment import NotIndexed, augment
from ..codec import ros
from ..codec.jointstate import TorqueReader
from ..errors import BagError, ForeignBag
from ..exit_codes import OK
from ..model_config import config_in_force, model_from_config
from ..viz import ArmScene, MarkerMaker, TorqueColours
from ..viz.marker_cdr import marker_array_cdr
from .common import die

PROG = "bag_viz"
CONFIG = "torque_node/config"


def parse_args(argv):
    head, _, rest = __doc__.partition("\n\n")
    ap = argparse.ArgumentParser(prog=PROG, description=head, epilog=rest,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", type=Path, help="MCAP bag with joint_torques")
    ap.add_argument("output", type=Path, help="the copy to write, with arm_markers")
    ap.add_argument("--rate-hz", type=float, default=30.0, help="marker rate (default 30)")
    ap.add_argument("--arrows", action="store_true", help="torque arrows along the joint axes")
    ap.add_argument("--arrow-scale", type=float, default=0.05, help="arrow m per N·m (0.05)")
    ap.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")
    args = ap.parse_args(argv)
    if not args.rate_hz > 0:
        ap.error(f"--rate-hz must be > 0, got {args.rate_hz}")
    return args


class _Models:
    """The drawn model in force at a stamp: the bag's configs (live changes), built once each."""

    def __init__(self, configs: list[tuple[int, dict]], args):
        self.configs, self.args = configs, args
        self._built: dict[str, tuple[MarkerMaker, str]] = {}
        self._keys: dict[int, str] = {}
        self.warnings: list[str] = []

    def at(self, stamp_ns: int) -> tuple[str, MarkerMaker, str]:
        cfg = config_in_force(self.configs, stamp_ns)
        if cfg is not None and id(cfg) in self._keys:
            return (self._keys[id(cfg)], *self._built[self._keys[id(cfg)]])
        key = "" if cfg is None else json.dumps({k: cfg.get(k) for k in sorted(cfg)
                                                 if k not in ("config_id", "applies_from_stamp_ns",
                                                              "build_ms")}, sort_keys=True)
        if cfg is not None:
            self._keys[id(cfg)] = key  # the configs live as long as this object
        if key not in self._built:
            try:
                choice = model_from_config(cfg)
            except ValueError as exc:
                raise ForeignBag(f"{CONFIG} names a model that cannot be built ({exc})") from None
            self.warnings += choice.warnings
            arm = choice.arm
            scene = ArmScene(arm)
            maker = MarkerMaker(scene, TorqueColours(arm.joint_names), arrows=self.args.arrows,
                                arrow_scale=self.args.arrow_scale)
            self._built[key] = (maker, arm.to_urdf())
        return (key, *self._built[key])


class _Drawer:
    """Chooses the joint_torques to draw (the first at or after each 1/rate of log time) and
    makes their MarkerArray (and a robot_description when the model changes)."""

    def __init__(self, args, models: _Models, torque_channel: int, source: str):
        self.models, self.channel, self.source = models, torque_channel, source
        self.period = round(1e9 / args.rate_hz)
        self.next_ns: int | None = None
        self.current: str | None = None
        self.reader = TorqueReader()
        self.counts = [0, 0]

    def reset(self) -> None:
        self.next_ns, self.current, self.counts = None, None, [0, 0]

    def due(self, log_time: int) -> bool:
        return self.next_ns is None or log_time >= self.next_ns

    def draw(self, log_time: int, data: bytes) -> list[tuple[int, int, bytes]]:
        """[(0 markers | 1 description, log time, bytes)] for the torque message `data`."""
        self.reader.keep(data)
        stamp = self.reader.stamp()
        key, maker, urdf = self.models.at(stamp)
        out = []
        if key != self.current:
            out.append((1, log_time, ros.serialize(ros.message("String")(data=urdf))))
        try:
            _, q, tau = self.reader.decode(maker.scene.joint_names)
            frame = maker.frame(q, tau)
        except ValueError as exc:
            raise ForeignBag(f"{self.source}: joint_torques at stamp {stamp}: {exc}") from None
        out.append((0, log_time, marker_array_cdr(frame, maker.scene.root_frame, stamp,
                                                  key != self.current)))
        self.current = key
        self.next_ns = log_time + self.period
        for k, *_ in out:
            self.counts[k] += 1
        return out

    def visit(self, view, _channels) -> list[tuple[int, int, bytes]]:
        out = []
        index = view.index.get(self.channel)
        if index is None or not len(index):
            return out
        index = index[np.argsort(index[:, 0], kind="stable")]
        times = index[:, 0].astype(np.int64)
        k = 0
        while k < len(times):
            if not self.due(int(times[k])):  # jump to the next message that is due
                k += int(np.searchsorted(times[k:], self.next_ns, side="left"))
                continue
            out += self.draw(int(times[k]), view.payload(int(index[k, 1])))
            k += 1
        return out


def _copy_by_message(bag, info, path: Path, topics, drawer: _Drawer) -> None:
    """The general path (a bag without message indexes): every message read and written."""
    with BagWriter(path, overwrite=True) as w:
        out_ch = {}
        for ch in info.channels.values():
            sid = w.add_schema(ch.schema_name, ch.schema_encoding, ch.schema_data)
            out_ch[ch.id] = w.add_channel(ch.topic, sid, ch.schema_name, ch.metadata,
                                          ch.message_encoding)
        added = [w.add_topic(t, type_name, qos) for t, type_name, qos in topics]
        for ch, msg in bag.messages():
            w.write(out_ch[ch.id], msg.data, msg.log_time, msg.publish_time)
            if ch.id == drawer.channel and drawer.due(msg.log_time):
                for k, log_time, data in drawer.draw(msg.log_time, bytes(msg.data)):
                    w.write(added[k], data, log_time)


def bag_viz(args) -> dict:
    src, dst = args.input.resolve(), args.output.resolve()
    if src == dst:
        raise ValueError(f"{args.output} is the input bag; write the copy elsewhere")
    bag = open_bag(args.input)
    info = bag.info
    torques = info.find_topic("joint_torques")
    if torques is None or info.counts.get(torques.id, 0) == 0:
        raise ForeignBag(f"{args.input}: no joint_torques messages (topics: "
                       f"{', '.join(sorted(info.topic_counts())) or 'none'})")
    configs = []
    cfg_ch = info.find_topic(CONFIG)
    if cfg_ch is not None:
        for _ch, msg in bag.messages([cfg_ch.topic]):
            try:
                cfg = json.loads(ros.deserialize(msg.data, "String").data)
            except ValueError:
                continue
            if isinstance(cfg, dict):
                configs.append((msg.log_time, cfg))
    models = _Models(configs, args)
    base = torques.topic[: -len("joint_torques")]
    if args.output.exists() and not args.overwrite:
        raise ValueError(f"{args.output} exists (give --overwrite to replace it)")
    tmp = args.output.with_name(args.output.name + ".part")
    drawer = _Drawer(args, models, torques.id, f"{args.input}")
    topics = [(base + "arm_markers", "visualization_msgs/msg/MarkerArray", TopicQos(depth=10)),
              (base + "robot_description", "std_msgs/msg/String",
               TopicQos(depth=1, durability="transient_local"))]
    t_start = time.perf_counter()
    try:
        try:
            augment(args.input, tmp, topics, drawer.visit, overwrite=True)
            written = {"path": "chunks"}
        except (NotIndexed, McapError, ZstdError, struct.error, EOFError):
            # no indexes, or damage the container reader can tell apart: the general path
            drawer.reset()
            _copy_by_message(bag, info, tmp, topics, drawer)
            written = {"path": "messages"}
        tmp.replace(args.output)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    written.update({"copied": info.message_count, "arm_markers": drawer.counts[0],
                    "robot_description": drawer.counts[1]})
    written["seconds"] = time.perf_counter() - t_start
    written["bag_seconds"] = (info.end_ns - info.start_ns) / 1e9
    written["warnings"] = models.warnings
    return written


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        out = bag_viz(args)
    except (BagError, OSError, ValueError) as exc:
        return die(f"{PROG}: error: {exc}")
    for w in out["warnings"]:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    speed = out["bag_seconds"] / out["seconds"] if out["seconds"] > 0 else float("inf")
    print(f"{PROG}: wrote {args.output}: {out['copied']} messages copied (by {out['path']}), "
          f"{out['arm_markers']} "
          f"arm_markers, {out['robot_description']} robot_description; {out['seconds']:.2f} s for "
          f"{out['bag_seconds']:.1f} s of bag ({speed:.0f}x real time, load "
          f"{os.getloadavg()[0]:.1f})", file=sys.stderr)
    return OK


if __name__ == "__main__":
    sys.exit(main())
