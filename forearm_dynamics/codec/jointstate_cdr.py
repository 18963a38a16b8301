"""sensor_msgs/JointState as CDR bytes: find the layout once, then read and write in place.

Why: on the 1 kHz hot path, turning each incoming message into Python objects (message,
header, 20 name strings, arrays) and each outgoing one back into C structs and CDR cost
more than the inverse dynamics itself (py-spy: `convert_to_py` alone ~13 % of the node's
CPU). With raw subscriptions and raw publishing the node works on the bytes:

- Input: a message's *shape* (frame_id, names, field counts, hence every offset) is
  parsed and checked once against rclpy's own deserialiser, then cached; a message of a
  known shape costs a length check, one masked integer comparison of its leading bytes,
  a 4-byte comparison of the effort count
  (padding ignored: serializers leave junk there) and numpy views at fixed offsets.
  Anything the parser does not vouch for (big-endian or XCDR2 encapsulation, a serializer
  with other conventions, a malformed message) goes through
  `rclpy.serialization.deserialize_message` as before.
- Output: one CDR template per frame_id (20 names, position/velocity/effort, made by
  rclpy's serialiser, checked, padding zeroed), with numpy views on its three arrays; the
  node writes q, qd and the torques straight into it, packs the stamp and publishes
  `bytes(template)`.

Encoding: plain CDR (XCDR1), little endian (encapsulation 00 01 00 00), what Fast DDS
sends for ROS 2 messages. Alignment of n-byte primitives is relative to the payload
(byte 4 of the buffer); a sequence is a uint32 count followed by its elements (float64
elements 8-aligned; an empty sequence has no padding after its count). rclpy's
serialize_message sizes the buffer generously when a sequence is empty: a few trailing
bytes past the last field are accepted (and never read).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .ros import deserialize, message, serialize

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR (XCDR1), little endian
STAMP = struct.Struct("<iI")  # builtin_interfaces/Time at byte 4
_U32 = struct.Struct("<I")
_PAYLOAD = 4  # alignment origin


class NotMine(ValueError):
    """The bytes are not a JointState this parser vouches for (use the generic path)."""


def _align(off: int, n: int) -> int:
    rel = off - _PAYLOAD
    return off + (-rel % n)


@dataclass(frozen=True)
class Layout:
    """Where everything sits in JointState CDR bytes of one shape.

    Padding bytes are not part of a shape: serializers leave whatever was in the buffer
    there (Fast CDR does), so `matches` compares bytes [12:key_end] under `key_mask`
    (frame_id, name counts and strings, the position and velocity counts) as integers,
    and the effort count (after the velocity values) as bytes: without it, one effort
    fewer plus 8 trailing bytes would pass for the cached shape.
    """

    size: int  # total bytes
    key_end: int  # end of the velocity count
    key: int  # bytes [12:key_end] & key_mask, little-endian integer
    key_mask: int
    meaningful: int  # mask of every byte that is not padding (whole message)
    frame_id: bytes  # UTF-8, without the terminating NUL
    names: tuple[str, ...]
    n_pos: int
    pos_off: int
    n_vel: int
    vel_off: int
    n_eff: int
    eff_off: int
    eff_count_off: int  # where the effort count (uint32) sits
    eff_count: bytes  # its 4 bytes

    def matches(self, data: bytes) -> bool:
        """Cheap test that `data` has this shape (stamp, array values and padding aside)."""
        return (len(data) == self.size and data[1] == 1 and data[0] == 0
                and data[self.eff_count_off:self.eff_count_off + 4] == self.eff_count
                and int.from_bytes(data[12:self.key_end], "little") & self.key_mask == self.key)

    def array(self, buf, which: str) -> np.ndarray:
        """numpy view (float64) of position, velocity or effort in `buf` (no copy)."""
        n, off = {"position": (self.n_pos, self.pos_off), "velocity": (self.n_vel, self.vel_off),
                  "effort": (self.n_eff, self.eff_off)}[which]
        return np.frombuffer(buf, dtype=np.float64, count=n, offset=off)

    def zero_padding(self, data) -> bytes:
        """`data` with every padding byte set to zero."""
        return (int.from_bytes(data, "little") & self.meaningful).to_bytes(self.size, "little")


class _Cursor:
    """Reads CDR fields in order and remembers which bytes were meaningful."""

    def __init__(self, data):
        self.data, self.size, self.off = data, len(data), _PAYLOAD
        self.used = bytearray(self.size)
        self.used[:12] = b"\xff" * 12  # encapsulation and stamp

    def take(self, n: int, align: int = 1) -> int:
        """Offset of the next n bytes (after alignment); marks them meaningful."""
        off = _align(self.off, align)
        if off + n > self.size:
            raise NotMine("truncated message")
        self.used[off:off + n] = b"\xff" * n
        self.off = off + n
        return off

    def u32(self) -> int:
        return _U32.unpack_from(self.data, self.take(4, 4))[0]

    def string(self) -> bytes:
        n = self.u32()
        off = self.take(n)
        if n == 0 or self.data[off + n - 1] != 0:
            raise NotMine("bad string")
        return bytes(self.data[off:off + n - 1])

    def float64s(self) -> tuple[int, int]:
        """(count, data offset) of a float64 sequence."""
        n = self.u32()
        if n > self.size:
            raise NotMine("implausible sequence length")
        return n, (self.take(8 * n, 8) if n else self.off)


def parse_layout(data, max_names: int = 1 << 16) -> Layout:
    """Layout of little-endian CDR JointState bytes; NotMine if this parser cannot vouch.

    Costs a Python loop over the names: call it once per shape, then use Layout.matches.
    """
    if len(data) < 16 or bytes(data[:4]) != ENCAPSULATION:
        raise NotMine("not little-endian plain CDR")
    c = _Cursor(data)
    c.take(8)  # stamp
    frame_id = c.string()
    count = c.u32()
    if count > c.size or count > max_names:
        raise NotMine("implausible name count")
    try:
        names = tuple(c.string().decode("utf-8") for _ in range(count))
    except UnicodeDecodeError:
        raise NotMine("name is not UTF-8") from None
    n_pos, pos_off = c.float64s()
    vel_count_end = c.off + (-(c.off - _PAYLOAD) % 4) + 4
    n_vel, vel_off = c.float64s()
    eff_count_off = _align(c.off, 4)
    n_eff, eff_off = c.float64s()
    if c.size - c.off > 32:  # serializers may size the buffer generously, not this much
        raise NotMine("unexpected trailing bytes")
    key_mask = bytearray(c.used[12:vel_count_end])
    for off, n in ((pos_off, n_pos), (vel_off, n_vel)):  # array values are not the shape
        lo, hi = max(off - 12, 0), min(off + 8 * n - 12, len(key_mask))
        key_mask[lo:hi] = bytes(max(hi - lo, 0))
    mask = int.from_bytes(key_mask, "little")
    return Layout(size=c.size, key_end=vel_count_end,
                  key=int.from_bytes(data[12:vel_count_end], "little") & mask, key_mask=mask,
                  meaningful=int.from_bytes(c.used, "little"), frame_id=frame_id, names=names,
                  n_pos=n_pos, pos_off=pos_off, n_vel=n_vel, vel_off=vel_off, n_eff=n_eff,
                  eff_off=eff_off, eff_count_off=eff_count_off,
                  eff_count=bytes(data[eff_count_off:eff_count_off + 4]))


def aligned_buffer(size: int) -> np.ndarray:
    """Zeroed uint8 buffer whose CDR float64 fields are 8-byte aligned in memory.

    Every float64 array of a message sits at an offset = 4 (mod 8) (8-aligned relative to
    the payload, which starts at byte 4), so shifting the buffer's start to an address = 4
    (mod 8) aligns all of them: numpy and Pinocchio (eigenpy) then work on them directly.
    A `bytearray` would leave them misaligned.
    """
    raw = np.zeros(size + 8, dtype=np.uint8)
    shift = (_PAYLOAD - raw.ctypes.data) % 8
    return raw[shift:shift + size]


def _same(a, b) -> bool:
    """Equal float arrays, NaN equal to NaN."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


