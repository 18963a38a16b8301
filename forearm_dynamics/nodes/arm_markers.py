"""viz.markers' arrays -> visualization_msgs/MarkerArray objects (rclpy classes), and the
joint_torques reader arm_viz and bag_viz share.

The live node publishes the CDR bytes of viz/marker_cdr.py (the same message, ~30x cheaper
to make); this builder is the reference those bytes are tested against, and what a Python
user of the node's code gets as a message object.
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from visualization_msgs.msg import Marker, MarkerArray

from ..bag.jointstate_cdr import NotMine, parse_layout
from ..viz.markers import ARROW, ARROW_SCALE, MarkerFrame


def stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _marker(t: Time, frame_id: str, ns: str, kind: int, action: int = Marker.ADD) -> Marker:
    k = Marker(ns=ns, id=0, type=kind, action=action)
    k.header.frame_id = frame_id
    k.header.stamp = t
    return k


def marker_array(frame: MarkerFrame, frame_id: str, stamp_ns: int,
                 delete_all: bool = False) -> MarkerArray:
    """One array; delete_all first clears what an earlier model drew (a link that is gone,
    e.g. a payload set to 0 kg, must not stay on screen)."""
    t = stamp(stamp_ns)
    out = [_marker(t, frame_id, "", 0, Marker.DELETEALL)] if delete_all else []
    for i, ns in enumerate(frame.ns):
        k = _marker(t, frame_id, ns, int(frame.types[i]))
        p, o = k.pose.position, k.pose.orientation
        p.x, p.y, p.z = (float(v) for v in frame.positions[i])
        o.x, o.y, o.z, o.w = (float(v) for v in frame.orientations[i])
        k.scale.x, k.scale.y, k.scale.z = (float(v) for v in frame.scales[i])
        k.color.r, k.color.g, k.color.b, k.color.a = (float(v) for v in frame.rgba[i])
        out.append(k)
    for i, ns in enumerate(frame.arrow_ns):
        k = _marker(t, frame_id, ns, ARROW)
        k.scale.x, k.scale.y, k.scale.z = ARROW_SCALE
        k.color.r, k.color.g, k.color.b, k.color.a = (float(v) for v in frame.arrow_rgba[i])
        k.points = [Point(x=float(a[0]), y=float(a[1]), z=float(a[2])) for a in frame.arrows[i]]
        out.append(k)
    return MarkerArray(markers=out)


class TorqueReader:
    """The newest joint_torques message, decoded on demand in model joint order."""

    def __init__(self):
        self.data: bytes | None = None
        self.seq = 0
        self._layout = None

    def keep(self, data: bytes) -> None:
        self.data = data
        self.seq += 1

    def stamp(self) -> int:
        """Header stamp (ns) of the kept message: read from the bytes, nothing decoded."""
        data = self.data
        if bytes(data[:4]) == b"\x00\x01\x00\x00":
            return int.from_bytes(data[4:8], "little", signed=True) * 1_000_000_000 + \
                int.from_bytes(data[8:12], "little")
        m = deserialize_message(data, JointState)
        return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec

    def decode(self, joint_names: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray]:
        """(stamp ns, q, tau) in joint_names order; ValueError naming what is missing."""
        data = self.data
        lay = self._layout
        if lay is None or not lay.matches(data):
            try:
                lay = parse_layout(data)
            except NotMine:
                lay = None
            self._layout = lay
        if lay is not None:
            names, pos, eff = lay.names, lay.array(data, "position"), lay.array(data, "effort")
            sec, nsec = np.frombuffer(data, "<i4", 1, 4)[0], np.frombuffer(data, "<u4", 1, 8)[0]
            stamp = int(sec) * 1_000_000_000 + int(nsec)
        else:  # big-endian or otherwise unusual bytes: the general decoder
            m = deserialize_message(data, JointState)
            names, pos, eff = tuple(m.name), np.array(m.position), np.array(m.effort)
            stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        if len(pos) != len(names) or len(eff) != len(names):
            raise ValueError(f"joint_torques carries {len(names)} names, {len(pos)} positions and "
                             f"{len(eff)} efforts; position and effort are needed for every joint")
        index = {n: i for i, n in enumerate(names)}
        missing = [n for n in joint_names if n not in index]
        if missing:
            raise ValueError(f"joint_torques lacks the model's joint(s) {missing[:3]}")
        cols = [index[n] for n in joint_names]
        return stamp, np.asarray(pos, float)[cols], np.asarray(eff, float)[cols]
