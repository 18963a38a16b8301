"""bag_torques' work: joint torques for every joint_states sample of a bag, in batch.

The samples go through the torque node's stamp rule (estimation/stamps.py, one rule for
both; `max_stamp_gap` 0 = adaptive, the node's default): a stamp that does not increase is
dropped (counted), a gap or a jump back starts a new segment (the estimator warms up
again). With a delay (kalman `delay_s`), each estimate is stamped with the sample it
estimates, as the node stamps it (the first version stamped it with the newest sample's
stamp: 50 ms misaligned at delay_s 0.05, and 3+ rows at the zero posture before the first
estimate; issue 29).
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

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import model_config
from ..bag.reader import open_bag
from ..codec.jointstate import JointSeries, read_joint_series
from ..codec.jointstate_cdr import OutputTemplate, StdTemplate
from ..dynamics import ArmModel
from ..errors import ForeignBag, OutputExists, UsageError
from ..estimation import DEFAULT_ESTIMATOR, make_estimator
from ..estimation import ESTIMATORS as NODE_ESTIMATORS
from ..estimation.offline import backward_batch, zero_phase
from ..estimation.stamps import StampRule, rate_note, resets
from ..filtering import analysis_config, usable_cutoff
from ..ranges import check_recording
from ..uncertainty import NoCovariance, TorqueStd
from ..version import package_version
from .outputs import CONFIG, JOINT_STATE, copy_with_outputs

#: Log time per chunk of the output (s): a cut file keeps all but the last CHUNK_SPAN_S
#: before the cut.
CHUNK_SPAN_S = 0.5

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
    cutoff_hz: float | None = None  # zero_phase: the cutoff used (None: the practice's)


def _segments(reset: np.ndarray) -> list[slice]:
    """Runs of samples between two restarts of the estimator (reset flags, the first True)."""
    starts = np.flatnonzero(reset).tolist()
    return [slice(a, b) for a, b in zip(starts, [*starts[1:], len(reset)], strict=True)]


def _batch(fn, t: np.ndarray, reset: np.ndarray, *arrays):
    """A batch estimator (zero_phase, backward_batch) run per segment of the stamp rule, so
    that it restarts where the node's estimator does (estimation/stamps.py)."""
    whole = np.iinfo(np.int64).max  # one segment per call: the rule has cut them already
    parts = [fn(t[seg], *(None if a is None else a[seg] for a in arrays), whole)
             for seg in _segments(reset)]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))


