"""JointState messages of a bag as arrays: the one reader (stamps, log times, frame ids, q, qd, effort).

Fast: the CDR layout of a message shape (names, field counts) is parsed once and checked
against rclpy's deserialiser (jointstate_cdr.py); every later message of that shape is a
cheap shape test while reading, and all of a shape's messages are turned into arrays at
the end through numpy views. Other shapes (big-endian, XCDR2, odd serialisers) go through
rclpy's deserialiser one by one. Columns are put in the requested joint order by name, so a
publisher's own order does not matter; a joint the message lacks is NaN.

`JointStateReader` collects the payloads of one topic as they come (so one pass over a bag
can feed several topics: offline/recording.py); `read_joint_series` reads one topic;
`TorqueReader` keeps only the newest message and decodes it on demand (arm_viz, bag_viz).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BagNoData, ForeignBag, SchemaError
from .jointstate_cdr import Layout, NotMine, parse_layout, verify_layout
from .ros import deserialize

FIELDS = ("position", "velocity", "effort")


@dataclass
class JointSeries:
    """One JointState topic: arrays (N, J) float64 in joint order, NaN where a joint (or the
    whole field: a count that differs from the names) was missing; effort None unless asked."""

    topic: str
    joint_names: tuple[str, ...]
    stamp_ns: np.ndarray  # (N,) int64 header stamps
    log_ns: np.ndarray  # (N,) int64 receive (log) times
    frame_ids: list[str]  # (N,)
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray | None = None
    short: dict[str, int] | None = None  # per field: messages whose count != the names'

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @property
    def has_velocity(self) -> np.ndarray:
        """(N,) bool: every requested joint has a velocity in that message."""
        return np.isfinite(self.velocity).all(axis=1)


def _index(names: tuple[str, ...], joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    pos = {n: i for i, n in enumerate(names)}
    idx = np.array([pos.get(n, -1) for n in joint_names], dtype=np.int64)
    return idx, idx >= 0


@dataclass
class _Plan:
    """One message shape: its layout and where its names go in joint order."""

    layout: Layout
    idx: np.ndarray
    ok: np.ndarray
    full: dict[str, bool]  # field -> its count equals the names'
    frame: str


class JointStateReader:
    """Collects the JointState CDR payloads of one topic (`add`), then `series()`.

    joint_names None: the first message's names (in its order) are the columns.
    where: names the source in error messages ("bag.mcap: /joint_states").
    """

    def __init__(self, joint_names: tuple[str, ...] | None, effort: bool = False, where: str = ""):
        self.joint_names = None if joint_names is None else tuple(joint_names)
        self.effort = effort
        self.where = where
        self._plans: list[_Plan] = []
        self._plan_of: dict[tuple[int, bytes], int] = {}
        self._which: list[int] = []  # per message: plan number, or -1 (decoded by rclpy)
        self._datas: list[bytes] = []
        self._logs: list[int] = []
        self._slow: dict[int, tuple] = {}  # message index -> (stamp, frame, q, v, e, short fields)
        self._last = -1

    def __len__(self) -> int:
        return len(self._which)

    def add(self, data: bytes, log_ns: int) -> None:
        self._logs.append(log_ns)
        last = self._last
        if last >= 0 and self._plans[last].layout.matches(data):
            self._which.append(last)
            self._datas.append(data)
            return
        try:
            pid = self._plan(data)
        except NotMine:
            pid = -1
        self._which.append(pid)
        if pid >= 0:
            self._datas.append(data)
            self._last = pid
            return
        self._datas.append(b"")
        self._slow[len(self._which) - 1] = self._decode(data)

    def _plan(self, data: bytes) -> int:
        lay = parse_layout(data)
        key = (lay.size, bytes(data[12:lay.key_end]))
        pid = self._plan_of.get(key, -1)
        if pid >= 0:
            return pid
        verify_layout(lay, data)
        names = lay.names
        if self.joint_names is None:
            self.joint_names = names
        idx, ok = _index(names, self.joint_names)
        n = len(names)
        full = {"position": lay.n_pos == n, "velocity": lay.n_vel == n, "effort": lay.n_eff == n}
        self._plans.append(_Plan(lay, idx, ok, full, lay.frame_id.decode("utf-8", "replace")))
        pid = self._plan_of[key] = len(self._plans) - 1
        return pid

    def _decode(self, data: bytes) -> tuple:
        try:
            m = deserialize(bytes(data), "JointState")
        except Exception as exc:  # noqa: BLE001 - rclpy raises several types
            raise SchemaError(f"{self.where}: message {len(self._which)} does not decode as "
                              f"JointState ({type(exc).__name__})") from None
        names = tuple(m.name)
        if self.joint_names is None:
            self.joint_names = names
        idx, ok = _index(names, self.joint_names)
        rows, short = [], []
        for f in FIELDS:
            row = np.full(len(self.joint_names), np.nan)
            values = getattr(m, f)
            if len(values) == len(names):
                row[ok] = np.asarray(values, float)[idx[ok]]
            else:
                short.append(f)
            rows.append(row)
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        return (stamp, m.header.frame_id, *rows, short)

    def series(self, topic: str = "") -> JointSeries:
        names = self.joint_names or ()
        n, nj = len(self._which), len(names)
        which = np.array(self._which, dtype=np.int64)
        stamps = np.zeros(n, np.int64)
        frames = [""] * n
        out = {f: np.full((n, nj), np.nan) for f in FIELDS}
        short = dict.fromkeys(FIELDS, 0)
        for pid, plan in enumerate(self._plans):
            rows = np.flatnonzero(which == pid)
            if not len(rows):
                continue
            lay = plan.layout
            buf = np.frombuffer(b"".join([self._datas[i] for i in rows]), np.uint8)
            buf = buf.reshape(len(rows), lay.size)
            stamps[rows] = np.ascontiguousarray(buf[:, 4:8]).view("<i4")[:, 0].astype(np.int64) \
                * 1_000_000_000 + np.ascontiguousarray(buf[:, 8:12]).view("<u4")[:, 0]
            for i in rows:
                frames[i] = plan.frame
            sel = np.flatnonzero(plan.ok)
            for f, (off, count) in (("position", (lay.pos_off, lay.n_pos)),
                                    ("velocity", (lay.vel_off, lay.n_vel)),
                                    ("effort", (lay.eff_off, lay.n_eff))):
                if not plan.full[f]:
                    short[f] += len(rows)
                    continue
                if f == "effort" and not self.effort:
                    continue
                values = np.ascontiguousarray(buf[:, off:off + 8 * count]).view("<f8")
                out[f][np.ix_(rows, sel)] = values[:, plan.idx[sel]]
        for i, (stamp, frame, q, v, e, missing) in self._slow.items():
            stamps[i], frames[i] = stamp, frame
            out["position"][i], out["velocity"][i], out["effort"][i] = q, v, e
            for f in missing:
                short[f] += 1
        return JointSeries(topic, names, stamps, np.array(self._logs, np.int64), frames,
                           out["position"], out["velocity"], out["effort"] if self.effort else None,
                           short)


def read_joint_series(bag, topic: str, joint_names: tuple[str, ...] | None,
                      effort: bool = False) -> JointSeries:
    """Every message of `topic` in `bag` (bag.reader.Bag); ForeignBag if the topic is absent
    or not JointState, BagNoData if it holds no message, SchemaError if one does not decode."""
    ch = find_joint_topic(bag, topic)
    reader = JointStateReader(joint_names, effort, f"{bag.path}: {ch.topic}")
    for _ch, msg in bag.messages([ch.topic]):
        reader.add(msg.data, msg.log_time)
    if not len(reader):
        raise BagNoData(f"{bag.path}: {ch.topic} holds no message"
                        + (f" (truncated: {bag.info.problem})" if not bag.info.complete else ""))
    return reader.series(ch.topic)


def find_joint_topic(bag, topic: str):
    """The channel of `topic` (bag.reader.ChannelInfo); ForeignBag if absent or not JointState."""
    ch = bag.info.find_topic(topic)
    if ch is None:
        raise ForeignBag(f"{bag.path}: no {topic} topic (topics: "
                         f"{', '.join(sorted(bag.info.topic_counts())) or 'none'})")
    if not ch.schema_name.endswith("JointState"):
        raise ForeignBag(f"{bag.path}: {ch.topic} is {ch.schema_name}, not sensor_msgs/msg/JointState")
    return ch


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


class _KeptJointState:
    """The newest JointState of a topic kept as bytes (a 1 kHz topic drawn at 30 Hz decodes
    only what is drawn) and its layout, parsed again only when the bytes' layout changes."""

    def __init__(self):
        self.data: bytes | None = None
        self.seq = 0
        self._layout = None

    def keep(self, data: bytes) -> None:
        self.data = data
        self.seq += 1

    def _read(self) -> tuple[int, tuple[str, ...], np.ndarray, np.ndarray]:
        """(stamp ns, names, positions, efforts) of the kept message: the fast layout when
        the bytes are little-endian CDR as rclpy writes them, else the general decoder."""
        data = self.data
        lay = self._layout
        if lay is None or not lay.matches(data):
            try:
                lay = parse_layout(data)
            except NotMine:
                lay = None
            self._layout = lay
        if lay is not None:
            sec, nsec = np.frombuffer(data, "<i4", 1, 4)[0], np.frombuffer(data, "<u4", 1, 8)[0]
            return (int(sec) * 1_000_000_000 + int(nsec), lay.names, lay.array(data, "position"),
                    lay.array(data, "effort"))
        m = deserialize(data, "JointState")  # big-endian or otherwise unusual bytes
        return (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, tuple(m.name),
                np.array(m.position), np.array(m.effort))


