"""The one JointState builder of the tests: a message (or its CDR bytes) from a stamp in ns
and arrays, in the model's joint order unless told otherwise."""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence

from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from forearm_dynamics import JOINT_NAMES

_EMPTY: tuple[float, ...] = ()


def joint_state(stamp_ns: int = 0, position: Iterable[float] | None = _EMPTY,
                velocity: Iterable[float] | None = _EMPTY, effort: Iterable[float] | None = _EMPTY,
                *, names: Sequence[str] = JOINT_NAMES, frame_id: str = "humerus") -> JointState:
    """A JointState stamped `stamp_ns`; a None array is an empty one (as the message's default)."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position = _floats(position)
    msg.velocity = _floats(velocity)
    msg.effort = _floats(effort)
    return msg


def _floats(values: Iterable[float] | None) -> list[float]:
    return [] if values is None else [float(x) for x in values]


def joint_state_bytes(stamp_ns: int = 0, position=_EMPTY, velocity=_EMPTY, effort=_EMPTY, *,
                      names: Sequence[str] = JOINT_NAMES, frame_id: str = "humerus") -> bytes:
    """joint_state(...) serialized (CDR), as a bag or a raw subscription holds it."""
    return serialize_message(joint_state(stamp_ns, position, velocity, effort, names=names,
                                         frame_id=frame_id))


def stamp_of(msg) -> int:
    """header.stamp of a stamped message, in ns."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def cdr_stamp(raw: bytes) -> int:
    """header.stamp of a serialized stamped message (4-byte CDR encapsulation, then sec, nanosec)."""
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nsec


def publish_positions(pub, peer, stamps: Sequence[int], q, frame_id: str = "humerus") -> None:
    """Publish one positions-only JointState per stamp (rows of q, the 20 joints), spinning
    the peer 0.5 ms after each (its subscriptions keep up; ~1 kHz at most)."""
    msg = JointState()
    msg.header.frame_id = frame_id
    msg.name = list(JOINT_NAMES)
    for k in range(len(stamps)):
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamps[k]), 1_000_000_000)
        msg.position = q[k].tolist()
        pub.publish(msg)
        peer.spin_for(0.0005)