def compute(stream: JointSeries, arm: ArmModel, estimator: str = DEFAULT_ESTIMATOR,
            settings: dict | None = None, max_gap_s: float = 0.0,
            cutoff_hz: float | None = None, std: bool = True, subject: str = "none") -> OfflineResult:
    """Torques of every kept sample; BagError when a joint of the model is never given.

    The samples go through the node's stamp rule (estimation/stamps.py; max_gap_s 0 =
    adaptive, the node's default) and the estimator's update() calls as the node makes
    them. With a delay (kalman delay_s > 0) each estimate is the row of the sample it
    estimates (its stamp, its frame_id) and carries the log time of the input that released
    it, as a recorder of the node would log it; the last delay_s of the recording, which
    the node outputs only when later samples come, are drained at the end (every kept
    sample gets exactly one row; no row is made up).

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
    finite = np.isfinite(stream.position).all(axis=1)
    warnings = []
    if not finite.all():
        warnings.append(f"{int((~finite).sum())} samples without a finite position for every "
                        "joint dropped (as the node rejects them)")
    # the node checks a sample's values before its stamp: a refused sample never moves the rule
    idx = np.flatnonzero(finite)
    keep, reset = resets(stream.stamp_ns[idx], max_gap_s)
    keep = np.array(keep, bool)
    reset = np.array(reset, bool)[keep]
    idx = idx[keep]
    dropped = len(stream.stamp_ns) - len(idx)
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
    rows = np.arange(len(t))  # the sample each output row estimates
    release = rows  # the input whose arrival released it (its log time)
    if not len(t):
        qd = qdd = np.zeros_like(q)
    elif estimator == "zero_phase":
        steps = np.diff(t)[~reset[1:]]
        if len(steps):  # a cutoff the stream's rate can use (check_bag's choice), said when changed
            cutoff_hz, note = usable_cutoff(1e9 / float(np.median(steps)), cutoff_hz)
            if note is not None:
                warnings.append(note)
        q, qd, qdd = _batch(lambda ts, x, g: zero_phase(ts, x, cutoff_hz, g), t, reset, q)
    elif estimator == "backward" and (has_v.all() or not has_v.any()):
        vel = stream.velocity[idx] if has_v.all() else None
        qd, qdd, _warm = _batch(lambda ts, x, v, g: backward_batch(ts, x, v, settings, g), t, reset, q, vel)
    else:  # the estimator sample by sample, as the node: q and qd as it estimates them
        q, qd, qdd, std_out, std_config, rows, release = _sample_by_sample(
            stream, idx, reset, arm, estimator, settings, std, subject, std_config)
    tau = arm.inverse_dynamics_batch(q, qd, qdd)
    elapsed = time.perf_counter() - start
    return OfflineResult(t[rows], stream.log_ns[idx[release]], [stream.frame_ids[idx[i]] for i in rows],
                         q, qd, qdd, tau, dropped, int(reset.sum()), warnings, elapsed, std_out, std_config,
                         cutoff_hz)


def _sample_by_sample(stream: JointSeries, idx: np.ndarray, reset: np.ndarray, arm: ArmModel,
                      estimator: str, settings: dict | None, std: bool, subject: str, std_config: dict):
    """The node's compute(): reset where the stamp rule says, update, output the estimate
    of est.stamp_ns (torque_node.compute and after_output, call for call)."""
    t, qin = stream.stamp_ns[idx], stream.position[idx]
    has_v = stream.has_velocity[idx]
    n_s = len(t)
    est = make_estimator(estimator, arm.nv, settings or {})
    ts = None
    if std:
        try:
            ts = TorqueStd(arm, est, subject=subject)
        except NoCovariance as exc:
            std_config = {"published": False, "why": str(exc)}
        else:
            std_config = {"published": True, **ts.parts()}
    row_of = {int(x): k for k, x in enumerate(t)}
    out = np.zeros((3, n_s, arm.nv))
    std_out = np.full((n_s, arm.nv), np.inf) if ts is not None else None
    done = np.zeros(n_s, bool)
    release = np.zeros(n_s, np.int64)
    for k in range(n_s):
        if reset[k]:
            est.reset()
            if ts is not None:
                ts.reset()
        vel = bool(has_v[k])
        warm = est.update(int(t[k]), qin[k], stream.velocity[idx[k]] if vel else None)
        stamp = est.stamp_ns
        if stamp is None:  # the first delay_s of a segment: output later
            continue
        i = k if stamp == t[k] else row_of[stamp]
        out[0, i], out[1, i], out[2, i] = est.q, est.qd, est.qdd
        done[i], release[i] = True, k
        if ts is not None and ts.update(stamp, vel) and warm:
            std_out[i] = ts.std
    for stamp, x in est.drain():  # the end of the recording: the node would output these later
        i = row_of[stamp]
        out[:, i] = x
        done[i], release[i] = True, n_s - 1
    rows = np.flatnonzero(done)
    return (out[0, rows], out[1, rows], out[2, rows],
            None if std_out is None else std_out[rows], std_config, rows, release[rows])


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
    templates: dict[str, OutputTemplate] = {}
    std_templates: dict[str, StdTemplate] = {}

    def emit(k: int, writer, channels: dict[str, int]) -> None:
        tpl = templates.get(res.frame_ids[k])
        if tpl is None:
            tpl = templates[res.frame_ids[k]] = OutputTemplate(arm.joint_names, res.frame_ids[k])
        tpl.q[:] = res.q[k]
        tpl.qd[:] = res.qd[k]
        tpl.effort[:] = res.tau[k]
        sec_nsec = divmod(int(res.stamps_ns[k]), 1_000_000_000)
        tpl.pack_stamp(*sec_nsec)
        writer.write(channels[output_topic], tpl.payload(), int(res.log_ns[k]))
        if res.std is not None:
            st = std_templates.get(res.frame_ids[k])
            if st is None:
                st = std_templates[res.frame_ids[k]] = StdTemplate(arm.joint_names, res.frame_ids[k])
            writer.write(channels[std_topic], st.fill(*sec_nsec, res.std[k]), int(res.log_ns[k]))

    kinds = [(output_topic, JOINT_STATE), (config_topic, CONFIG)]
    if res.std is not None:
        kinds.append((std_topic, JOINT_STATE))
    # chunks of 0.5 s of log time: written in a fraction of a second, the file would otherwise
    # hold ~1 MiB chunks (seconds of recording each) and a cut file lose them (bag/writer.py)
    return copy_with_outputs(bag, dst, kinds, config, res.log_ns, emit, overwrite=overwrite,
                             chunk_span_s=CHUNK_SPAN_S)


def bag_torques(src: Path, dst: Path, arm: ArmModel, *, estimator: str = DEFAULT_ESTIMATOR,
                settings: dict | None = None, input_topic: str = "joint_states",
                output_topic: str = "joint_torques", max_gap_s: float = 0.0,
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
    steps = steps[(steps > 0) & (steps <= StampRule(max_gap_s).gap_ns())]  # within segments
    dt_s = float(np.median(steps)) * 1e-9 if len(steps) else 1e-3
    note = rate_note(dt_s) if len(steps) and estimator != "zero_phase" else None
    if note is not None:  # what the node says at the stream's first step
        res.warnings.append(note)
    velocity_given = bool(len(stream.has_velocity)) and bool(stream.has_velocity.all())
    config = config_message(arm, estimator, settings, src, stream.topic, output_topic, max_gap_s,
                            res.cutoff_hz, dt_s, velocity_given)
    config["std"] = dict(res.std_config)
    if res.std is not None:
        config["std"]["topic"] = output_topic.rstrip("/") + "_std"
    counts = write_bag(src, dst, res, arm, config, output_topic, cfg_topic, overwrite)
    return res, counts
