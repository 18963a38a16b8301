"""visualization_msgs/MarkerArray as CDR bytes (little endian, as rmw and rosbag2 write it).

arm_viz and bag_viz write tens of MarkerArrays per second; building rclpy message objects
and serialize_message cost ~10 ms per array on this (loaded) machine. Here the bytes of one
array shape are made once (a template, every number zero) and each array is a copy with its
numbers written in by numpy (tens of µs).
The bytes are checked equal to rclpy's serialize_message in test/test_viz_markers.py.
Layout: XCDR1 (the 4-byte encapsulation header, then every primitive aligned to its size,
counted from the end of that header); strings as uint32 length with the NUL, then the bytes.
"""

from __future__ import annotations

import struct

import numpy as np

from .markers import (
    ARROW,
    ARROW_SCALE,
    MUSCLE_NS,
    MUSCLE_TEXT_HEIGHT,
    MUSCLE_TEXT_LIFETIME,
    MUSCLE_TEXT_RGBA,
    TEXT,
    MarkerFrame,
)

ADD, DELETEALL = 0, 3
_HEADER = b"\x00\x01\x00\x00"  # CDR_LE, no options


class _Buf:
    __slots__ = ("b",)

    def __init__(self):
        self.b = bytearray(_HEADER)

    def align(self, n: int) -> None:
        pad = (-(len(self.b) - 4)) % n
        if pad:
            self.b += b"\x00" * pad

    def u32(self, v: int) -> None:
        self.align(4)
        self.b += struct.pack("<I", v)

    def string(self, s: bytes) -> None:
        self.u32(len(s) + 1)
        self.b += s
        self.b += b"\x00"


def _marker(buf: _Buf, sec: int, nsec: int, frame: bytes, ns: bytes, kind: int, action: int,
            pose: tuple, scale: tuple, rgba: tuple, points: np.ndarray | None,
            text: bytes = b"", lifetime: tuple[int, int] = (0, 0)) -> tuple[int, ...]:
    """Appends one Marker; returns where its stamp, pose (+ scale), colour and points are."""
    buf.align(4)
    at_stamp = len(buf.b)
    buf.b += struct.pack("<iI", sec, nsec)
    buf.string(frame)
    buf.string(ns)
    buf.align(4)
    buf.b += struct.pack("<iii", 0, kind, action)
    buf.align(8)
    at_pose = len(buf.b)
    buf.b += struct.pack("<10d", *pose, *scale)
    at_color = len(buf.b)
    buf.b += struct.pack("<4f", *rgba)  # offset is a multiple of 8 here
    buf.b += struct.pack("<iI?", *lifetime, False)  # lifetime (0 = forever), frame_locked
    at_points = -1
    if points is None:
        buf.u32(0)
    else:
        buf.u32(len(points))
        buf.align(8)
        at_points = len(buf.b)
        buf.b += np.ascontiguousarray(points, "<f8").tobytes()
    buf.u32(0)  # colors
    buf.string(b"")  # texture_resource
    buf.align(4)
    buf.b += struct.pack("<iI", 0, 0)  # texture.header.stamp
    buf.string(b"")  # texture.header.frame_id
    buf.string(b"")  # texture.format
    buf.u32(0)  # texture.data
    buf.u32(0)  # uv_coordinates
    buf.string(text)  # text
    buf.string(b"")  # mesh_resource
    buf.string(b"")  # mesh_file.filename
    buf.u32(0)  # mesh_file.data
    buf.b += b"\x00"  # mesh_use_embedded_materials
    return at_stamp, at_pose, at_color, at_points


_ZERO_POSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


