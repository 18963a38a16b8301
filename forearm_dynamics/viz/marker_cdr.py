"""visualization_msgs/MarkerArray as CDR bytes (little endian, as rmw and rosbag2 write it).

bag_viz writes tens of MarkerArrays per second of bag; building rclpy message objects and
serialize_message costs ~10 ms per array on this machine, this ~0.3 ms (benchmarks/viz.py).
The bytes are checked equal to rclpy's serialize_message in test/test_viz_markers.py.
Layout: XCDR1 (the 4-byte encapsulation header, then every primitive aligned to its size,
counted from the end of that header); strings as uint32 length with the NUL, then the bytes.
"""

from __future__ import annotations

import struct

import numpy as np

from .markers import ARROW, ARROW_SCALE, MarkerFrame

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
            pose: tuple, scale: tuple, rgba: tuple, points: np.ndarray | None) -> None:
    buf.align(4)
    buf.b += struct.pack("<iI", sec, nsec)
    buf.string(frame)
    buf.string(ns)
    buf.align(4)
    buf.b += struct.pack("<iii", 0, kind, action)
    buf.align(8)
    buf.b += struct.pack("<10d", *pose, *scale)
    buf.b += struct.pack("<4f", *rgba)  # offset is a multiple of 8 here
    buf.b += struct.pack("<iI?", 0, 0, False)  # lifetime (0 = forever), frame_locked
    if points is None:
        buf.u32(0)
    else:
        buf.u32(len(points))
        buf.align(8)
        buf.b += np.ascontiguousarray(points, "<f8").tobytes()
    buf.u32(0)  # colors
    buf.string(b"")  # texture_resource
    buf.align(4)
    buf.b += struct.pack("<iI", 0, 0)  # texture.header.stamp
    buf.string(b"")  # texture.header.frame_id
    buf.string(b"")  # texture.format
    buf.u32(0)  # texture.data
    buf.u32(0)  # uv_coordinates
    buf.string(b"")  # text
    buf.string(b"")  # mesh_resource
    buf.string(b"")  # mesh_file.filename
    buf.u32(0)  # mesh_file.data
    buf.b += b"\x00"  # mesh_use_embedded_materials


_ZERO_POSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def marker_array_cdr(frame: MarkerFrame, frame_id: str, stamp_ns: int,
                     delete_all: bool = False) -> bytes:
    """The serialized MarkerArray of nodes/arm_markers.marker_array (same bytes)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    fid = frame_id.encode()
    buf = _Buf()
    n = len(frame.ns) + len(frame.arrow_ns) + int(delete_all)
    buf.u32(n)
    if delete_all:
        _marker(buf, sec, nsec, fid, b"", 0, DELETEALL, _ZERO_POSE, (0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0, 0.0), None)
    poses = np.column_stack([frame.positions, frame.orientations]).tolist()
    scales, rgba, types = frame.scales.tolist(), frame.rgba.tolist(), frame.types.tolist()
    for i, ns in enumerate(frame.ns):
        _marker(buf, sec, nsec, fid, ns.encode(), types[i], ADD, poses[i], scales[i], rgba[i],
                None)
    if frame.arrow_ns:
        arrow_rgba = frame.arrow_rgba.tolist()
        for i, ns in enumerate(frame.arrow_ns):
            _marker(buf, sec, nsec, fid, ns.encode(), ARROW, ADD, _ZERO_POSE, ARROW_SCALE,
                    arrow_rgba[i], frame.arrows[i])
    return bytes(buf.b)
