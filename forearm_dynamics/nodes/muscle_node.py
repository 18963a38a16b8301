"""muscle_node: joint_torques -> muscle_forces, the muscles behind every torque (issue 31).

    ros2 run forearm_dynamics muscle_node [--ros-args -p decimation:=2]

Input  sensor_msgs/JointState on `joint_torques` (the torque node's output): position,
       velocity and effort (torque, N·m) by joint name; names in any order, extra names
       ignored.
Output sensor_msgs/JointState on `muscle_forces`, one per input sample (one in `decimation`),
       same header (stamp, frame_id) as the torques it answers: name = the muscles (model
       order), position = activation (0..1), velocity = muscle-tendon lengthening speed (m/s,
       lengthening positive), effort = tendon force (N). And `muscle_reserves`, same header:
       name = the joints, effort = each joint's reserve torque (N·m), what the muscles could
       not carry (position and velocity empty).
Why JointState (not a message of our own): every tool reads it already (ros2 topic echo,
       rosbag2, check_bag, bag_export, rosbags, PlotJuggler, Foxglove); a custom message would
       need a rosidl build, which a pip-installed ROS does not have; names travel with every
       message, so a reader never guesses the muscle order. The layout is stated on ~/config.

Per sample: the muscle model's moment arms, lengths and speeds at q, q̇ (polynomial
surrogates), then the static optimisation (min Σa² + Σ(r/r_opt)² s.t. R·F(a) + r = τ,
0 ≤ a ≤ 1; daqp, warm-started from the previous sample): forearm_dynamics/muscles. No
message objects on the hot path: the bytes are read through the stream nodes' cached input
plans (input_plans.py: one parse per message shape) and one numpy take, and the outputs are
written into preallocated CDR templates (muscle_io.py, over codec/jointstate_cdr.py);
~/config, /diagnostics and the shutdown summary are muscle_status.py.

The muscle model follows the torque node: its config (torque_node/config, latched) names the
model, body size and side; each change there (a live change of the torque node) rebuilds
the muscle model on a worker thread, swapped in between two samples; until a config arrives
(or with config_topic '') this node's own model parameters rule (the torque node's
definitions, live). The muscle set, source, licence, scaling and solver are stated on
`~/config` (JSON, latched) at start-up, with every /diagnostics message and on every change.

Bad input (NaN torques, missing joints, no efforts): the sample is dropped, counted per
reason, one warning line per reason per second; the node keeps running.

Behind (a loaded machine: the node runs at nice 10), it takes what has arrived out of the
DDS reader every 5 ms into a queue of its own and answers every sample in order, late but
not lost (muscle_backlog.py; `backlog_limit`, on /diagnostics).
"""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ..codec.jointstate_cdr import STAMP
from ..description import JOINT_NAMES
from ..model_config import model_from_config
from ..muscles import MuscleModelError
from ..version import package_version
from . import validation as v
from .common import latched_qos, main_for, stream_qos
from .diagnostics import PipelineStats
from .input_plans import GENERIC, InputPlans
from .model_builder import ModelBuilder
from .muscle_backlog import BUDGET_NS, DRAIN_NS, InputBacklog
from .muscle_io import NO_EFFORT, NO_VELOCITY, OutputTemplates, StateReader
from .muscle_settings import (
    MODEL_NAMES,
    SPECS,
    MuscleBundle,
    MuscleSettings,
    arm_summary,
    build_bundle,
    own_arm,
)
from .muscle_status import WARN_EVERY_S, MuscleStatus
from .params import ParameterError, Params, init_node

REASONS = (*v.REASONS, NO_EFFORT, NO_VELOCITY)
_perf_ns, _time_ns = time.perf_counter_ns, time.time_ns
_MODEL_KEYS = ("model", "body_size", "side", "payload", "placement", "joint_names", "schema")


