"""A JointState topic of a bag as arrays, fast: stamps, log times, frame ids, q, qd.

The CDR layout of a message shape (names, field counts) is parsed once and checked
against rclpy's deserialiser (nodes/jointstate_cdr.py); every later message of that shape
is read through numpy views. Other shapes (big-endian, XCDR2, odd serialisers) go through
rclpy's deserialiser. Columns are put in the requested joint order by name.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from ..nodes.jointstate_cdr import NotMine, parse_layout, verify_layout
from .errors import BagError
from .reader import Bag


@dataclass
class JointStream:
    topic: str
    stamp_ns: np.ndarray  # (N,) int64
    log_ns: np.ndarray  # (N,) int64
    frame_ids: list[str]  # (N,)
    position: np.ndarray  # (N, J) NaN where a joint is missing
    velocity: np.ndarray  # (N, J) NaN where missing (or the message has no velocities)
    has_velocity: np.ndarray  # (N,) bool: every requested joint has a velocity
    effort: np.ndarray | None = None  # (N, J) NaN where missing; read when asked


def tidy(data: bytes) -> bytes:
    """JointState CDR as rclpy serialises it, without its junk: padding bytes zeroed and the
    spare bytes rclpy's serialiser leaves after an empty sequence cut off (to a multiple of 4,
    as on the wire). Strict readers (rosbags) check the size; unchanged if not parseable."""
    try:
        lay = parse_layout(data)
    except NotMine:
        return data
    end = (lay.meaningful.bit_length() + 7) // 8
    end += -end % 4
    return lay.zero_padding(data)[:end]


def _index(names: tuple[str, ...], joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    pos = {n: i for i, n in enumerate(names)}
    idx = np.array([pos.get(n, -1) for n in joint_names])
    return idx, idx >= 0


def read_joint_stream(bag: Bag, topic: str, joint_names: tuple[str, ...],
                      effort: bool = False) -> JointStream:
    """Every message of `topic`; BagError if it is absent, empty or does not decode."""
    ch = bag.info.find_topic(topic)
    if ch is None:
        raise BagError("foreign", f"{bag.path}: no {topic} topic (topics: "
                       f"{', '.join(sorted(bag.info.topic_counts())) or 'none'})")
    if not ch.schema_name.endswith("JointState"):
        raise BagError("foreign", f"{bag.path}: {ch.topic} is {ch.schema_name}, not sensor_msgs/msg/JointState")
    nj = len(joint_names)
    stamps, logs, frames, rows_q, rows_v, rows_e = [], [], [], [], [], []
    layouts: dict[tuple[int, bytes], tuple] = {}
    last = None
    for k, (_ch, msg) in enumerate(bag.messages([ch.topic]), 1):
        data = msg.data
        plan = None
        if last is not None and last[0].matches(data):
            plan = last
        else:
            try:
                lay = parse_layout(data)
                key = (lay.size, bytes(data[12:lay.key_end]))
                plan = layouts.get(key)
                if plan is None:
                    verify_layout(lay, data)
                    idx, ok = _index(lay.names, joint_names)
                    if lay.n_pos != len(lay.names):
                        raise NotMine("position count differs from names")
                    plan = layouts[key] = (lay, idx, ok, lay.n_vel == len(lay.names) and ok.all(),
                                           lay.frame_id.decode("utf-8", "replace"))
            except NotMine:
                plan = None
        q = np.full(nj, np.nan)
        v = np.full(nj, np.nan)
        e = np.full(nj, np.nan)
        if plan is not None:
            last = plan
            lay, idx, ok, has_v, frame = plan
            pos = np.frombuffer(data, np.float64, lay.n_pos, lay.pos_off)
            q[ok] = pos[idx[ok]]
            if has_v:
                v[:] = np.frombuffer(data, np.float64, lay.n_vel, lay.vel_off)[idx]
            if effort and lay.n_eff == len(lay.names):
                e[ok] = np.frombuffer(data, np.float64, lay.n_eff, lay.eff_off)[idx[ok]]
            sec = int.from_bytes(data[4:8], "little", signed=True)
            nsec = int.from_bytes(data[8:12], "little")
        else:
            try:
                m = deserialize_message(bytes(data), JointState)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types
                raise BagError("schema", f"{bag.path}: {ch.topic} message {k} does not decode as "
                               f"JointState ({type(exc).__name__})") from None
            idx, ok = _index(tuple(m.name), joint_names)
            if len(m.position) == len(m.name):
                q[ok] = np.asarray(m.position, float)[idx[ok]]
            has_v = len(m.velocity) == len(m.name) and ok.all()
            if has_v:
                v[:] = np.asarray(m.velocity, float)[idx]
            if effort and len(m.effort) == len(m.name):
                e[ok] = np.asarray(m.effort, float)[idx[ok]]
            sec, nsec = m.header.stamp.sec, m.header.stamp.nanosec
            frame = m.header.frame_id
        stamps.append(sec * 1_000_000_000 + nsec)
        logs.append(msg.log_time)
        frames.append(frame)
        rows_q.append(q)
        rows_v.append(v)
        if effort:
            rows_e.append(e)
    if not stamps:
        raise BagError("no_data", f"{bag.path}: {ch.topic} holds no message"
                       + (f" (truncated: {bag.info.problem})" if not bag.info.complete else ""))
    vel = np.array(rows_v)
    return JointStream(ch.topic, np.array(stamps, np.int64), np.array(logs, np.int64), frames,
                       np.array(rows_q), vel, np.isfinite(vel).all(axis=1),
                       np.array(rows_e) if effort else None)