class _Template:
    """The bytes of one MarkerArray shape (names, types, frame, arrows) with every number
    zero, and where the numbers go: each array is then a copy with numpy writes into it.
    The buffer starts 4 bytes early, so the CDR payload's 8-byte alignment is the buffer's
    and the doubles can be written through one float64 view."""

    def __init__(self, frame: MarkerFrame, frame_id: str, delete_all: bool):
        fid = frame_id.encode()
        buf = _Buf()
        buf.u32(len(frame.ns) + len(frame.arrow_ns) + int(delete_all) + int(frame.text is not None))
        stamps, poses, colors, points = [], [], [], []
        if delete_all:
            stamps.append(_marker(buf, 0, 0, fid, b"", 0, DELETEALL, _ZERO_POSE, (0.0, 0.0, 0.0),
                                  (0.0, 0.0, 0.0, 0.0), None)[0])
        for i, ns in enumerate(frame.ns):
            o = _marker(buf, 0, 0, fid, ns.encode(), int(frame.types[i]), ADD, _ZERO_POSE,
                        (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), None)
            stamps.append(o[0])
            poses.append(o[1])
            colors.append(o[2])
        for ns in frame.arrow_ns:
            o = _marker(buf, 0, 0, fid, ns.encode(), ARROW, ADD, _ZERO_POSE, ARROW_SCALE,
                        (0.0, 0.0, 0.0, 0.0), np.zeros((2, 3)))
            stamps.append(o[0])
            colors.append(o[2])
            points.append(o[3])
        self.text_pose = None
        if frame.text is not None:  # its text, orientation, scale and colour are the template's
            o = _marker(buf, 0, 0, fid, MUSCLE_NS.encode(), TEXT, ADD, _ZERO_POSE,
                        (0.0, 0.0, MUSCLE_TEXT_HEIGHT), MUSCLE_TEXT_RGBA, None,
                        frame.text.encode(), MUSCLE_TEXT_LIFETIME)
            stamps.append(o[0])
            self.text_pose = o[1]
        self.size = len(buf.b)
        raw = np.zeros(4 + self.size + (-(4 + self.size)) % 8, np.uint8)
        raw[4:4 + self.size] = np.frombuffer(bytes(buf.b), np.uint8)
        self.raw = raw
        shift = 4
        self.stamp = (np.array(stamps) + shift) // 4
        self.pose = (np.array(poses, int) + shift) // 8
        self.color = (np.array(colors) + shift) // 4
        self.n_shapes = len(frame.ns)
        self.points = (np.array(points, int) + shift) // 8
        if self.text_pose is not None:
            self.text_pose = (self.text_pose + shift) // 8

    def encode(self, frame: MarkerFrame, stamp_ns: int) -> bytes:
        b = self.raw.copy()
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        i32, u32, f32, f64 = b.view("<i4"), b.view("<u4"), b.view("<f4"), b.view("<f8")
        i32[self.stamp] = sec
        u32[self.stamp + 1] = nsec
        n = self.n_shapes
        if n:
            f64[self.pose[:, None] + np.arange(10)] = np.column_stack(
                [frame.positions, frame.orientations, frame.scales])
            f32[self.color[:n, None] + np.arange(4)] = frame.rgba
        if len(self.points):
            f64[self.points[:, None] + np.arange(6)] = frame.arrows.reshape(-1, 6)
            f32[self.color[n:, None] + np.arange(4)] = frame.arrow_rgba
        if self.text_pose is not None:
            f64[self.text_pose + np.arange(3)] = frame.text_position
        return b[4:4 + self.size].tobytes()


_TEMPLATES: dict[tuple, _Template] = {}


def marker_array_cdr(frame: MarkerFrame, frame_id: str, stamp_ns: int,
                     delete_all: bool = False) -> bytes:
    """The serialized MarkerArray of nodes/arm_markers.marker_array (the same message)."""
    key = (frame.ns, tuple(frame.types.tolist()), frame.arrow_ns, frame_id, delete_all,
           frame.text)
    t = _TEMPLATES.get(key)
    if t is None:
        if len(_TEMPLATES) > 16:  # a few models in one process: keep the cache small
            _TEMPLATES.clear()
        t = _TEMPLATES[key] = _Template(frame, frame_id, delete_all)
    return t.encode(frame, stamp_ns)
