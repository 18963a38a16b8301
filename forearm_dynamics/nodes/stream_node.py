"""The joint_states -> JointState pipeline shared by torque_node and null_echo_node.

One subscription, one publisher, one preallocated output message: its position, velocity
and effort are array.array buffers with numpy views, so a sample is gathered straight into
the outgoing message (model joint order) and nothing is allocated per message apart from
what rclpy itself allocates. Subclasses only fill `effort` (and `velocity` when the input
has none) in `compute()`.

Stamp rules (max_stamp_gap = G):
    stamp zero                      -> rejected (stamp_missing)
    0 < stamp - last <= G           -> normal sample
    stamp - last > G                -> accepted, history reset (reset.stamp_gap)
    -G <= stamp - last <= 0         -> rejected (stamp_not_increasing: duplicate/out of order)
    stamp - last < -G               -> accepted, history reset (reset.stamp_jump_back: the
                                       source restarted, e.g. a bag replayed again)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState

from . import validation as v
from .common import EXECUTORS, float_field, stream_qos
from .diagnostics import PipelineStats, diagnostic_array
from .params import Params, Spec

WARN_EVERY_S = 1.0  # rate limit of the rejection warning, per reason

#: Why the default depth is 1000 (measured on this machine, UDP loopback, Fast DDS): a
#: one-off 0.27-0.34 s reliable-delivery stall happens in many runs (about 3 s after a new
#: publisher joins); with depth 100 at 1 kHz ~230 samples were then dropped, with 1000 none.
QOS_NOTE = "depth 1000 = 1 s at 1 kHz: rides out a ~0.3 s delivery stall without loss"

STREAM_SPECS = (
    Spec("input_topic", "joint_states", "JointState input (remappable too)"),
    Spec("output_topic", "joint_torques", "JointState output, model joint order"),
    Spec("qos_depth", 1000, "history depth of input and output (>= 1); see QOS_NOTE"),
    Spec("qos_reliable", True, "reliable (true) or best-effort (false) input and output"),
    Spec("executor", "events", "'events' (EventsExecutor, fastest) or 'single'"),
    Spec("diagnostics_period", 1.0, "s between /diagnostics messages; 0 = none"),
    Spec("max_stamp_gap", 0.1, "s; larger stamp jumps reset the estimator history"),
)


@dataclass(frozen=True)
class StreamSettings:
    """Transport settings common to every JointState pipeline node."""

    input_topic: str
    output_topic: str
    qos_depth: int
    qos_reliable: bool
    executor: str
    diagnostics_period: float
    max_stamp_gap: float

    @classmethod
    def from_params(cls, p: Params) -> StreamSettings:
        return cls(
            input_topic=p.topic("input_topic"),
            output_topic=p.topic("output_topic"),
            qos_depth=p.integer("qos_depth", 1, 100000),
            qos_reliable=p.boolean("qos_reliable"),
            executor=p.string("executor", EXECUTORS),
            diagnostics_period=p.number("diagnostics_period", 0.0, 3600.0),
            max_stamp_gap=p.number("max_stamp_gap", 1e-6, 3600.0),
        )


class JointStreamNode(Node):
    """Validates joint_states, gathers model-order q/qd, lets compute() fill effort."""

    specs: tuple[Spec, ...] = STREAM_SPECS

    def __init__(self, node_name: str):
        super().__init__(node_name)
        self.params = Params(self, self.specs)
        self.settings = StreamSettings.from_params(self.params)
        self.executor_kind = self.settings.executor
        joint_names = self.configure(self.params)  # subclass: model etc.; may raise
        self.params.refuse_changes()
        for name in self.params.unknown_overrides():
            self.get_logger().warning(f"ignoring unknown parameter '{name}'")

        self.joint_names = tuple(joint_names)
        self.names = v.NameMatcher(self.joint_names)
        self.stats = PipelineStats(v.REASONS)
        nv = len(self.joint_names)
        self.out = JointState()
        self.out.name = list(self.joint_names)
        self.q = float_field(self.out, "position", nv)
        self.qd = float_field(self.out, "velocity", nv)
        self.effort = float_field(self.out, "effort", nv)
        self._last_t_ns: int | None = None
        self._max_gap_ns = round(self.settings.max_stamp_gap * 1e9)
        self._warned: dict[str, tuple[float, int]] = {}

        s = self.settings
        qos = stream_qos(s.qos_depth, s.qos_reliable)
        self.pub = self.create_publisher(JointState, s.output_topic, qos)
        self.sub = self.create_subscription(JointState, s.input_topic, self._on_joint_state, qos)
        self.diag_pub = None
        if s.diagnostics_period > 0:
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        self.get_logger().info(
            f"{self.sub.topic_name} -> {self.pub.topic_name} "
            f"(depth {s.qos_depth}, {'reliable' if s.qos_reliable else 'best effort'}, "
            f"{s.executor} executor)"
        )

    # -- subclass hooks ------------------------------------------------------------------
    def configure(self, params: Params) -> tuple[str, ...]:
        """Read the subclass's own parameters; return the output joint names."""
        raise NotImplementedError

    def compute(self, t_ns: int, reset: bool, velocity_given: bool) -> bool:
        """Fill self.effort (and self.qd if not velocity_given); return warm.

        `reset` says the history must be dropped first (first sample or a stamp jump).
        """
        raise NotImplementedError

    # -- the pipeline --------------------------------------------------------------------
    def _on_joint_state(self, msg: JointState) -> None:
        t_start = time.perf_counter_ns()
        recv_ns = time.time_ns()
        stats = self.stats
        stats.received += 1
        try:
            t_ns, reset, velocity_given = self._ingest(msg)
            warm = self.compute(t_ns, reset, velocity_given)
        except v.Rejection as r:
            stats.rejected[r.reason] += 1
            self._warn(r)
            return
        out = self.out
        out.header.stamp = msg.header.stamp
        out.header.frame_id = msg.header.frame_id
        self.pub.publish(out)
        stats.published += 1
        if not warm:
            stats.warmup += 1
        stats.record(time.perf_counter_ns() - t_start, recv_ns - t_ns)

    def _ingest(self, msg: JointState) -> tuple[int, bool, bool]:
        """Validate and gather q (and qd if given) in model order; raise Rejection."""
        names = msg.name
        index = self.names.match(names)
        n = len(names)
        pos, vel = msg.position, msg.velocity
        if len(pos) != n:
            raise v.Rejection(v.LENGTH_MISMATCH, f"{len(pos)} positions for {n} names")
        nvel = len(vel)
        if nvel not in (0, n):
            raise v.Rejection(v.LENGTH_MISMATCH, f"{nvel} velocities for {n} names (0 or {n})")
        np.frombuffer(pos, dtype=np.float64).take(index, out=self.q)
        if not math.isfinite(self.q.sum()):
            raise v.Rejection(v.NON_FINITE, self.names.nonfinite_detail("position", self.q))
        if nvel:
            np.frombuffer(vel, dtype=np.float64).take(index, out=self.qd)
            if not math.isfinite(self.qd.sum()):
                raise v.Rejection(v.NON_FINITE, self.names.nonfinite_detail("velocity", self.qd))
        stamp = msg.header.stamp
        t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        if t_ns == 0:
            raise v.Rejection(v.STAMP_MISSING, "header.stamp is zero")
        last = self._last_t_ns
        reset = last is None
        if not reset:
            d = t_ns - last
            if d > self._max_gap_ns:
                reset = True
                self.stats.resets["stamp_gap"] += 1
            elif d < -self._max_gap_ns:
                reset = True
                self.stats.resets["stamp_jump_back"] += 1
                self.get_logger().warning(
                    f"header.stamp jumped back {-d / 1e9:.3f} s: source restarted? "
                    "estimator history reset", throttle_duration_sec=WARN_EVERY_S
                )
            elif d <= 0:
                raise v.Rejection(
                    v.STAMP_NOT_INCREASING,
                    f"stamp {t_ns} ns is {-d} ns at or before the previous sample",
                )
        self._last_t_ns = t_ns
        return t_ns, reset, nvel > 0

    def _warn(self, r: v.Rejection) -> None:
        """One warning per reason per WARN_EVERY_S, with the number suppressed meanwhile."""
        now = time.monotonic()
        last, suppressed = self._warned.get(r.reason, (-math.inf, 0))
        if now - last < WARN_EVERY_S:
            self._warned[r.reason] = (last, suppressed + 1)
            return
        more = f" (+{suppressed} more since the last warning)" if suppressed else ""
        self.get_logger().warning(f"rejected sample [{r.reason}]: {r.detail}{more}")
        self._warned[r.reason] = (now, 0)

    def _publish_diagnostics(self) -> None:
        status = self.stats.status(f"{self.get_name()}: pipeline", self.get_fully_qualified_name())
        self.diag_pub.publish(diagnostic_array(status, self.get_clock().now().to_msg()))
