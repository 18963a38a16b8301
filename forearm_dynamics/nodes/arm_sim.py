"""arm_sim: the virtual arm. Joint torques in, simulated joint angles out (forward dynamics).

Input  sensor_msgs/JointState on `joint_commands`: effort by joint name (N·m); joints not
       named get zero torque; position and velocity are ignored. A command is held (zero-
       order hold) until the next one.
Output sensor_msgs/JointState on `joint_states` every step: the model's 20 joints in
       joint_names order, position (rad), velocity (rad/s) and effort = the torque applied
       over the step that led there (N·m); stamped with the simulated time, which starts at
       the system clock's time when the node starts and advances exactly 1/rate_hz per step
       (in real time also over skipped steps, see below, so it stays on the system clock).

Two modes:
- real time (lockstep false, the default): a timer steps the arm at rate_hz. Steps are due
  at fixed times from the start (k/rate_hz); a late tick catches up (at most MAX_CATCH_UP_S
  worth of steps); the rest of a longer stall is skipped: the arm stands still over it,
  its stamps jump by the skipped time (a stamp gap: they stay on the system clock, which
  the reference a controller tracks is stamped with; a closed loop measured 0.3 s of
  apparent lead after a stall when they did not), counted in /diagnostics (steps_skipped).
  No accepted command for `command_timeout` s -> zero torque, a WARN line in /diagnostics
  and one log line (and one when commands are back).
- lockstep (true): no timer. Each command received advances exactly one step and is
  answered by one joint_states message and one /clock message (rosgraph_msgs/Clock, the
  simulated time), so a controller with use_sim_time runs in the simulation's time, as fast
  as it answers, and the run is deterministic (the trajectory is a function of the commands).

Bad commands are refused, counted per reason and logged one line each (rate-limited per
reason), and the arm keeps going with the last accepted command: no effort (or a length
different from the names), an unknown or repeated joint name, a NaN/inf effort, |effort|
above max_torque. In lockstep mode a refused command still advances its step.

The model comes from the torque node's model parameters (one definition:
torque_config.MODEL_SPECS), read-only here; the simulation from simulation/ (RK4 or
semi-implicit Euler, damping, joint limits). The node states both on `~/config` (JSON,
latched): the model part as torque_node's (model_config.py) plus the solver, damping and
limit gains per joint, the initial posture, mode and topics.
"""

from __future__ import annotations

import json
import math
import signal
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ..codec.jointstate_cdr import Layout, NotMine, OutputTemplate, verified_layout
from ..exit_codes import OK
from ..model_config import model_config
from ..simulation import ArmSimulator
from ..version import package_version
from .arm_sim_settings import SPECS, ArmSimSettings
from .common import latched_qos, main_for, stream_qos
from .diagnostics import diagnostic_array, load_average_1min
from .params import ParameterError, Params, init_node
from .scheduling import RealtimeNode, realtime_request

#: Real time: how far (s) one late tick may catch up; the rest of a longer stall is skipped.
#: Short on purpose: a catch-up is a burst of steps under one held command, i.e. a delay in
#: a controller's loop; 0.25 s of it (the first choice) made examples/closed_loop.py's 5 Hz
#: loop unstable after a stall (2 cores at load 15: stalls of 70-300 ms every few seconds).
MAX_CATCH_UP_S = 0.02
WARN_EVERY_S = 1.0
REASONS = ("no_effort", "length_mismatch", "unknown_joint", "duplicate_joint", "non_finite",
           "too_large")
_mono = time.monotonic_ns
_perf = time.perf_counter_ns


class CommandRefused(ValueError):
    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


