"""A JointState topic of a bag as arrays, fast: stamps, log times, frame ids, q, qd.

The CDR layout of a message shape (names, field counts) is parsed once and checked
against rclpy's deserialiser (bag/jointstate_cdr.py); every later message of that shape
is read through numpy views. Other shapes (big-endian, XCDR2, odd serialisers) go through
rclpy's deserialiser. Columns are put in the requested joint order by name.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from .errors import BagError
from .jointstate_cdr import NotMine, parse_layout, verify_layout
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
        raise BagError("foreign",
                       f"{bag.path}: {ch.topic} is {ch.schema_name}, not sensor_msgs/msg/JointState")
    nj = len(joint_names)
    plans: list[tuple] = []  # (layout, idx, ok, has_v, frame)
    plan_of: dict[tuple[int, bytes], int] = {}
    which: list[int] = []  # per message: plan number, or -1 (decoded by rclpy)
    datas: list[bytes] = []
    logs: list[int] = []
    slow: dict[int, tuple] = {}  # message index -> (stamp, frame, q, v, e)
    last = -1
    for k, (_ch, msg) in enumerate(bag.messages([ch.topic])):
        data = msg.data
        logs.append(msg.log_time)
        if last >= 0 and plans[last][0].matches(data):
            which.append(last)
            datas.append(data)
            continue
        pid = -1
        try:
            lay = parse_layout(data)
            key = (lay.size, bytes(data[12:lay.key_end]))
            pid = plan_of.get(key, -1)
            if pid < 0:
                verify_layout(lay, data)
                if lay.n_pos != len(lay.names):
                    raise NotMine("position count differs from names")
                idx, ok = _index(lay.names, joint_names)
                plans.append((lay, idx, ok, lay.n_vel == len(lay.names) and ok.all(),
                              lay.n_eff == len(lay.names), lay.frame_id.decode("utf-8", "replace")))
                pid = plan_of[key] = len(plans) - 1
        except NotMine:
            pid = -1
        which.append(pid)
        datas.append(data if pid >= 0 else b"")
        if pid >= 0:
            last = pid
            continue
        try:
            m = deserialize_message(bytes(data), JointState)
        except Exception as exc:  # noqa: BLE001 - rclpy raises several types
            raise BagError("schema", f"{bag.path}: {ch.topic} message {k + 1} does not decode as "
                           f"JointState ({type(exc).__name__})") from None
        idx, ok = _index(tuple(m.name), joint_names)
        q, v, e = np.full(nj, np.nan), np.full(nj, np.nan), np.full(nj, np.nan)
        if len(m.position) == len(m.name):
            q[ok] = np.asarray(m.position, float)[idx[ok]]
        if len(m.velocity) == len(m.name) and ok.all():
            v[:] = np.asarray(m.velocity, float)[idx]
        if len(m.effort) == len(m.name):
            e[ok] = np.asarray(m.effort, float)[idx[ok]]
        slow[k] = (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, m.header.frame_id, q, v, e)
    n = len(which)
    if not n:
        raise BagError("no_data", f"{bag.path}: {ch.topic} holds no message"
                       + (f" (truncated: {bag.info.problem})" if not bag.info.complete else ""))
    which_a = np.array(which)
    stamps = np.zeros(n, np.int64)
    frames = [""] * n
    pos = np.full((n, nj), np.nan)
    vel = np.full((n, nj), np.nan)
    eff = np.full((n, nj), np.nan) if effort else None
    for pid, (lay, idx, ok, has_v, has_e, frame) in enumerate(plans):
        rows = np.flatnonzero(which_a == pid)
        if not len(rows):
            continue
        buf = np.frombuffer(b"".join([datas[i] for i in rows]), np.uint8).reshape(len(rows), lay.size)

        def col(off: int, count: int, buf=buf) -> np.ndarray:
            return np.ascontiguousarray(buf[:, off:off + 8 * count]).view("<f8")

        stamps[rows] = np.ascontiguousarray(buf[:, 4:8]).view("<i4")[:, 0].astype(np.int64) * 1_000_000_000 \
            + np.ascontiguousarray(buf[:, 8:12]).view("<u4")[:, 0]
        for i in rows:
            frames[i] = frame
        sel = np.flatnonzero(ok)
        pos[np.ix_(rows, sel)] = col(lay.pos_off, lay.n_pos)[:, idx[sel]]
        if has_v:
            vel[rows] = col(lay.vel_off, lay.n_vel)[:, idx]
        if effort and has_e:
            eff[np.ix_(rows, sel)] = col(lay.eff_off, lay.n_eff)[:, idx[sel]]
    for i, (stamp, frame, q, v, e) in slow.items():
        stamps[i], frames[i], pos[i], vel[i] = stamp, frame, q, v
        if effort:
            eff[i] = e
    return JointStream(ch.topic, stamps, np.array(logs, np.int64), frames, pos, vel,
                       np.isfinite(vel).all(axis=1), eff)