def verify_layout(lay: Layout, data) -> None:
    """Check `lay` field by field against rclpy's deserialiser; NotMine if they disagree."""
    msg = deserialize(bytes(data), "JointState")
    sec, nsec = STAMP.unpack_from(data, 4)
    ok = (
        (msg.header.stamp.sec, msg.header.stamp.nanosec) == (sec, nsec)
        and msg.header.frame_id.encode("utf-8") == lay.frame_id
        and tuple(msg.name) == lay.names
        and _same(msg.position, lay.array(data, "position"))
        and _same(msg.velocity, lay.array(data, "velocity"))
        and _same(msg.effort, lay.array(data, "effort"))
    )
    if not ok:
        raise NotMine("layout disagrees with rclpy's deserialiser")


def verified_layout(data) -> Layout:
    """parse_layout, checked against rclpy's deserialiser."""
    lay = parse_layout(data)
    verify_layout(lay, data)
    return lay


class OutputTemplate:
    """CDR bytes of an output JointState with writable views on its arrays.

    `q`, `qd`, `effort` are float64 views into `buf` (`effort` empty when effort=False,
    `qd` empty when velocity=False: a positions-only sensor stream);
    `pack_stamp(sec, nsec)` writes the header stamp; `payload()` is what to publish.
    """

    def __init__(self, joint_names, frame_id: str = "", effort: bool = True, velocity: bool = True):
        n = len(joint_names)
        msg = message("JointState")()
        msg.header.frame_id = frame_id
        msg.name = list(joint_names)
        # distinct values so the check below proves each view points at its own field
        msg.position = [1.0 + i for i in range(n)]
        msg.velocity = [-1.0 - i for i in range(n)] if velocity else []
        msg.effort = [math.pi * (i + 1) for i in range(n)] if effort else []
        raw = serialize(msg)
        self.layout = lay = verified_layout(raw)
        if (lay.names != tuple(joint_names) or lay.n_pos != n or lay.n_vel != (n if velocity else 0)
                or lay.n_eff != (n if effort else 0)):
            raise NotMine("output template does not hold the joint names")
        self.frame_id = lay.frame_id
        # what the serializer left in the padding (and past the end) is not ours to send
        self.buf = aligned_buffer(lay.size)
        memoryview(self.buf)[:] = lay.zero_padding(raw)
        self.q = lay.array(self.buf, "position")
        self.qd = lay.array(self.buf, "velocity")
        self.effort = lay.array(self.buf, "effort")
        self.q.fill(0.0)
        self.qd.fill(0.0)
        self.effort.fill(0.0)
        self._pack = STAMP.pack_into

    def pack_stamp(self, sec: int, nsec: int) -> None:
        self._pack(self.buf, 4, sec, nsec)

    def payload(self) -> bytes:
        return self.buf.tobytes()