class ArmSim(RealtimeNode, Node):
    """One ArmSimulator, a command input, a state output, diagnostics and config."""

    def __init__(self, node_name: str = "arm_sim"):
        init_node(self, node_name)
        self.params = Params(self, SPECS, "arm_sim")
        s = self.settings = ArmSimSettings.from_params(self.params)
        self.realtime_req = realtime_request(self.params)  # applied by run() before the spin
        self.params.warn_unknown()
        self.executor_kind = s.executor
        self.exit_code = OK
        # SIGINT/SIGTERM end the spin through `done` (common.run), never as a
        # KeyboardInterrupt inside a callback: a step takes ~0.1 ms of every 1 ms, so
        # rclpy's handler (which raises it wherever Python runs) hit a step mid-way.
        self.done = Future()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        try:
            self.sim = ArmSimulator(s.arm, s.sim, s.q0)
        except ValueError as exc:
            raise ParameterError("damping", str(exc)) from None
        self.joint_names = s.arm.joint_names
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        # raw commands of the last shape (names, counts): its layout and joint indices
        self._shape: tuple[Layout, np.ndarray] | None = None
        self.command = np.zeros(self.sim.nv)  # last accepted, N·m
        self._zero = np.zeros(self.sim.nv)
        self.refused = dict.fromkeys(REASONS, 0)
        self.received = self.accepted = 0
        self.timeouts = 0  # times the command timed out (zero torque from then on)
        self.skipped = 0  # real time: steps skipped after a stall
        self.diverged = 0  # steps whose result was not finite (state kept, at rest)
        self._warned: dict[str, float] = {}
        self._timed_out = False
        self._step_ns: list[int] = []
        self._steps_at_diag = 0
        self._diag_t = time.monotonic()

        qos = stream_qos(s.qos_depth, True)
        self.out = OutputTemplate(self.joint_names)
        self.pub = self.create_publisher(JointState, s.state_topic, qos)
        self.config_pub = self.create_publisher(String, "~/config", latched_qos())
        self.clock_pub = self.create_publisher(Clock, "/clock", 10) if s.lockstep else None
        self._clock_msg = Clock()
        self.diag_pub = None
        if s.diagnostics_period > 0:
            self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        self._period_ns = round(1e9 / s.rate_hz)
        self._max_catch_up = max(1, round(MAX_CATCH_UP_S * s.rate_hz))
        self._anchor()
        self.sub = self.create_subscription(JointState, s.command_topic, self._on_command, qos,
                                            raw=True)
        self._config_json = json.dumps(self._config())
        self.config_pub.publish(String(data=self._config_json))
        if s.lockstep:
            self._publish_state(self._zero)  # the initial state, at simulated time 0
        else:  # anchored at the first tick: start-up time is not a stall
            self._started = False
            self.create_timer(0.5 / s.rate_hz, self._on_tick)
        a = s.arm
        self.get_logger().info(
            f"{a.kind}, body size {a.body_size.label}, {a.side} arm; {s.sim.method} at "
            f"{s.rate_hz:g} Hz, {'lockstep (one step per command, /clock)' if s.lockstep else 'real time'}; "
            f"{self.sub.topic_name} -> {self.pub.topic_name}")

    def _on_signal(self, _signum, _frame) -> None:
        if not self.done.done():
            self.done.set_result(True)

    def _anchor(self) -> None:
        """Simulated time 0 = now, on the system clock (stamps) and the monotonic (steps due)."""
        self.t0_ns = time.time_ns()
        self._start_mono = _mono()
        self._last_cmd_mono = self._start_mono

    # -- commands ------------------------------------------------------------------------
    def _on_command(self, data: bytes) -> None:
        self.received += 1
        try:
            self.command = self._parse(data)
            self.accepted += 1
            self._last_cmd_mono = _mono()
            if self._timed_out:
                self._timed_out = False
                self.get_logger().info("commands back: applying them again")
        except CommandRefused as exc:
            self.refused[exc.reason] += 1
            self._warn(exc.reason, f"command refused ({exc.reason}): {exc}; the arm keeps the "
                       "last accepted command")
        if self.settings.lockstep:
            self._advance(self.command)

    def _parse(self, data: bytes) -> np.ndarray:
        """The command's torques in model order. Raw CDR: a message of the last shape (the
        controller's usual one) costs a shape test and a view (jointstate_cdr); another
        shape is parsed (or deserialised by rclpy), checked and becomes the cached one."""
        shape = self._shape
        if shape is not None and shape[0].matches(data):
            lay, idx = shape
            effort = lay.array(data, "effort")
            names = lay.names
        else:
            try:
                lay = verified_layout(data)
                names, n_eff = lay.names, lay.n_eff
            except NotMine:
                lay = None
                msg = deserialize_message(data, JointState)
                names, n_eff = tuple(msg.name), len(msg.effort)
            idx = self._indices(names, n_eff)
            if lay is not None:
                self._shape = (lay, idx)
                effort = lay.array(data, "effort")
            else:
                effort = np.asarray(msg.effort, dtype=np.float64)
        if not np.isfinite(effort).all():
            k = int(np.flatnonzero(~np.isfinite(effort))[0])
            raise CommandRefused("non_finite", f"effort of {names[k]} is {effort[k]!r}")
        if len(effort) and np.abs(effort).max() > self.settings.max_torque:
            k = int(np.abs(effort).argmax())
            raise CommandRefused("too_large", f"effort of {names[k]} is {effort[k]:g} N·m, beyond "
                                 f"max_torque {self.settings.max_torque:g}")
        tau = np.zeros(self.sim.nv)
        tau[idx] = effort
        return tau

    def _indices(self, names: tuple[str, ...], n_effort: int) -> np.ndarray:
        """Model indices of a command's names, or CommandRefused saying what is wrong."""
        if n_effort == 0:
            raise CommandRefused("no_effort", f"no effort for {len(names)} name(s)")
        if n_effort != len(names):
            raise CommandRefused("length_mismatch",
                                 f"{n_effort} effort value(s) for {len(names)} name(s)")
        unknown = [n for n in names if n not in self._index]
        if unknown:
            raise CommandRefused("unknown_joint", f"unknown joint name {unknown[0]!r}")
        if len(set(names)) != len(names):
            dup = next(n for n in names if names.count(n) > 1)
            raise CommandRefused("duplicate_joint", f"joint {dup!r} named twice")
        return np.array([self._index[n] for n in names], dtype=np.intp)

    def _warn(self, key: str, text: str) -> None:
        now = time.monotonic()
        if now - self._warned.get(key, -math.inf) >= WARN_EVERY_S:
            self._warned[key] = now
            self.get_logger().warning(text)

    # -- stepping ------------------------------------------------------------------------
    def _on_tick(self) -> None:
        """Real time: do every step due by now (k periods from the start), at most
        MAX_CATCH_UP_S worth; the rest of a longer stall is skipped and counted."""
        if not self._started:
            self._started = True
            self._anchor()
            self._publish_state(self._zero)  # the initial state, at simulated time 0
            return
        now = _mono()
        due = (now - self._start_mono) // self._period_ns - self.sim.steps - self.skipped
        if due <= 0:
            return
        if due > self._max_catch_up:
            self.skipped += due - self._max_catch_up
            self._warn("late", f"{due / self.settings.rate_hz * 1e3:.0f} ms behind: skipping "
                       f"{due - self._max_catch_up} steps (the arm stands still over them; its "
                       "stamps jump ahead with the clock)")
            due = self._max_catch_up
        timeout = self.settings.command_timeout
        tau = self.command
        if timeout > 0 and now - self._last_cmd_mono > timeout * 1e9:
            tau = self._zero
            if not self._timed_out:
                self._timed_out = True
                self.timeouts += 1
                self.get_logger().warning(
                    f"no command for {(now - self._last_cmd_mono) / 1e9:.3f} s (> command_timeout "
                    f"{timeout:g} s): zero torque")
        for _ in range(due):
            self._advance(tau)

    def _advance(self, tau: np.ndarray) -> None:
        t = _perf()
        sim = self.sim
        q, qd = sim.q, sim.qd
        sim.step(tau)
        if not math.isfinite(sim.q.sum() + sim.qd.sum()):  # never publish (or keep) NaN
            sim.q, sim.qd = q, np.zeros_like(qd)
            self.diverged += 1
            self._warn("diverged", f"the step from t={sim.t - sim.dt:.3f} s diverged (torques "
                       f"{np.abs(tau).max():.3g} N·m at most): kept the last finite posture, at rest")
        self._publish_state(tau)
        if self.diag_pub is not None and len(self._step_ns) < 100_000:
            self._step_ns.append(_perf() - t)

    def _publish_state(self, tau: np.ndarray) -> None:
        out = self.out
        np.copyto(out.q, self.sim.q)
        np.copyto(out.qd, self.sim.qd)
        np.copyto(out.effort, tau)
        stamp = self.t0_ns + (self.sim.steps + self.skipped) * self._period_ns
        sec, nsec = divmod(stamp, 1_000_000_000)
        out.pack_stamp(sec, nsec)
        self.pub.publish(out.payload())
        if self.clock_pub is not None:
            self._clock_msg.clock.sec, self._clock_msg.clock.nanosec = sec, nsec
            self.clock_pub.publish(self._clock_msg)

    # -- config and diagnostics ----------------------------------------------------------
    def _config(self) -> dict:
        s = self.settings
        return {"node": self.get_fully_qualified_name(), "version": package_version(),
                **model_config(s.arm), "simulation": self.sim.describe(),
                "initial_posture": dict(zip(self.joint_names, s.q0.tolist(), strict=True)),
                "rate_hz": s.rate_hz, "lockstep": s.lockstep,
                "command_timeout": s.command_timeout, "max_torque": s.max_torque,
                "command_topic": self.sub.topic_name if hasattr(self, "sub") else s.command_topic,
                "state_topic": self.pub.topic_name, "t0_ns": self.t0_ns}

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        span = max(now - self._diag_t, 1e-9)
        steps = self.sim.steps - self._steps_at_diag
        times = np.asarray(self._step_ns, dtype=np.int64)
        self._step_ns = []
        p50, p99 = (np.percentile(times, (50, 99)) / 1e3).tolist() if times.size else (math.nan,) * 2
        behind = ((_mono() - self._start_mono) / 1e9
                  - (self.sim.steps + self.skipped) / self.settings.rate_hz) * 1e3
        values = {
            "steps_total": str(self.sim.steps), "step_rate_hz": f"{steps / span:.1f}",
            "simulated_time_s": f"{self.sim.t:.3f}",
            "behind_ms": "n/a (lockstep)" if self.settings.lockstep else f"{behind:.1f}",
            "step_us_p50": f"{p50:.1f}", "step_us_p99": f"{p99:.1f}",
            "commands_received": str(self.received), "commands_accepted": str(self.accepted),
            "commands_refused": str(sum(self.refused.values())),
            **{f"refused.{k}": str(n) for k, n in self.refused.items()},
            "command_timeouts": str(self.timeouts), "steps_skipped": str(self.skipped),
            "steps_diverged": str(self.diverged),
            "load_average_1min": load_average_1min(),
            **self.realtime_values(),
        }
        level, message = DiagnosticStatus.OK, "running"
        if self._timed_out:
            level = DiagnosticStatus.WARN
            message = (f"no command for > command_timeout ({self.settings.command_timeout:g} s): "
                       "zero torque")
        status = DiagnosticStatus(level=level, name=f"{self.get_name()}: simulation", message=message,
                                  hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=x) for k, x in values.items()])
        self.diag_pub.publish(diagnostic_array(status, self.get_clock().now().to_msg()))
        self.config_pub.publish(String(data=self._config_json))
        self._diag_t, self._steps_at_diag = now, self.sim.steps

    def destroy_node(self) -> None:
        import rclpy

        if getattr(self, "sim", None) is not None:
            refused = ", ".join(f"{k} {n}" for k, n in self.refused.items() if n)
            rclpy.logging.get_logger(f"{self.get_name()}.shutdown").info(
                f"summary: {self.sim.steps} steps ({self.sim.t:.3f} s simulated), commands "
                f"received {self.received}, accepted {self.accepted}, refused "
                f"{sum(self.refused.values())}" + (f" ({refused})" if refused else "")
                + f", timeouts {self.timeouts}, steps skipped {self.skipped}, diverged "
                f"{self.diverged}")
        super().destroy_node()


def main() -> None:
    main_for(ArmSim, "arm_sim")


if __name__ == "__main__":
    main()
