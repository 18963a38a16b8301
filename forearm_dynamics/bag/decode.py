"""The pipeline's topics out of a bag, as numpy arrays (what check_bag analyses).

JointState payloads are deserialised with rclpy (the same CDR code the nodes use);
columns are put in the requested joint order by name, so a publisher's own order does
not matter. One pass over the bag reads every topic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from .reader import Bag

JOINT_STATES = "joint_states"
JOINT_TORQUES = "joint_torques"
MOVEMENT = "movement"
CONFIG = "torque_node/config"
DIAGNOSTICS = "/diagnostics"
LOAD_KEY = "load_average_1min"  # put in /diagnostics by the torque node


@dataclass
class JointSeries:
    """One JointState topic: header stamps, receive (log) times, arrays in joint order.

    Arrays are (N, J) float64 with NaN where a joint (or the whole field) was missing;
    None when the field was not asked for.
    """

    stamp_ns: np.ndarray  # (N,) int64
    log_ns: np.ndarray  # (N,) int64
    position: np.ndarray | None = None
    velocity: np.ndarray | None = None
    effort: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.stamp_ns)


@dataclass
class Marker:
    """A `movement` message: which movement starts, and its first sample's stamp."""

    id: int
    name: str
    elbow: str
    t0_ns: int
    body_size: object = None
    samples: int | None = None  # as announced by the publisher, if it did
    sensor: dict | None = None  # simulated sensor: noise_deg, publish_velocity, jitter_ms, ...


@dataclass
class Recording:
    joint_states: JointSeries | None
    joint_torques: JointSeries | None
    markers: list[Marker]
    warnings: list[str] = field(default_factory=list)
    load_average: list[float] = field(default_factory=list)  # from /diagnostics, if recorded


class _Collector:
    """Deserialises JointStates; keeps the asked-for fields, columns matched by joint name."""

    def __init__(self, joint_names: tuple[str, ...], fields: tuple[str, ...]):
        self.joint_names = joint_names
        self.fields = fields
        self.stamps: list[int] = []
        self.logs: list[int] = []
        self.rows: dict[str, list[np.ndarray]] = {f: [] for f in fields}
        self._maps: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}
        self.incomplete = dict.fromkeys(fields, 0)  # messages whose field length != names

    def add(self, data: bytes, log_ns: int) -> None:
        msg = deserialize_message(data, JointState)
        st = msg.header.stamp
        self.stamps.append(st.sec * 1_000_000_000 + st.nanosec)
        self.logs.append(log_ns)
        if not self.fields:
            return
        names = tuple(msg.name)
        mapping = self._maps.get(names)
        if mapping is None:
            pos = {n: i for i, n in enumerate(names)}
            idx = np.array([pos.get(n, -1) for n in self.joint_names])
            mapping = self._maps[names] = (idx, idx >= 0)
        idx, ok = mapping
        for f in self.fields:
            values = getattr(msg, f)
            row = np.full(len(self.joint_names), np.nan)
            if len(values) == len(names):
                row[ok] = np.frombuffer(values, dtype=np.float64)[idx[ok]]
            else:
                self.incomplete[f] += 1
            self.rows[f].append(row)

    def series(self) -> JointSeries:
        arrays = {f: np.array(r).reshape(len(r), len(self.joint_names)) for f, r in self.rows.items()}
        return JointSeries(np.array(self.stamps, np.int64), np.array(self.logs, np.int64), **arrays)


def _marker(text: str) -> Marker:
    d = json.loads(text)
    if "t0_ns" in d:
        t0 = int(d["t0_ns"])
    else:
        t0 = round(float(d["t0"]) * 1e9)
    samples = d.get("samples")
    sensor = d.get("sensor")
    return Marker(int(d["id"]), str(d.get("name", "")), str(d.get("elbow", "")), t0,
                  d.get("body_size"), int(samples) if samples is not None else None,
                  sensor if isinstance(sensor, dict) else None)


def read_config(bag: Bag) -> tuple[dict | None, list[str]]:
    """The last torque_node/config JSON of the bag (None if absent), with warnings."""
    ch = bag.info.find_topic(CONFIG)
    if ch is None:
        return None, []
    config, warnings = None, []
    for _ch, msg in bag.messages([ch.topic]):
        text = deserialize_message(msg.data, String).data
        try:
            config = json.loads(text)
        except ValueError as exc:
            warnings.append(f"unreadable {CONFIG} message ignored ({exc}): {text[:80]!r}")
    return (config if isinstance(config, dict) else None), warnings


def read_recording(bag: Bag, joint_names: tuple[str, ...]) -> Recording:
    """Read joint_states (stamps, position, velocity), joint_torques (stamps, effort), markers."""
    info = bag.info
    chans = {key: info.find_topic(key) for key in (JOINT_STATES, JOINT_TORQUES, MOVEMENT)}
    diag = next((c for c in info.channels.values() if c.topic == DIAGNOSTICS), None)
    if diag is not None:
        chans[DIAGNOSTICS] = diag
    load: list[float] = []
    ids = {c.id: key for key, c in chans.items() if c is not None}
    states = _Collector(joint_names, ("position", "velocity"))
    torques = _Collector(joint_names, ("effort",))
    markers: list[Marker] = []
    warnings: list[str] = []
    for ch, msg in bag.messages([c.topic for c in chans.values() if c is not None]):
        key = ids.get(ch.id)
        if key == JOINT_TORQUES:
            torques.add(msg.data, msg.log_time)
        elif key == JOINT_STATES:
            states.add(msg.data, msg.log_time)
        elif key == MOVEMENT:
            text = deserialize_message(msg.data, String).data
            try:
                markers.append(_marker(text))
            except (ValueError, KeyError, TypeError) as exc:
                warnings.append(f"unreadable {key} message ignored ({exc}): {text[:80]!r}")
        elif key == DIAGNOSTICS:
            load += _load_average(msg.data)
    if torques.incomplete["effort"]:
        warnings.append(f"{torques.incomplete['effort']} joint_torques messages without one effort "
                        "per name")
    unique = {(m.id, m.t0_ns): m for m in markers}
    return Recording(
        joint_states=states.series() if chans[JOINT_STATES] is not None else None,
        joint_torques=torques.series() if chans[JOINT_TORQUES] is not None else None,
        markers=sorted(unique.values(), key=lambda m: m.t0_ns),
        warnings=warnings,
        load_average=load,
    )


def _load_average(data: bytes) -> list[float]:
    """The torque node's load_average_1min values in one DiagnosticArray (none if absent)."""
    try:
        msg = deserialize_message(data, DiagnosticArray)
    except Exception:  # noqa: BLE001 - a damaged diagnostics message only loses the load figure
        return []
    out = []
    for status in msg.status:
        for kv in status.values:
            if kv.key == LOAD_KEY:
                try:
                    out.append(float(kv.value))
                except ValueError:
                    pass
    return out
