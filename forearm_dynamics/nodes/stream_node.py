"""The joint_states -> JointState pipeline shared by torque_node and null_echo_node.

One raw subscription, one raw publisher (jointstate_cdr.py): the node works on the CDR
bytes. An input message's shape (frame_id, names, field counts) is parsed, checked against
rclpy's deserialiser and validated (names, lengths) once, then cached (input_plans.py); a message of a known
shape costs one masked comparison, a memcpy and numpy `take`s into the output template,
whose position, velocity and effort are 8-byte-aligned numpy views, so a sample is
gathered straight into the outgoing bytes (model joint order). Nothing is allocated per
message but the bytes rclpy hands over and the bytes published. Shapes the parser does not
vouch for go through rclpy's deserialiser and the same checks (`_ingest`). Subclasses only
fill `effort` (and `velocity` when the input has none) in `compute()`.

Why, measured (py-spy, line_profiler, `make bench`): docs/architecture.md, "The stream
nodes' hot path".

Stamp rules (G = max_stamp_gap; with max_stamp_gap 0, the default, G adapts to the stream:
max(0.1 s, 5 x the previous stamp step; 0.5 s for a stream's first step), so a 10 Hz (or
5 Hz) stream is not a gap at any sample while a 1 kHz stream that pauses 0.1 s is; one
rule for the node and bag_torques: estimation/stamps.py):
    stamp zero                      -> rejected (stamp_missing)
    stamp negative, nanosec >= 1e9  -> rejected (stamp_invalid)
    0 < stamp - last <= G           -> normal sample
    stamp - last > G                -> accepted, history reset (reset.stamp_gap), unless
                                       > 60 s ahead of this node's clock (stamp_in_future)
    -G <= stamp - last <= 0         -> rejected (stamp_not_increasing: duplicate/out of order)
    stamp - last < -G               -> accepted, history reset (reset.stamp_jump_back: the
                                       source restarted, e.g. a bag replayed again), unless
                                       a live stream jumps to a stale stamp
                                       (stamp_not_increasing; validation.check_jump)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, KeyValue
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from ..codec.jointstate_cdr import STAMP, OutputTemplate
from ..deadlines import REASONS_INPUT, REASONS_TIMER, Deadlines
from ..estimation.stamps import (
    CONTINUE,
    FIRST_STEP_MAX_S,
    GAP,
    GAP_PERIODS,
    JUMP_BACK,
    MIN_ADAPTIVE_GAP_S,
    StampRule,
)
from ..gcwatch import GcWatch
from . import validation as v
from .common import CONFIG_TOPIC, EXECUTORS, MATCH_POLL_S, MatchLog, stream_qos
from .diagnostics import PipelineStats, diagnostic_array, load_average_1min
from .input_plans import GENERIC, InputPlan, InputPlans
from .params import Params, Spec, init_node
from .scheduling import REALTIME_SPECS, RealtimeNode, realtime_request
from .std_output import PerFrame

WARN_EVERY_S = 1.0  # rate limit of the rejection warning, per reason
BEHIND_WARN_EVERY_S = 10.0  # rate limit of the falling-behind warning
#: s between looks at how many subscriptions the output's writer has matched (logged when
#: it changes; get_subscription_count costs ~2 µs)
_perf_ns, _time_ns = time.perf_counter_ns, time.time_ns

#: Why the default depth is 1000 (measured on this machine, Fast DDS on loopback, whatever
#: the transport): a one-off ~0.3 s reliable-delivery stall happens in some runs (about 3 s
#: after a new publisher joins); a short queue then drops samples (depth 100: ~230, depth
#: 10: 318 in make bench), 1000 none. Reliable, depth 1000 and the EventsExecutor were
#: chosen by measurement: make bench, section choices; see config/nodes/torque_node.yaml.

#: The node's own config topic, relative to the node (two instances never collide).
NODE_CONFIG_TOPIC = "~/config"

#: Topics the stream nodes use themselves: input/output may not name them.
RESERVED_TOPICS = {"/diagnostics": "diagnostics topic", NODE_CONFIG_TOPIC: "node's config topic",
                   CONFIG_TOPIC: "torque_node's config topic"}

STREAM_SPECS = (
    Spec("input_topic", "joint_states", "JointState input topic (remappable too)"),
    Spec("output_topic", "joint_torques", "JointState output topic, model joint order"),
    Spec("qos_depth", 1000, "history depth of input and output; 1000 = 1 s at 1 kHz, rides out "
         "a ~0.3 s delivery stall without loss", "messages", 1, 100000),
    Spec("qos_reliable", True, "reliable (true) or best-effort (false) input and output"),
    Spec("qos_reliability_input", "", "input reliability apart: '' = as qos_reliable",
         choices=("", "reliable", "best_effort")),
    Spec("qos_reliability_output", "", "output reliability apart: '' = as qos_reliable",
         choices=("", "reliable", "best_effort")),
    Spec("executor", "events", "rclpy executor: events (EventsExecutor, fastest) or single",
         choices=EXECUTORS),
    Spec("diagnostics_period", 1.0, "time between /diagnostics messages; 0 = none", "s", 0.0, 3600.0),
    Spec("max_stamp_gap", 0.0, "a stamp jump larger than this resets the estimator history; "
         f"0 = adaptive: larger than {MIN_ADAPTIVE_GAP_S:g} s and {GAP_PERIODS} x the previous "
         f"stamp step ({FIRST_STEP_MAX_S:g} s for the stream's first step)", "s", 0.0, 3600.0),
    Spec("deadline_ms", 1.0, "an output published later than this after its input's arrival "
         "(with output_rate_hz: after its scheduled time) is a missed deadline, counted per "
         "reason in /diagnostics and the shutdown summary; it is published all the same; "
         "0 = not counted", "ms", 0.0, 60000.0),
    *REALTIME_SPECS,
)




@dataclass(frozen=True)
class StreamSettings:
    """Transport settings common to every JointState pipeline node."""

    input_topic: str
    output_topic: str
    qos_depth: int
    qos_reliable: bool
    input_reliable: bool
    output_reliable: bool
    executor: str
    diagnostics_period: float
    max_stamp_gap: float

    @classmethod
    def from_params(cls, p: Params) -> StreamSettings:
        settings = cls(
            input_topic=p.topic("input_topic"),
            output_topic=p.topic("output_topic"),
            qos_depth=p.value("qos_depth"),
            qos_reliable=p.value("qos_reliable"),
            input_reliable=_reliable(p.value("qos_reliability_input"), p.value("qos_reliable")),
            output_reliable=_reliable(p.value("qos_reliability_output"), p.value("qos_reliable")),
            executor=p.value("executor"),
            diagnostics_period=p.value("diagnostics_period"),
            max_stamp_gap=p.value("max_stamp_gap"),
        )
        p.distinct_topics(("input_topic", "output_topic"), RESERVED_TOPICS)
        return settings


def _rel(inp: bool, out: bool) -> str:
    word = {True: "reliable", False: "best effort"}
    return word[inp] if inp == out else f"input {word[inp]}, output {word[out]}"


def _reliable(choice: str, default: bool) -> bool:
    return default if choice == "" else choice == "reliable"


class JointStreamNode(RealtimeNode, Node):
    """Validates joint_states, gathers model-order q/qd, lets compute() fill effort."""

    specs: tuple[Spec, ...] = STREAM_SPECS
    config_name: str = ""  # config/<config_name>.yaml holds the defaults

    def __init__(self, node_name: str):
        self._init_ros_node(node_name)
        self.params = Params(self, self.specs, self.config_name or node_name)
        self.settings = StreamSettings.from_params(self.params)
        self.executor_kind = self.settings.executor
        self.realtime_req = realtime_request(self.params)
        joint_names = self.configure(self.params)  # subclass: model etc.; may raise
        self.params.warn_unknown()

        self.joint_names = tuple(joint_names)
        hold = self.hold_posture()  # missing_joints: hold -> (n,) posture, else None (reject)
        self.names = v.NameMatcher(self.joint_names, hold=hold is not None,
                                   aliases=self.input_aliases(), external=self.external_joints())
        self._hold = hold
        self.held_joints: tuple[str, ...] = ()  # held in the last input (missing_joints: hold)
        #: compute() sets this when its output is the estimate of another stamp (a delay)
        self.output_stamp_ns: int | None = None
        self.stats = PipelineStats(v.REASONS)
        timed = getattr(self, "output_rate_hz", 0) > 0
        self.deadlines = Deadlines(self.params.value("deadline_ms"),
                                   REASONS_TIMER if timed else REASONS_INPUT)
        self.gc_watch = GcWatch()
        self._templates = PerFrame(lambda frame: OutputTemplate(self.joint_names, frame))
        self._use_template(self._template(b""))  # self.out, self.q, self.qd, self.effort
        self._shapes = InputPlans(self.names)
        self._plan: InputPlan = GENERIC  # the last message's (the steady state: one shape)
        self._stamp = STAMP.unpack_from
        self._last_t_ns: int | None = None
        self._rate_mark: tuple[int, int | None] = (0, None)  # received, last stamp: _warn_if_behind
        self.stamp_rule = StampRule(self.settings.max_stamp_gap)  # the jump rule
        self._max_gap_ns = self.stamp_rule.fast_ns  # steps up to this always continue
        self._step_pending = True  # on_first_step not called yet
        self._warned: dict[str, tuple[float, int]] = {}
        # the after_output hook costs a call per output only where a subclass defines it
        overridden = type(self).after_output is not JointStreamNode.after_output
        self._after_output = self.after_output if overridden else None

        s = self.settings
        self.pub = self.create_publisher(JointState, s.output_topic,
                                         stream_qos(s.qos_depth, s.output_reliable))
        self.sub = self.create_subscription(JointState, s.input_topic, self._on_joint_state,
                                            stream_qos(s.qos_depth, s.input_reliable), raw=True)
        self.diag_pub = None
        if s.diagnostics_period > 0:
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        # Who gets the output, as this writer sees it, and whom the input comes from, as this
        # reader sees it: a sample sent before the other side is matched here never arrives
        # (volatile), and discovery can take a participant announcement (~3 s) longer for one
        # pair of nodes than for another (in a CI run the recorder missed the replay's first
        # 92 answers, though the replay had seen it on joint_states 2 s before it started).
        # Logged on each change (common.MatchLog): what a user, a demo or a test waits for
        # before the stream starts.
        out_topic, in_topic = self.pub.topic_name, self.sub.topic_name
        self._matches = (
            MatchLog(self, self.pub.get_subscription_count,
                     lambda n: f"{out_topic}: matched by {n} subscriber(s)"),
            MatchLog(self, self.sub.get_publisher_count,
                     lambda n: f"{in_topic}: receiving from {n} publisher(s)"))
        self.create_timer(MATCH_POLL_S, self._log_matches)
        # First-call costs (shape parsing and checks, numpy paths) now, not on the first
        # sample: the usual shape (model joint order, positions + velocities) is cached.
        self._plan = self._shapes.find(OutputTemplate(self.joint_names, effort=False).payload())
        self.get_logger().info(
            f"{self.sub.topic_name} -> {self.pub.topic_name} "
            f"(depth {s.qos_depth}, {_rel(s.input_reliable, s.output_reliable)}, "
            f"{s.executor} executor)"
        )

    def _log_matches(self) -> None:
        for log in self._matches:
            log()

    def _init_ros_node(self, node_name: str) -> None:
        """rclpy's Node.__init__ (params.init_node); the managed node (lifecycle.py) made its
        rclpy node before and runs this constructor as its configure transition."""
        init_node(self, node_name)

    def summary(self) -> str:
        """One line for the log at shutdown: processed, rejected by reason, warm-up, resets."""
        st = self.stats
        rejected = {k: n for k, n in st.rejected.items() if n}
        why = ", ".join(f"{k} {n}" for k, n in rejected.items())
        resets = ", ".join(f"{k} {n}" for k, n in st.resets.items() if n)
        return (f"summary: received {st.received}, processed {st.published} "
                f"(warm-up {st.warmup}), rejected {sum(rejected.values())}"
                + (f" ({why})" if why else "") + (f"; estimator resets: {resets}" if resets else "")
                + f"; {self.deadlines.summary()}; scheduling {self.realtime_line()}")

    def destroy_node(self) -> None:
        if getattr(self, "stats", None) is not None:
            # not the node's logger: after SIGINT its /rosout publisher is gone
            rclpy.logging.get_logger(f"{self.get_name()}.shutdown").info(self.summary())
        super().destroy_node()

    # -- subclass hooks ------------------------------------------------------------------
    def configure(self, params: Params) -> tuple[str, ...]:
        """Read the subclass's own parameters; return the output joint names."""
        raise NotImplementedError

    def after_output(self, sec: int, nanosec: int) -> None:
        """Called right after every output is published (header stamp sec, nanosec), on the
        executor thread and inside the callback's timing, if a subclass defines it: to
        publish a companion message of the same sample (joint_torques_std), or to state a
        config applied from that stamp."""

    def diagnostic_values(self, status) -> dict[str, str]:  # noqa: ARG002 - a hook
        """A subclass's own key-values for its /diagnostics status (it may also set
        status.level and status.message); the timing values are added after them."""
        return {}

    def after_diagnostics(self) -> None:
        """Called after each /diagnostics message (e.g. to republish a latched config)."""

    def sample_interval_s(self, default: float = 1e-3) -> float:
        """The stream's last stamp step (s, the last two accepted inputs'; a gap counts
        until the next step); `default` before two samples."""
        dt = self.stamp_rule.interval_ns
        return dt * 1e-9 if dt else default

    def on_first_step(self, d_ns: int) -> None:
        """Called once, at the stream's first step that continues its history (normally its
        second sample), with the step (ns): the first moment the stream's rate is known
        (torque_node says if it is below the supported rates)."""

    def compute(self, t_ns: int, reset: bool, velocity_given: bool) -> bool | None:
        """Fill self.effort (and self.qd if not velocity_given); return warm, or None when
        the subclass publishes on its own schedule (nothing is published for this input).

        `reset` says the history must be dropped first (first sample or a stamp jump).
        """
        raise NotImplementedError

    # -- the pipeline --------------------------------------------------------------------
    def _on_joint_state(self, data: bytes) -> None:
        """Raw callback: CDR bytes in, CDR bytes out (see the module docstring)."""
        t_start = _perf_ns()
        recv_ns = _time_ns()
        stats = self.stats
        stats.received += 1
        try:
            plan = self._plan
            if plan.layout is None or not plan.layout.matches(data):
                plan = self._plan = self._shapes.find(data)
            if plan.layout is None:
                t_ns, sec, nsec, reset, velocity_given = self._ingest_generic(data)
            else:
                if plan.rejection is not None:
                    raise plan.rejection
                if plan.layout.frame_id != self.out.frame_id:
                    self._use_template(self._template(plan.layout.frame_id))
                plan.buf[:] = data
                q = self.q
                plan.pos.take(plan.index, out=q)
                velocity_given = plan.vel is not None
                if velocity_given:
                    plan.vel.take(plan.index, out=self.qd)
                if plan.held is not None:  # missing_joints: hold
                    self._apply_hold(plan.held, velocity_given)
                    # one reduction for both: NaN/inf in either makes q.qd non-finite
                    if not math.isfinite(q.dot(self.qd)):
                        self._check_finite(True)
                elif not math.isfinite(q.sum()):
                    self._check_finite(False)
                sec, nsec = self._stamp(data, 4)
                t_ns, reset = self._check_stamp(sec, nsec)
            warm = self.compute(t_ns, reset, velocity_given)
        except v.Rejection as r:
            stats.rejected[r.reason] += 1
            self._warn(r)
            return
        if warm is None:  # the subclass publishes on its own schedule (a timer)
            stats.record(_perf_ns() - t_start, recv_ns - t_ns, 0)
            return
        out = self.out
        if self.output_stamp_ns is not None:  # the estimate of an earlier sample (a delay)
            sec, nsec = divmod(self.output_stamp_ns, 1_000_000_000)
        out.pack_stamp(sec, nsec)
        t_pub = _perf_ns()
        self.pub.publish(out.payload())
        t_end = _perf_ns()
        t_pub_ns = t_end - t_pub
        if self._after_output is not None:  # e.g. a second output of the same sample
            self._after_output(sec, nsec)
            t_end = _perf_ns()
        stats.published += 1
        if not warm:
            stats.warmup += 1
        stats.record(t_end - t_start, recv_ns - t_ns, t_pub_ns)
        self.deadlines.check_input(recv_ns - t_ns, t_end - t_start)

    def _apply_hold(self, held: np.ndarray, velocity_given: bool) -> None:
        """The joints the message lacks: held at their posture, at rest (one write each)."""
        self.q[held] = self._hold[held]
        if velocity_given:
            self.qd[held] = 0.0
        if len(held) != len(self.held_joints):
            self.held_joints = tuple(self.joint_names[i] for i in held)
            self.get_logger().info(f"holding {len(held)} joint(s) the input lacks: "
                                   f"{', '.join(self.held_joints[:6])}"
                                   + (" ..." if len(held) > 6 else "") + " (missing_joints: hold)")

    def input_aliases(self) -> dict[str, str]:
        """Other names an input may give a model joint -> the model's name (none here)."""
        return {}

    def external_joints(self) -> frozenset[str]:
        """Model joints another input supplies: not required in joint_states (none here)."""
        return frozenset()

    def hold_posture(self) -> np.ndarray | None:
        """missing_joints: hold -> the posture (rad, model order) of the joints an input
        lacks; None (the default) refuses such inputs. Subclasses with the parameter."""
        return None

    def _check_finite(self, velocity_given: bool) -> None:
        """After a non-finite q.qd (or sum): reject NaN/inf in q or qd (else it was overflow)."""
        q, qd = self.q, self.qd
        if not np.isfinite(q).all():
            raise v.Rejection(v.NON_FINITE, self.names.nonfinite_detail("position", q))
        if velocity_given and not np.isfinite(qd).all():
            raise v.Rejection(v.NON_FINITE, self.names.nonfinite_detail("velocity", qd))

    # -- templates, the generic path (rare: once per new shape or frame_id) -----------------
    def _template(self, frame_id: bytes) -> OutputTemplate:
        return self._templates.get(frame_id)

    def _use_template(self, t: OutputTemplate) -> None:
        """Publish from `t` from now on; q, qd, effort are its views (compute() writes them)."""
        self.out, self.q, self.qd, self.effort = t, t.q, t.qd, t.effort

    def _ingest_generic(self, data: bytes) -> tuple[int, int, int, bool, bool]:
        """Any JointState bytes rclpy can read: deserialise, then `_ingest`."""
        try:
            msg = deserialize_message(data, JointState)
        except Exception:  # noqa: BLE001 - a raw publisher can send anything
            raise v.Rejection(v.LENGTH_MISMATCH, f"undecodable JointState ({len(data)} bytes)") from None
        frame_id = msg.header.frame_id.encode("utf-8")
        if frame_id != self.out.frame_id:
            self._use_template(self._template(frame_id))
        t_ns, reset, velocity_given = self._ingest(msg)
        return t_ns, msg.header.stamp.sec, msg.header.stamp.nanosec, reset, velocity_given

    def _ingest(self, msg: JointState) -> tuple[int, bool, bool]:
        """Validate and gather q (and qd if given) in model order; raise Rejection."""
        names = msg.name
        pos, vel = msg.position, msg.velocity
        nvel = len(vel)
        index = v.match_fields(self.names, names, len(pos), nvel, len(msg.effort))
        np.frombuffer(pos, dtype=np.float64).take(index, out=self.q)
        if nvel:
            np.frombuffer(vel, dtype=np.float64).take(index, out=self.qd)
        if self.names.held is not None:
            self._apply_hold(self.names.held, nvel > 0)
            if not math.isfinite(self.q.dot(self.qd)):
                self._check_finite(True)
        elif not math.isfinite(self.q.sum()):
            self._check_finite(False)
        stamp = msg.header.stamp
        t_ns, reset = self._check_stamp(stamp.sec, stamp.nanosec)
        return t_ns, reset, nvel > 0

    def _check_stamp(self, sec: int, nanosec: int) -> tuple[int, bool]:
        """(t_ns, reset) of a valid stamp (the rules in the module docstring); raise Rejection."""
        t_ns = sec * 1_000_000_000 + nanosec
        if t_ns <= 0 or nanosec >= 1_000_000_000:
            raise v.bad_stamp(sec, nanosec)
        last = self._last_t_ns
        reset = last is None
        if reset:
            v.check_jump(t_ns, None)
        else:
            d = t_ns - last
            rule = self.stamp_rule
            if 0 < d <= self._max_gap_ns:  # the steady state
                if self._step_pending:
                    self._first_step(d)
                rule.interval_ns = d
            else:  # rare: a slow stream, a gap, a jump back or a repeat (estimation/stamps.py)
                verdict = rule.judge(d)
                if verdict == GAP:
                    v.check_jump(t_ns, last)
                    reset = True
                    self.stats.resets["stamp_gap"] += 1
                elif verdict == JUMP_BACK:
                    v.check_jump(t_ns, last)
                    reset = True
                    self.stats.resets["stamp_jump_back"] += 1
                    self.get_logger().warning(
                        f"header.stamp jumped back {-d / 1e9:.3f} s: source restarted? "
                        "estimator history reset", throttle_duration_sec=WARN_EVERY_S
                    )
                elif verdict != CONTINUE:
                    raise v.Rejection(
                        v.STAMP_NOT_INCREASING,
                        f"stamp {t_ns} ns is {-d} ns at or before the previous sample",
                    )
                if d > 0:
                    if self._step_pending and not reset:
                        self._first_step(d)
                    rule.interval_ns = d
        self._last_t_ns = t_ns
        return t_ns, reset

    def _first_step(self, d_ns: int) -> None:
        self._step_pending = False
        self.on_first_step(d_ns)

    def _warn(self, r: v.Rejection) -> None:
        v.warn_rejection(self._warned, self.get_logger(), r, WARN_EVERY_S)

    def _publish_diagnostics(self) -> None:
        v.flush_suppressed(self._warned, self.get_logger(), WARN_EVERY_S)
        self._warn_if_behind()
        status = self.stats.status(f"{self.get_name()}: pipeline", self.get_fully_qualified_name())
        values = {**self.diagnostic_values(status), **self.timing_values()}
        status.values.extend(KeyValue(key=k, value=x) for k, x in values.items())
        self.diag_pub.publish(diagnostic_array(status, self.get_clock().now().to_msg()))
        self.after_diagnostics()

    def _warn_if_behind(self) -> None:
        """Past its queue (qos_depth samples) DDS drops the oldest input samples, and no event
        tells this node (docs/reliability.md, known limits): say so while the node is more
        than half a queue behind its live stamps (a starved machine: beside a dd + fsync loop
        the demo's node fell up to 1.4 s behind and lost samples; benchmarks/pipeline_disk_load).
        The queue in seconds is at the stream's rate over the period (samples per second of
        stamps), not its last step: a publisher catching up stamps a burst microseconds apart."""
        behind = self.deadlines.take_behind() / 1e9
        mark = (self.stats.received, self._last_t_ns)
        (n0, t0), self._rate_mark = self._rate_mark, mark
        if not (t0 and mark[1] and mark[1] > t0 and mark[0] > n0):
            return  # no stamps this period, or a restart (a jump back)
        rate = (mark[0] - n0) / ((mark[1] - t0) * 1e-9)
        queue_s = self.settings.qos_depth / rate
        if behind < 0.5 * queue_s:
            return
        self.get_logger().warning(
            f"{behind:.2f} s behind the input's stamps, past half of what the input queue holds "
            f"({self.settings.qos_depth} samples = {queue_s:.2f} s at {rate:.0f} Hz): beyond "
            "it DDS drops the oldest samples, which this node cannot count; the machine is not "
            f"giving it the CPU it needs (load average {load_average_1min()}): free it, or "
            "raise qos_depth (every sample kept, answered later)",
            throttle_duration_sec=BEHIND_WARN_EVERY_S)

    def timing_values(self) -> dict[str, str]:
        """Deadline, real-time and garbage-collection key-values for /diagnostics."""
        return {**self.deadlines.values(), **self.realtime_values(), **self.gc_watch.values()}

    def on_serving(self) -> None:
        """run() froze the start-up heap and applied the scheduling: serving starts."""
        self.gc_watch.serving()
