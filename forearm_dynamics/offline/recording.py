"""The pipeline's topics out of a bag, as numpy arrays (what check_bag analyses).

JointStates through the one reader (codec/jointstate.py), columns in the requested joint
order by name; the movement markers, the config messages and the load average from
/diagnostics beside them. One pass over the bag reads every topic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from ..bag.reader import Bag
from ..codec.jointstate import JointSeries, JointStateReader
from ..codec.ros import deserialize

JOINT_STATES = "joint_states"
JOINT_TORQUES = "joint_torques"
JOINT_TORQUES_STD = "joint_torques_std"
MOVEMENT = "movement"
CONFIG = "torque_node/config"
DIAGNOSTICS = "/diagnostics"
LOAD_KEY = "load_average_1min"  # put in /diagnostics by the torque node


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
    joint_torques_std: JointSeries | None = None  # effort = 1σ of each torque, if recorded


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
        text = deserialize(msg.data, "String").data
        try:
            config = json.loads(text)
        except ValueError as exc:
            warnings.append(f"unreadable {CONFIG} message ignored ({exc}): {text[:80]!r}")
    return (config if isinstance(config, dict) else None), warnings


def read_recording(bag: Bag, joint_names: tuple[str, ...]) -> Recording:
    """Read joint_states (stamps, position, velocity), joint_torques (stamps, effort), markers."""
    info = bag.info
    chans = {key: info.find_topic(key) for key in (JOINT_STATES, JOINT_TORQUES, MOVEMENT,
                                                    JOINT_TORQUES_STD)}
    diag = next((c for c in info.channels.values() if c.topic == DIAGNOSTICS), None)
    if diag is not None:
        chans[DIAGNOSTICS] = diag
    load: list[float] = []
    ids = {c.id: key for key, c in chans.items() if c is not None}
    where = f"{bag.path}: "
    states = JointStateReader(joint_names, False, where + JOINT_STATES)
    torques = JointStateReader(joint_names, True, where + JOINT_TORQUES)
    stds = JointStateReader(joint_names, True, where + JOINT_TORQUES_STD)
    markers: list[Marker] = []
    warnings: list[str] = []
    for ch, msg in bag.messages([c.topic for c in chans.values() if c is not None]):
        key = ids.get(ch.id)
        if key == JOINT_TORQUES:
            torques.add(msg.data, msg.log_time)
        elif key == JOINT_TORQUES_STD:
            stds.add(msg.data, msg.log_time)
        elif key == JOINT_STATES:
            states.add(msg.data, msg.log_time)
        elif key == MOVEMENT:
            text = deserialize(msg.data, "String").data
            try:
                markers.append(_marker(text))
            except (ValueError, KeyError, TypeError) as exc:
                warnings.append(f"unreadable {key} message ignored ({exc}): {text[:80]!r}")
        elif key == DIAGNOSTICS:
            load += _load_average(msg.data)
    joint_torques = torques.series(JOINT_TORQUES) if chans[JOINT_TORQUES] is not None else None
    if joint_torques is not None and joint_torques.short["effort"]:
        warnings.append(f"{joint_torques.short['effort']} joint_torques messages without one effort "
                        "per name")
    unique = {(m.id, m.t0_ns): m for m in markers}
    return Recording(
        joint_states=states.series(JOINT_STATES) if chans[JOINT_STATES] is not None else None,
        joint_torques=joint_torques,
        markers=sorted(unique.values(), key=lambda m: m.t0_ns),
        warnings=warnings,
        load_average=load,
        joint_torques_std=stds.series(JOINT_TORQUES_STD) if chans[JOINT_TORQUES_STD] is not None else None,
    )


def _load_average(data: bytes) -> list[float]:
    """The torque node's load_average_1min values in one DiagnosticArray (none if absent)."""
    try:
        msg = deserialize(data, "DiagnosticArray")
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
