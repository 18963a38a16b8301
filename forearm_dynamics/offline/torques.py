"""bag_torques' work: joint torques for every joint_states sample of a bag, in batch.

The samples go through the torque node's stamp rules (stream_node.py): a stamp that does
not increase by more than `max_stamp_gap` backwards is dropped (counted), a step larger
than `max_stamp_gap` either way starts a new segment (the estimator warms up again).
Estimators: any of the torque node's (estimation.ESTIMATORS, default the node's default):
the same update() calls the node makes, sample by sample, so the same numbers as a
torque_node given the same stream ('backward' through estimation/offline.backward_batch,
vectorised, bit for bit the same), or 'zero_phase' (offline: 6 Hz forward-backward
low-pass, derivatives of the filtered positions). Torques: ArmModel.inverse_dynamics_batch.

The output bag holds every message of the input (same channels, QoS, log times) plus
`joint_torques` (JointState in the model's joint order: position, velocity as used, effort;
header copied from the input; log time = the input's), `joint_torques_std` beside it (same
header and names, effort = 1σ per torque, inf while warming up: the node's publish_std, for
estimators with a covariance; bag_torques --no-std leaves it out) and a `torque_node/config`
JSON like the node's, naming model, body size, estimator and what the σ contains, so
check_bag can rebuild the model and score the σ.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import model_config
from ..bag.reader import open_bag
from ..bag.recover import copy_layout, custom_data
from ..bag.rosbag2_meta import TopicQos
from ..bag.writer import BagWriter
from ..codec.jointstate import JointSeries, read_joint_series
from ..codec.jointstate_cdr import OutputTemplate, StdTemplate
from ..codec.ros import message, serialize
from ..dynamics import ArmModel
from ..errors import ForeignBag, OutputExists, UsageError
from ..estimation import DEFAULT_ESTIMATOR, make_estimator
from ..estimation import ESTIMATORS as NODE_ESTIMATORS
from ..estimation.offline import backward_batch, segments, zero_phase
from ..filtering import analysis_config
from ..ranges import check_recording
from ..uncertainty import NoCovariance, TorqueStd
from ..version import package_version

#: The node's estimators, then the offline zero-phase one.
ESTIMATORS = (*NODE_ESTIMATORS, "zero_phase")


@dataclass
class OfflineResult:
    stamps_ns: np.ndarray
    log_ns: np.ndarray
    frame_ids: list[str]
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    dropped: int = 0  # samples the node's stamp rules reject
    segments: int = 1
    warnings: list[str] = field(default_factory=list)
    compute_s: float = 0.0
    std: np.ndarray | None = None  # (N, n) 1σ per torque (inf while warming up), as the node's
    std_config: dict = field(default_factory=lambda: {"published": False, "why": "not asked for"})


def stamp_rules(stamps_ns: np.ndarray, max_gap_ns: int) -> np.ndarray:
    """Mask of the samples a torque node keeps: zero stamps and stamps that do not advance
    (within max_gap backwards: duplicates, reordering) are dropped; larger jumps are kept."""
    s = np.asarray(stamps_ns, np.int64)
    keep = s > 0
    d = np.diff(s)
    if keep.all() and (d > 0).all():
        return keep
    last = None
    for i in range(len(s)):
        if not keep[i]:
            continue
        if last is not None and -max_gap_ns <= s[i] - last <= 0:
            keep[i] = False
            continue
        last = s[i]
    return keep


def compute(stream: JointSeries, arm: ArmModel, estimator: str = DEFAULT_ESTIMATOR,
            settings: dict | None = None, max_gap_s: float = 0.1,
            cutoff_hz: float | None = None, std: bool = True, subject: str = "none") -> OfflineResult:
    """Torques of every kept sample; BagError when a joint of the model is never given.

    std: also the σ of every torque (uncertainty.TorqueStd, the node's publish_std: same
    numbers, inf while the estimate warms up) when the estimator carries a covariance;
    `std_config` says what it contains or why there is none. subject: the σ's subject part,
    "none" or "ansur" (the node's subject_std; uncertainty/subject.py)."""
    if estimator not in ESTIMATORS:
        raise UsageError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    missing = [n for j, n in enumerate(arm.joint_names) if not np.isfinite(stream.position[:, j]).any()]
    if missing:
        raise ForeignBag(f"{stream.topic} has no position for {', '.join(missing[:4])}"
                       f"{' ...' if len(missing) > 4 else ''}: not this model's joints")
    gap = round(max_gap_s * 1e9)
    keep = stamp_rules(stream.stamp_ns, gap)
    finite = np.isfinite(stream.position).all(axis=1)
    warnings = []
    if not finite.all():
        warnings.append(f"{int((~finite).sum())} samples without a finite position for every "
                        "joint dropped (as the node rejects them)")
    keep &= finite
    dropped = int((~keep).sum())
    idx = np.flatnonzero(keep)
    t, q = stream.stamp_ns[idx], stream.position[idx]
    units = check_recording(q, arm.joint_names, source=f"{stream.topic} positions")
    if units.refusal:  # degrees as radians (or radians twice): torques of nothing real
        raise UsageError(units.refusal + "; nothing written")
    warnings += units.warnings
    has_v = stream.has_velocity[idx]
    start = time.perf_counter()
    std_out, std_config = None, {"published": False, "why": "not asked for (--no-std)"}
    if std and estimator in ("zero_phase", "backward"):
        std_config = {"published": False, "why": f"estimator {estimator!r} carries no covariance: "
                      "no torque σ (use estimator kalman)"}
    if estimator == "zero_phase":
        q, qd, qdd = zero_phase(t, q, cutoff_hz, gap)
    elif estimator == "backward" and (has_v.all() or not has_v.any()):
        qd, qdd, _warm = backward_batch(t, q, stream.velocity[idx] if has_v.all() else None, settings, gap)
    else:  # the estimator sample by sample, as the node: q and qd as it estimates them
        est = make_estimator(estimator, arm.nv, settings or {})
        ts = None
        if std:
            try:
                ts = TorqueStd(arm, est, subject=subject)
            except NoCovariance as exc:
                std_config = {"published": False, "why": str(exc)}
            else:
                std_config = {"published": True, **ts.parts()}
        q, qd, qdd = q.copy(), np.zeros_like(q), np.zeros_like(q)
        std_out = np.full_like(q, np.inf) if ts is not None else None
        last = None
        for k in range(len(t)):
            if last is not None and not 0 < t[k] - last <= gap:
                est.reset()
                if ts is not None:
                    ts.reset()
            last = t[k]
            vel = bool(has_v[k])
            warm = est.update(int(t[k]), q[k], stream.velocity[idx[k]] if vel else None)
            q[k], qd[k], qdd[k] = est.q, est.qd, est.qdd
            if ts is not None and ts.update(int(t[k]), vel) and warm:
                std_out[k] = ts.std
    tau = arm.inverse_dynamics_batch(q, qd, qdd)
    elapsed = time.perf_counter() - start
    return OfflineResult(t, stream.log_ns[idx], [stream.frame_ids[i] for i in idx], q, qd, qdd, tau,
                         dropped, len(segments(t, gap)), warnings, elapsed, std_out, std_config)


def config_message(arm: ArmModel, estimator: str, settings: dict | None, src: Path,
                   input_topic: str, output_topic: str, max_gap_s: float,
                   cutoff_hz: float | None, dt_s: float = 1e-3,
                   velocity_given: bool = False) -> dict:
    """What the torque node states on torque_node/config, for an offline run: the estimator
    described at the bag's own sample period `dt_s` (its lags depend on it), as the node
    describes it at the period it receives."""
    if estimator == "zero_phase":
        desc = {"method": "zero_phase", "settings": {"cutoff_hz": float(
            cutoff_hz if cutoff_hz is not None else analysis_config()["filter"]["cutoff_hz"])},
            "lag_s": {"q": 0.0, "qd": 0.0, "qdd": 0.0}, "offline": True}
    else:
        desc = make_estimator(estimator, arm.nv, settings or {}).describe(dt_s, velocity_given)
    return model_config.config_message(
        model_config.model_config(arm), node="bag_torques", version=package_version(),
        estimator=desc, input_topic=input_topic, output_topic=output_topic,
        max_stamp_gap=max_gap_s, source_bag=str(src))


def write_bag(src: Path, dst: Path, res: OfflineResult, arm: ArmModel, config: dict,
              output_topic: str = "joint_torques", config_topic: str = "torque_node/config",
              overwrite: bool = False) -> dict[str, int]:
    """Every message of src plus output_topic, its σ (output_topic + "_std", when res.std is
    not None) and config_topic; returns counts per topic."""
    bag = open_bag(src)
    info = bag.info
    std_topic = output_topic.rstrip("/") + "_std"
    topics = (output_topic, config_topic) + ((std_topic,) if res.std is not None else ())
    for topic in topics:
        if (ch := info.find_topic(topic)) is not None:
            raise OutputExists(f"{src} already has {ch.topic}; choose another with --topic "
                           f"(e.g. {output_topic}_offline)")
    writer = BagWriter(dst, overwrite=overwrite, custom_data=custom_data(info.metadata))
    try:
        ids = copy_layout(info, writer)
        out = writer.add_topic("/" + output_topic.strip("/"), "sensor_msgs/msg/JointState",
                               TopicQos(depth=1000))
        cfg = writer.add_topic("/" + config_topic.strip("/"), "std_msgs/msg/String",
                               TopicQos(depth=1, durability="transient_local"))
        std_ch = None
        if res.std is not None:
            std_ch = writer.add_topic("/" + std_topic.strip("/"), "sensor_msgs/msg/JointState",
                                      TopicQos(depth=1000))
        first_log = int(res.log_ns.min()) if len(res.log_ns) else info.start_ns
        writer.write(cfg, serialize(message("String")(data=json.dumps(config))), first_log)
        templates: dict[str, OutputTemplate] = {}
        std_templates: dict[str, StdTemplate] = {}

        def emit(k: int) -> None:
            tpl = templates.get(res.frame_ids[k])
            if tpl is None:
                tpl = templates[res.frame_ids[k]] = OutputTemplate(arm.joint_names, res.frame_ids[k])
            tpl.q[:] = res.q[k]
            tpl.qd[:] = res.qd[k]
            tpl.effort[:] = res.tau[k]
            sec_nsec = divmod(int(res.stamps_ns[k]), 1_000_000_000)
            tpl.pack_stamp(*sec_nsec)
            writer.write(out, tpl.payload(), int(res.log_ns[k]))
            if std_ch is not None:
                st = std_templates.get(res.frame_ids[k])
                if st is None:
                    st = std_templates[res.frame_ids[k]] = StdTemplate(arm.joint_names, res.frame_ids[k])
                writer.write(std_ch, st.fill(*sec_nsec, res.std[k]), int(res.log_ns[k]))

        k, n = 0, len(res.stamps_ns)
        # interleave: each output right after its input (both carry the input's log time)
        for ch, msg in bag.messages():
            writer.write(ids[ch.id], msg.data, msg.log_time, msg.publish_time, msg.sequence)
            while k < n and res.log_ns[k] <= msg.log_time:
                emit(k)
                k += 1
        for rest in range(k, n):
            emit(rest)
        writer.close()
    except BaseException:
        writer.abort()
        if not overwrite:
            try:
                os.unlink(dst)
            except OSError:
                pass
        raise
    return writer.counts()


def bag_torques(src: Path, dst: Path, arm: ArmModel, *, estimator: str = DEFAULT_ESTIMATOR,
                settings: dict | None = None, input_topic: str = "joint_states",
                output_topic: str = "joint_torques", max_gap_s: float = 0.1,
                cutoff_hz: float | None = None, overwrite: bool = False,
                std: bool = True, subject: str = "none") -> tuple[OfflineResult, dict]:
    src, dst = Path(src), Path(dst)
    if dst.exists() and src.resolve() == dst.resolve():
        raise OutputExists(f"{dst}: the output must be another file than the input")
    bag = open_bag(src)
    stream = read_joint_series(bag, input_topic, arm.joint_names)
    res = compute(stream, arm, estimator, settings, max_gap_s, cutoff_hz, std, subject)
    if not bag.info.complete:
        res.warnings.insert(0, f"{src} is truncated ({bag.info.problem}); using the "
                            f"{bag.info.message_count} messages of its complete chunks")
    cfg_topic = "torque_node/config" if output_topic.strip("/") == "joint_torques" else \
        output_topic.strip("/") + "/config"
    if not output_topic.startswith("/"):  # relative names: in the input topic's namespace
        ns = stream.topic.rsplit("/", 1)[0]
        output_topic, cfg_topic = f"{ns}/{output_topic}", f"{ns}/{cfg_topic}"
    steps = np.diff(res.stamps_ns)
    steps = steps[(steps > 0) & (steps <= max_gap_s * 1e9)]  # within segments
    dt_s = float(np.median(steps)) * 1e-9 if len(steps) else 1e-3
    velocity_given = bool(len(stream.has_velocity)) and bool(stream.has_velocity.all())
    config = config_message(arm, estimator, settings, src, stream.topic, output_topic, max_gap_s,
                            cutoff_hz, dt_s, velocity_given)
    config["std"] = dict(res.std_config)
    if res.std is not None:
        config["std"]["topic"] = output_topic.rstrip("/") + "_std"
    counts = write_bag(src, dst, res, arm, config, output_topic, cfg_topic, overwrite)
    return res, counts