class MuscleNode(MuscleStatus, Node):
    """Static optimisation of every torque sample (see the module docstring)."""

    def __init__(self, node_name: str = "muscle_node"):
        init_node(self, node_name)
        self.params = Params(self, SPECS, "muscle_node")
        s = self.settings = MuscleSettings.from_values(self.params.values())
        topics = ["input_topic", "output_topic"] + (["reserves_topic"] if s.reserves_topic else [])
        for t in topics:
            self.params.topic(t)
        topics += ["config_topic"] if s.config_topic else []
        self.params.distinct_topics(topics, {"/diagnostics": "diagnostics topic",
                                             "~/config": "node's config topic"})
        self.params.warn_unknown()
        self.executor_kind = s.executor
        if s.nice > 0:  # before any thread exists: DDS's and the worker's threads inherit it
            try:
                os.nice(s.nice)
            except OSError as exc:
                self.get_logger().warning(f"nice {s.nice} not applied ({exc})")
        self._version = package_version()
        arm = self._own_arm(self.params.values(MODEL_NAMES))
        try:
            self.bundle = build_bundle(s, 1, arm.body_size, arm.side, "own parameters",
                                       arm_summary(arm))
        except MuscleModelError as exc:
            raise ParameterError("muscle_model", str(exc)) from None
        self._next: MuscleBundle | None = None  # built on the worker, swapped in by a sample
        self._config_ids = 1
        self._torque_config_text: str | None = None
        self._torque_config_id = None
        self.applies_from = 0
        self.stats = PipelineStats(REASONS)
        self._cpu_mark: tuple[int, int] | None = None  # (thread CPU ns, published) per period
        self.decimated = 0
        self.reserve_use = 0
        self.infeasible = 0
        self.solver_failed = 0
        self._max_reserve = (0.0, "")
        self._reserve_warn = s.reserve_warn
        self._solve_ns = np.zeros(16384, np.int64)
        self._n_solve = 0
        self._count = 0
        self._warned: dict[str, tuple[float, int]] = {}
        self._names = v.NameMatcher(JOINT_NAMES)
        self._plans = InputPlans(self._names)
        self._plan = GENERIC
        self._reader = StateReader(s.input_topic, len(JOINT_NAMES))
        self._state = self._reader.state
        self.q, self.qd, self.tau = self._state  # views: the reader writes them
        # finiteness of all 60 numbers as one BLAS dot with ones (a NaN or inf makes the sum
        # non-finite, as ndarray.sum() did): 1.3 vs 3.0 µs, the ufunc reduction's set-up
        self._state_flat, self._ones = self._state.reshape(-1), np.ones(self._state.size)
        self._outputs = OutputTemplates(self.bundle.model.names, JOINT_NAMES)
        self._stamp = STAMP.unpack_from

        qos = stream_qos(s.qos_depth, s.qos_reliable)
        self.pub = self.create_publisher(JointState, s.output_topic, qos)
        self.reserves_pub = (self.create_publisher(JointState, s.reserves_topic, qos)
                             if s.reserves_topic else None)
        self.config_pub = self.create_publisher(String, "~/config", latched_qos())
        self._worker = ModelBuilder(self._build, self._announce)
        self._publish_config(self.bundle, 0)
        self.sub = self.create_subscription(JointState, s.input_topic, self._on_torques,
                                            stream_qos(s.input_depth, s.input_reliable), raw=True)
        handle = self.sub.handle
        self._backlog = InputBacklog(lambda: handle.take_message(JointState, True),
                                     s.backlog_limit)
        self._own_queue = s.backlog_limit > 0  # 0: the DDS reader's queue alone (as before)
        self._resume = self.create_timer(0.001, self._on_resume)
        self._resume.cancel()  # armed only when a callback returns with samples queued
        if s.config_topic:
            self.create_subscription(String, s.config_topic, self._on_torque_config, latched_qos())
        self.add_on_set_parameters_callback(self._on_set)
        self.diag_pub = None
        if s.diagnostics_period > 0:
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        mm = self.bundle.model
        self.get_logger().info(
            f"{self.sub.topic_name} -> {self.pub.topic_name}"
            + (f" + {self.reserves_pub.topic_name}" if self.reserves_pub is not None else "") + ": "
            f"{mm.n} muscles ({mm.source.get('name')}, {mm.source.get('licence')}), "
            f"{self.bundle.arm_summary['body_size']} {mm.side} arm, decimation {s.decimation}; "
            f"config on {self.config_pub.topic_name}"
            + (f"; following {s.config_topic}" if s.config_topic else ""))

    # -- the hot path --------------------------------------------------------------------
    def _on_torques(self, data: bytes) -> None:
        """The executor's sample: answered at once, or after those the node has queued
        (muscle_backlog.py: taken from the DDS reader while it works, answered in order)."""
        bl = self._backlog
        bl.delivered()
        if bl.pending:
            bl.pending.append(data)
            self._work()
            return
        self._sample(data)
        if self._own_queue and _perf_ns() - bl.last_drain > DRAIN_NS and bl.drain():
            self._work()

    def _work(self) -> None:
        """Answer the queued samples in order, taking new arrivals every DRAIN_NS, for at
        most BUDGET_NS; then return (timers and /diagnostics run) and resume."""
        bl = self._backlog
        q, end = bl.pending, _perf_ns() + BUDGET_NS
        while q:
            self._sample(q.popleft())
            now = _perf_ns()
            if now - bl.last_drain > DRAIN_NS:
                bl.drain()
            if now > end and q:
                self._resume.reset()
                return

    def _on_resume(self) -> None:
        self._resume.cancel()
        self._work()

    def _sample(self, data: bytes) -> None:
        t_start = _perf_ns()
        recv_ns = _time_ns()
        st = self.stats
        st.received += 1
        try:
            plan = self._plan
            if plan.layout is None or not plan.layout.matches(data):
                plan = self._plan = self._plans.find(data)
            if plan.layout is None:
                sec, nsec, frame_id = self._ingest_generic(data)
            else:
                if plan.rejection is not None:
                    raise plan.rejection
                plan.buf[:] = data
                self._reader.read(plan)
                sec, nsec = self._stamp(data, 4)
                if not (sec or nsec) or nsec >= 1_000_000_000 or sec < 0:
                    raise v.bad_stamp(sec, nsec)
                frame_id = plan.layout.frame_id
            if not math.isfinite(self._state_flat.dot(self._ones)):
                raise self._nonfinite()
        except v.Rejection as r:
            st.rejected[r.reason] += 1
            self._warn(r)
            return
        self._count += 1
        if (self._count - 1) % self.settings.decimation:
            self.decimated += 1
            return
        nxt = self._next
        if nxt is not None:  # a rebuilt model: from this sample on
            self._next = None
            self._outputs.rename(nxt.model.names)
            self.bundle = nxt
            self.applies_from = sec * 1_000_000_000 + nsec
            self._worker.announce(nxt, self.applies_from)
        b = self.bundle
        out, res = self._outputs.get(frame_id)
        # activations, forces and reserves written straight into the two messages' bytes
        flag, infeasible, solve_s = b.optimizer.solve_sample_into(
            self.q, self.qd, self.tau, b.geometry, out.q, out.effort, res.effort)
        np.copyto(out.qd, b.geometry[2])  # the path velocities
        out.pack_stamp(sec, nsec)
        t_pub = _perf_ns()
        self.pub.publish(out.payload())
        if self.reserves_pub is not None:
            self.reserves_pub.publish(res.stamped(sec, nsec))
        t_end = _perf_ns()
        # bookkeeping after the clock stops: counters and rings the diagnostics timer reads
        if flag < 1:
            self.solver_failed += 1
        if infeasible:
            self.infeasible += 1
        r = res.effort.tolist()  # 20 floats: Python's max beats two numpy reductions
        big = max(max(r), -min(r))
        if big > self._reserve_warn:
            self.reserve_use += 1
            if big > self._max_reserve[0]:
                self._max_reserve = (float(big), JOINT_NAMES[int(np.abs(res.effort).argmax())])
        self._solve_ns[self._n_solve % len(self._solve_ns)] = round(solve_s * 1e9)
        self._n_solve += 1
        st.published += 1
        st.record(t_end - t_start, recv_ns - (sec * 1_000_000_000 + nsec), t_end - t_pub)

    def _ingest_generic(self, data: bytes) -> tuple[int, int, bytes]:
        try:
            msg = deserialize_message(data, JointState)
        except Exception:  # noqa: BLE001 - a raw publisher can send anything
            raise v.Rejection(v.LENGTH_MISMATCH, f"undecodable JointState ({len(data)} bytes)") from None
        names = list(msg.name)
        index = v.match_fields(self._names, names, len(msg.position), len(msg.velocity),
                               len(msg.effort))
        if len(msg.effort) != len(names):
            raise v.Rejection(NO_EFFORT, f"{len(msg.effort)} efforts for {len(names)} names: "
                              "not joint torques")
        if len(msg.velocity) != len(names):
            raise v.Rejection(NO_VELOCITY, "no velocities (the force-velocity needs them)")
        np.take(np.asarray(msg.position), index, out=self.q)
        np.take(np.asarray(msg.velocity), index, out=self.qd)
        np.take(np.asarray(msg.effort), index, out=self.tau)
        st = msg.header.stamp
        if not (st.sec or st.nanosec) or st.sec < 0:
            raise v.bad_stamp(st.sec, st.nanosec)
        return st.sec, st.nanosec, msg.header.frame_id.encode("utf-8")

    def _nonfinite(self) -> v.Rejection:
        for field, x in (("effort (torque)", self.tau), ("position", self.q), ("velocity", self.qd)):
            if not np.isfinite(x).all():
                return v.Rejection(v.NON_FINITE, self._names.nonfinite_detail(field, x))
        return v.Rejection(v.NON_FINITE, "overflow")

    def _warn(self, r: v.Rejection) -> None:
        v.warn_rejection(self._warned, self.get_logger(), r, WARN_EVERY_S)

    # -- the model: own parameters or the torque node's config ----------------------------
    def _own_arm(self, values):
        return own_arm(values)

    def _on_torque_config(self, msg: String) -> None:
        try:
            cfg = json.loads(msg.data)
            part = json.dumps({k: cfg[k] for k in sorted(cfg) if k in _MODEL_KEYS})
            if part == self._torque_config_text:
                return  # a periodic repeat, or an estimator-only change
            arm = model_from_config(cfg).arm
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            self._warn(v.Rejection("config", f"ignoring a config message on "
                                   f"{self.settings.config_topic} ({str(exc).splitlines()[0]}); "
                                   "the muscle model in use stays"))
            return
        self._torque_config_text = part
        self._torque_config_id = cfg.get("config_id")
        self._worker.submit((arm.body_size, arm.side, self.settings.config_topic, arm_summary(arm)))

    def _on_set(self, params) -> SetParametersResult:
        changed = {p.name: p.value for p in params if p.name in MODEL_NAMES}
        if not changed:
            return SetParametersResult(successful=True)
        for name, value in changed.items():
            why = self.params.specs[name].check(value)
            if why:
                return SetParametersResult(successful=False, reason=f"{name}: {why}")
        try:
            arm = self._own_arm({**self.params.values(MODEL_NAMES), **changed})
        except (ParameterError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if self._torque_config_text is None:  # a torque node's config rules once it came
            self._worker.submit((arm.body_size, arm.side, "own parameters", arm_summary(arm)))
        return SetParametersResult(successful=True)

    def _build(self, request) -> None:
        """Worker thread: build the requested muscle model; the next sample swaps it in."""
        body_size, side, source, summary = request
        self._config_ids += 1
        try:
            b = build_bundle(self.settings, self._config_ids, body_size, side, source, summary)
        except (MuscleModelError, ValueError) as exc:
            self.get_logger().error(f"muscle model not rebuilt ({exc}); config "
                                    f"{self.bundle.config_id} keeps running")
            return
        self._publish_config(b, None)
        self._next = b
        self.get_logger().info(f"muscle config {b.config_id} built in {b.build_ms:.1f} ms "
                               f"({summary['body_size']} {side} arm, from {source}); applies "
                               "from the next sample")

    def _announce(self, bundle: MuscleBundle, stamp_ns: int) -> None:
        self._publish_config(bundle, stamp_ns)

    def destroy_node(self) -> None:
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
        if getattr(self, "stats", None) is not None:
            rclpy.logging.get_logger(f"{self.get_name()}.shutdown").info(self.summary())
        super().destroy_node()


def main() -> None:
    main_for(MuscleNode, "muscle_node")


if __name__ == "__main__":
    main()
