"""viz.markers' arrays -> visualization_msgs/MarkerArray objects (rclpy classes).

The live node publishes the CDR bytes of viz/marker_cdr.py (the same message, ~30x cheaper
to make); this builder is the reference those bytes are tested against, and what a Python
user of the node's code gets as a message object.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from visualization_msgs.msg import Marker, MarkerArray

from ..viz.markers import (
    ARROW,
    ARROW_SCALE,
    MUSCLE_NS,
    MUSCLE_TEXT_HEIGHT,
    MUSCLE_TEXT_LIFETIME,
    MUSCLE_TEXT_RGBA,
    TEXT,
    MarkerFrame,
)


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
    if frame.text is not None:
        k = _marker(t, frame_id, MUSCLE_NS, TEXT)
        p = k.pose.position
        p.x, p.y, p.z = (float(v) for v in frame.text_position)
        k.pose.orientation.w = 1.0
        k.scale.z = MUSCLE_TEXT_HEIGHT
        k.color.r, k.color.g, k.color.b, k.color.a = MUSCLE_TEXT_RGBA
        k.text = frame.text
        k.lifetime.sec, k.lifetime.nanosec = MUSCLE_TEXT_LIFETIME
        out.append(k)
    return MarkerArray(markers=out)
