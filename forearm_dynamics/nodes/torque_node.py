"""torque_node: joint_states -> joint_torques (inverse dynamics of the forearm-hand model).

Input  sensor_msgs/JointState on `joint_states`: names in any order (extra names ignored),
       position required, velocity optional (empty -> estimated from positions).
Output sensor_msgs/JointState on `joint_torques`: the model's 20 joints in joint_names
       order; position and velocity as used (velocity = the estimate when the input had
       none); effort = RNEA torques (N·m). With output_rate_hz 0 (default): one output per
       input, header (stamp, frame_id) copied from it. With output_rate_hz > 0: a timer
       publishes at that rate, each output stamped with its publication time (system
       clock) and computed from the estimator's prediction to that time. Deadlines are
       absolute (k periods from the first); an rcl timer at twice the rate publishes when
       one is due, so an output delayed by load is caught up (at most one per tick: never
       a burst, never a stale value) unless more than 50 ms behind. When no input came
       for input_timeout s, or the input's stamps are that far behind this node's clock,
       nothing is published (said in /diagnostics): never a stale repeat, never an
       extrapolation beyond input_timeout.

Angles are checked against the joints' ranges (forearm_dynamics/ranges.py, the check every
input path shares): a sample far outside (degrees sent as radians) is rejected
(angle_out_of_range) with a line naming units, and /diagnostics turns ERROR while such
samples come; a joint moderately outside is warned about once; a stream whose first 1 s
stay within +-3 deg while moving (radians converted twice) is warned about once (WARN).

Velocity and acceleration come from the state estimator (parameter `estimator`, settings
`estimator.<name>`; forearm_dynamics/estimation). Bad samples are dropped and counted per
reason (validation.py); stamp jumps beyond max_stamp_gap reset the estimator
(stream_node.py).

The model is stated on `~/config` (JSON, latched; /torque_node/config for a node named
torque_node), at start-up, with every /diagnostics message and at once on every live change:
model, body size, side, payload, the pro/sup placement that was built, the estimator (its
lag per estimate and the noise it assumes), `config_id` and `applies_from_stamp_ns`.

Live changes (torque_config.py): model, body_size, side, payload_*, placement, split,
custom anthropometry and estimator parameters can be set at runtime. A change is
validated on the executor thread (cheap; refused with the reason, nothing changes), built
on this node's worker thread and swapped in by the subscription callback between two
samples (live_model.py: one ROS-free object owns the bundle in use, the newest built
one, the config ids and texts and the switch counters). Several parameters set together
(set_parameters_atomically) are one build and one swap. A change of model only keeps the
estimator (and its history); a change of estimator settings starts a fresh one (it warms
up again, counted as warm-up).
Other parameters are read-only (their descriptors say so).
"""

from __future__ import annotations

import math
import time

import numpy as np
import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String

from ..description import JOINT_NAMES
from ..ranges import SampleGuard
from ..shoulder import ENU_TO_WORLD, angles_from_rotation, convention, quaternion_matrix
from ..version import package_version
from . import validation as v
from .common import latched_qos, main_for, stream_qos
from .fixed_rate_output import FixedRateOutput
from .live_model import LiveModel
from .model_builder import ModelBuilder
from .params import ParameterError, Params
from .std_output import StdTemplates
from .stream_node import NODE_CONFIG_TOPIC, RESERVED_TOPICS, STREAM_SPECS, JointStreamNode
from .torque_config import (
    INPUT_SPECS,
    LIVE,
    MODEL_SPECS,
    OUTPUT_SPECS,
    ModelBundle,
    ModelRequest,
    OutputSettings,
    build_bundle,
)
from .torque_status import TorqueStatus

_time_ns = time.time_ns