class StdTemplate:
    """CDR bytes of a JointState with names and effort only (joint_torques_std: position and
    velocity empty, effort = 1σ per torque); `fill(sec, nsec, std)` writes stamp and effort
    and returns the payload."""

    def __init__(self, joint_names, frame_id: str = ""):
        n = len(joint_names)
        msg = message("JointState")()
        msg.header.frame_id = frame_id
        msg.name = list(joint_names)
        msg.effort = [float(i + 1) for i in range(n)]
        raw = serialize(msg)
        lay = verified_layout(raw)
        if lay.names != tuple(joint_names) or lay.n_pos or lay.n_vel or lay.n_eff != n:
            raise NotMine("std template does not hold the joint names")
        self.buf = aligned_buffer(lay.size)
        memoryview(self.buf)[:] = lay.zero_padding(raw)
        self.effort = lay.array(self.buf, "effort")
        self.effort.fill(0.0)
        self._pack = STAMP.pack_into
        # rclpy's serialiser leaves spare bytes after the empty position/velocity sequences;
        # strict readers (rosbags) check the size: the payload ends where the message does
        end = (lay.meaningful.bit_length() + 7) // 8
        self._end = end + (-end % 4)

    def fill(self, sec: int, nsec: int, std) -> bytes:
        np.copyto(self.effort, std)
        return self.stamped(sec, nsec)

    def stamped(self, sec: int, nsec: int) -> bytes:
        """The payload with this stamp and the efforts already written into `effort`."""
        self._pack(self.buf, 4, sec, nsec)
        return self.buf[:self._end].tobytes()