class TorqueReader(_KeptJointState):
    """The newest joint_torques message, decoded on demand in model joint order."""

    def stamp(self) -> int:
        """Header stamp (ns) of the kept message: read from the bytes, nothing decoded."""
        data = self.data
        if bytes(data[:4]) == b"\x00\x01\x00\x00":
            return int.from_bytes(data[4:8], "little", signed=True) * 1_000_000_000 + \
                int.from_bytes(data[8:12], "little")
        m = deserialize(data, "JointState")
        return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec

    def decode(self, joint_names: tuple[str, ...]) -> tuple[int, np.ndarray, np.ndarray]:
        """(stamp ns, q, tau) in joint_names order; ValueError naming what is missing."""
        stamp, names, pos, eff = self._read()
        if len(pos) != len(names) or len(eff) != len(names):
            raise ValueError(f"joint_torques carries {len(names)} names, {len(pos)} positions and "
                             f"{len(eff)} efforts; position and effort are needed for every joint")
        index = {n: i for i, n in enumerate(names)}
        missing = [n for n in joint_names if n not in index]
        if missing:
            raise ValueError(f"joint_torques lacks the model's joint(s) {missing[:3]}")
        cols = [index[n] for n in joint_names]
        return stamp, np.asarray(pos, float)[cols], np.asarray(eff, float)[cols]


class MuscleReader(_KeptJointState):
    """The newest muscle_forces message (muscle_node's output: name = muscles, position =
    activation), kept as bytes and decoded on demand (arm_viz: 30 Hz of a 1 kHz topic)."""

    def decode(self) -> tuple[int, tuple[str, ...], np.ndarray]:
        """(stamp ns, names, activations) of the kept message."""
        stamp, names, pos, _ = self._read()
        return stamp, names, np.asarray(pos, float)