class TorqueNode(TorqueStatus, FixedRateOutput, JointStreamNode):
    """Inverse dynamics per sample: pin.rnea on preallocated q, qd, qdd. What it states
    about itself: torque_status.py; output at a fixed rate: fixed_rate_output.py."""

    specs = (*STREAM_SPECS, *INPUT_SPECS, *OUTPUT_SPECS, *MODEL_SPECS)
    config_name = "torque_node"

    def __init__(self, node_name: str = "torque_node"):
        super().__init__(node_name)
        if self._std_topic is not None:  # joint_torques_std: published by the output hook
            s = self.settings
            self.std_pub = self.create_publisher(JointState, self._std_topic,
                                                 stream_qos(s.qos_depth, s.output_reliable))
            self._std_templates = StdTemplates(self.joint_names)
            self._std_unknown = np.full(len(self.joint_names), np.inf)
        self.config_pub = self.create_publisher(String, NODE_CONFIG_TOPIC, latched_qos())
        self._version = package_version()
        self._publish_config(self.live.in_use, 0)
        # a helper thread: stays at normal priority
        self._worker = ModelBuilder(self.build, self._publish_config)
        if self._imu_topic:
            self.imu_sub = self.create_subscription(Imu, self._imu_topic, self._on_imu,
                                                    stream_qos(self.settings.qos_depth,
                                                               self.settings.input_reliable))
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._after_set)
        if self.output_rate_hz > 0:
            self.start_fixed_rate_output()  # fixed_rate_output.py
        b = self.live.in_use
        self.get_logger().info(
            f"{b.summary()}; config on {self.config_pub.topic_name}"
            + (f"; output at {self.output_rate_hz:g} Hz" if self.output_rate_hz > 0 else "")
        )

    # -- start-up ------------------------------------------------------------------------
    def realtime_helpers(self) -> tuple[int, ...]:
        return (self._worker.native_id,)

    def on_realtime_applied(self) -> None:
        self.live.restate()  # the config states the scheduling the node got: restate it
        self._publish_config(self.live.in_use, 0)

    def hold_posture(self) -> np.ndarray | None:
        return self._hold_posture

    def input_aliases(self) -> dict[str, str]:
        """The shoulder's model-file names (both sides: the side may change live)."""
        if self._shoulder == "none":
            return {}
        conv = convention(self._shoulder)
        return {**conv.alias_map("right"), **conv.alias_map("left")}

    def external_joints(self) -> frozenset[str]:
        if not self._imu_topic:
            return frozenset()
        return frozenset(convention(self._shoulder).joint_names)

    def _on_imu(self, msg: Imu) -> None:
        """An upper-arm orientation -> the shoulder angles the next joint sample uses."""
        o = msg.orientation
        quat = (o.x, o.y, o.z, o.w)
        if not math.isfinite(sum(quat)) or sum(x * x for x in quat) < 1e-6:
            self._imu_bad += 1
            if self._imu_bad == 1:
                self.get_logger().warning(f"{self.imu_sub.topic_name}: orientation {quat} is not a "
                                          "rotation (NaN or zero quaternion): ignored")
            return
        arm = self.live.in_use.arm
        r = ENU_TO_WORLD @ quaternion_matrix(*quat) @ self._imu_mount
        self._imu_angles = angles_from_rotation(arm.shoulder, arm.side, r, self._imu_angles)

    def configure(self, params: Params) -> tuple[str, ...]:
        out = self.output_settings = OutputSettings.from_params(params)
        self.missing_joints = params.value("missing_joints")
        self.output_rate_hz = out.output_rate_hz
        self.input_timeout_ns = round(out.input_timeout * 1e9)
        self._std_topic = None
        if out.publish_std:
            self._std_topic = params.topic("std_topic")
            params.distinct_topics(("input_topic", "output_topic", "std_topic"), RESERVED_TOPICS)
        self._shoulder = params.value("shoulder")
        self._imu_topic = params.value("imu_topic").strip()
        self._imu_angles: np.ndarray | None = None  # the latest Imu's shoulder angles
        self._imu_bad = 0  # Imu messages refused (non-finite or zero quaternion)
        if self._imu_topic and self._shoulder == "none":
            raise ParameterError("imu_topic", "needs shoulder mobl or fullbody (which angles the "
                                 "Imu's orientation is turned into)")
        if self._shoulder != "none" and out.publish_std:
            raise ParameterError("publish_std", "not available with a shoulder yet (the torque σ "
                                 "is that of the 20-joint model)")
        mount = [float(x) for x in params.value("imu_mount")]
        if len(mount) != 4 or not math.isfinite(sum(mount)) or sum(x * x for x in mount) < 1e-6:
            raise ParameterError("imu_mount", f"{mount}: needs a quaternion (x, y, z, w), not zero")
        self._imu_mount = quaternion_matrix(*mount)
        values = params.values(LIVE)
        values["shoulder"] = self._shoulder
        request = ModelRequest.from_values(values)
        try:
            bundle = build_bundle(request, 1, 20, std=self._std_topic)
        except ValueError as exc:
            raise ParameterError("model", str(exc)) from None
        if bundle.arm.nv != bundle.estimator.n:
            bundle = build_bundle(request, 1, bundle.arm.nv, std=self._std_topic)
        self._std_ready = False  # the last output has a σ to publish (after it: after_output)
        self._std_stamp = 0  # ... the stamp of the estimate it is the σ of
        self._std_warm = False  # ... the estimate is warm (else σ = inf)
        std = self._std_topic

        def make(request: ModelRequest, config_id: int, n: int, previous: ModelBundle) -> ModelBundle:
            return build_bundle(request, config_id, n, previous, std=std)

        self._hold_posture = None
        self._held_stated: tuple[str, ...] = ()
        if self.missing_joints == "hold":
            self._hold_posture = np.array([params.value(f"hold_posture.{j}") if j in JOINT_NAMES
                                           else 0.0 for j in bundle.arm.joint_names])
        self.live = LiveModel(bundle, make, self.config_message)
        self._guard = SampleGuard(bundle.arm.joint_names)
        self._far_seen = 0  # guard.far_count at the last /diagnostics
        # output_rate_hz > 0: whether the estimator holds a state to predict from, the input clock
        self._have_state = False
        self._last_in_ns = 0  # receive time of the last input (system clock)
        self._last_out_ns = 0
        self._state_t_ns = 0
        self._silent: str | None = None  # why the timer is not publishing
        self._velocity_given = True
        self.timer_skipped = {"no_input": 0, "input_timeout": 0, "stamps_behind": 0, "late": 0}
        return bundle.arm.joint_names

    # -- the hot path --------------------------------------------------------------------
    def compute(self, t_ns: int, reset: bool, velocity_given: bool) -> bool | None:
        guard = self._guard
        why = guard.check(self.q)  # 4 numpy calls when every angle is in range
        if why is not None:  # before the estimator: its history keeps only real angles
            raise v.Rejection(v.ANGLE_OUT_OF_RANGE, why)
        if guard.pending_warnings:
            for w in guard.pending_warnings:
                self.get_logger().warning(w)
            guard.pending_warnings.clear()
        if not guard.window_done and guard.observe(t_ns, self.q):
            self.get_logger().warning(guard.tiny_warning)
        b, fresh = self.live.current()  # a live change built: swapped in between two samples
        if fresh:
            self._have_state = False
            reset = True
        est = b.estimator
        ts = b.std
        if self._imu_topic:  # the shoulder from the Imu: its latest orientation
            angles = self._imu_angles
            if angles is None:
                raise v.Rejection(v.NO_IMU, f"no Imu on {self._imu_topic} yet: the shoulder angles "
                                  "are unknown")
            self.q[20:] = angles
            velocity_given = False  # the shoulder's rates are estimated like the others'
        if reset:
            est.reset()
            if ts is not None:
                ts.reset()
        try:
            warm = est.update(t_ns, self.q, self.qd if velocity_given else None)
        except ValueError as exc:  # the estimator refuses a sample (state unchanged)
            raise v.Rejection(v.NON_FINITE, str(exc)) from None
        self._velocity_given = velocity_given
        if self.output_rate_hz > 0:  # the timer publishes (est.predict keeps this estimate)
            # only once the estimator is warm: a timer fed by one sample would repeat it
            self._have_state = warm and est.stamp_ns is not None
            self._std_ready = ts is not None
            if ts is not None and est.stamp_ns is not None:  # the jerk and covariance it predicts from
                ts.observe(est.stamp_ns, velocity_given)
            self._state_t_ns = t_ns
            self._last_in_ns = _time_ns()
            return None
        if est.stamp_ns != t_ns:  # a delay: the estimate of an earlier sample, or none yet
            if est.stamp_ns is None:  # the first delay_s of a stream: published later
                return None
            self.output_stamp_ns = est.stamp_ns
        else:
            self.output_stamp_ns = None
        # the state as estimated (a filtering estimator smooths q and qd too): the torque is
        # computed from it and the output message states it ("position and velocity as used")
        np.copyto(self.q, est.q)
        np.copyto(self.qd, est.qd)
        tau = b.torques(self.q, self.qd, est.qdd)
        if not math.isfinite(tau.sum()):
            est.reset()  # it has taken in the absurd sample: the next one starts afresh
            if ts is not None:
                ts.reset()
            self._std_ready = False
            raise v.Rejection(v.NON_FINITE_TORQUE, "torque overflowed (absurd inputs?)")
        np.copyto(self.effort, tau)
        # the σ is computed after the torques are published (after_output): they never wait for it
        self._std_ready = ts is not None
        self._std_stamp, self._std_warm = est.stamp_ns, warm
        return warm

    def after_output(self, sec: int, nanosec: int) -> None:
        """After each output: joint_torques_std for it (same header and names; σ = inf while
        the estimate warms up: its error is not what the covariance says), computed here,
        after the torques went out; and the first output of a new config states that
        config, applied from this output's stamp. First the estimator's deferred work
        (Estimator.learn: the Kalman's noise statistics), which the torques did not wait for."""
        self.live.in_use.estimator.learn()
        if self._std_ready:
            ts = self.live.in_use.std
            if self.output_rate_hz > 0:  # the σ of the prediction to the output's stamp
                known = ts.predict(sec * 1_000_000_000 + nanosec)
            else:
                known = ts.update(self._std_stamp, self._velocity_given) and self._std_warm
            t = self._std_templates.get(self.out.frame_id)
            self.std_pub.publish(t.fill(sec, nanosec, ts.std if known else self._std_unknown))
        if self.live.announcing:
            b = self.live.first_output()
            if b is not None:  # the worker thread publishes it: no JSON work here
                self._worker.announce(b, sec * 1_000_000_000 + nanosec)

    # -- live changes --------------------------------------------------------------------
    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Validate a change of live parameters (cheap, no build); refuse with the reason."""
        names = {p.name for p in params}
        if not names & LIVE:
            return SetParametersResult(successful=True)
        values = self.params.values(LIVE)
        values.update({p.name: p.value for p in params if p.name in LIVE})
        try:
            for p in params:
                why = self.params.specs[p.name].check(p.value) if p.name in self.params.specs else None
                if why:
                    raise ParameterError(p.name, why)
            values["shoulder"] = self._shoulder
            self._requested = ModelRequest.from_values(values)
        except ParameterError as exc:
            self.live.count("refused")
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _after_set(self, params: list[Parameter]) -> None:
        if {p.name for p in params} & LIVE:
            self._worker.submit(self._requested)

    def build(self, request: ModelRequest) -> None:
        """Worker thread: build, state it, then hand it over with one reference assignment."""
        try:
            b = self.live.build(request)
        except (ValueError, TypeError) as exc:
            self.live.count("failed")
            self.get_logger().error(f"live change not applied, config {self.live.in_use.config_id} "
                                    f"keeps running: {exc}")
            return
        self._publish_config(b, None)  # built: stated at once; applied from its first sample
        self.live.built(b)
        self.get_logger().info(f"config {b.config_id} built in {b.build_ms:.1f} ms "
                               f"({b.summary()}); applies from the next sample")

    def destroy_node(self) -> None:
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
        if getattr(self, "stats", None) is not None and self.output_rate_hz > 0:
            skipped = ", ".join(f"{k} {n}" for k, n in self.timer_skipped.items() if n)
            rclpy.logging.get_logger(f"{self.get_name()}.shutdown").info(
                f"timer outputs skipped: {skipped or 'none'}")
        super().destroy_node()


def main() -> None:
    main_for(TorqueNode, "torque_node")


if __name__ == "__main__":
    main()
