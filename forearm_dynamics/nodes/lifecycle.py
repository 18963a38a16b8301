"""torque_lifecycle_node: torque_node as a managed (lifecycle) node, for supervisors that
configure, activate and deactivate the nodes a controller trusts (ros2_control, nav2's
lifecycle manager, `ros2 lifecycle set`).

Why a second executable, not `-p managed:=true`: the plain torque_node stays exactly what
it was (no state check per sample, no lifecycle services, the same hot path and latency),
and the choice is made before any node exists (a parameter is read only after the node
is made, and would mean nothing once it runs). Same parameters, same topics, same default
node name (`torque_node`): a launch file switches by executable alone.

States (rclpy.lifecycle, the standard state machine; `ros2 lifecycle get/set/list/nodes`):
- unconfigured: no model, no topics but the lifecycle services and ~/transition_event.
  Parameters may be given (-p, a params file) or set (`ros2 param set`), unchecked yet.
- configure: the plain node's start-up, on the transition: parameters validated (the same
  Specs, ranges and messages), the model built, topics made. A refusal is one error line
  naming the parameter; the node stays unconfigured with the values it had, so the value
  can be fixed (`ros2 param set`) and configure asked again.
- inactive: joint_states is received but not processed, nothing is published on
  joint_torques (lifecycle publishers, disabled); /diagnostics and ~/config go on and
  state `lifecycle_state: inactive`.
- activate: publishes from the next sample.
- deactivate: stops at once. Transitions run on the executor thread that runs the sample
  callbacks, so once deactivate returns no further sample is processed: nothing stamped
  after the transition is published. The estimator state is DROPPED: the next sample after
  activate starts afresh (counted as warm-up, as at start-up). Why: while inactive the
  stream is not followed, so the history ends at the deactivation; a derivative across that
  hole (which may be shorter than the stamp-gap rule's 0.1 s) would be a stale, wrong
  velocity/acceleration given to a controller at the very moment it takes over.
- cleanup: back to unconfigured (topics, timers, model and worker thread released);
  parameters keep their values (read-only ones become settable again until configure).
- shutdown: from any state; the process then exits 0 (like a stop by signal).

Read-only parameters (descriptor read_only in the plain node) are refused by this node
while configured (inactive or active) and accepted while unconfigured: rclpy's own
read_only could never be released for the next configure.
"""

from __future__ import annotations

import time

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.task import Future
from sensor_msgs.msg import JointState

from .common import main_for
from .params import NODE_OPTIONS, ParameterError
from .torque_node import TorqueNode

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE


class ManagedTorqueNode(TorqueNode, LifecycleNode):
    """TorqueNode whose start-up is the configure transition, gated by activate/deactivate."""

    def __init__(self, node_name: str = "torque_node"):
        self.lifecycle_state = "unconfigured"
        self._active = False
        self._configured = False
        self._read_only: set[str] = set()
        self.inactive_dropped = 0  # samples received while inactive (not processed)
        self.transition_ms: dict[str, float] = {}  # the last time of each transition
        self._pending: list[str] = []  # run()'s start-up steps waiting for configure
        self._entities: tuple[set, set, set] | None = None
        self.done = Future()  # shutdown: the process ends (common.run)
        try:
            LifecycleNode.__init__(self, node_name, allow_undeclared_parameters=True,
                                   **NODE_OPTIONS)
        except ValueError as exc:  # an override rclpy cannot type (e.g. an empty list)
            raise ParameterError("(command line)", str(exc).splitlines()[0]) from None
        given = self.get_parameter("executor").value if self.has_parameter("executor") else "events"
        self.executor_kind = given if given in ("events", "single") else "events"
        self.add_on_set_parameters_callback(self._lifecycle_on_set)
        self.get_logger().info("managed torque node: unconfigured (configure, then activate, "
                               "to publish joint_torques)")

    # -- the plain node's start-up, deferred to configure ---------------------------------
    def _init_ros_node(self, node_name: str) -> None:
        """The rclpy node exists already (made unconfigured in __init__)."""

    def start_realtime(self):
        if not self._configured:
            self._pending.append("realtime")
            return None
        return super().start_realtime()

    def on_serving(self) -> None:
        if not self._configured:
            self._pending.append("serving")
            return
        super().on_serving()

    def declare_parameter(self, name, value=None, descriptor=None, ignore_override=False):
        """Read-only parameters are enforced by this node (_lifecycle_on_set) while
        configured: rclpy's read_only cannot be undone for the next configure."""
        if descriptor is not None and descriptor.read_only:
            self._read_only.add(name)
            descriptor.read_only = False
        return super().declare_parameter(name, value, descriptor, ignore_override)

    def _lifecycle_on_set(self, params) -> SetParametersResult:
        if not self._configured:
            return SetParametersResult(successful=True)  # checked at configure
        for p in params:
            if p.name in self._read_only:
                return SetParametersResult(successful=False, reason=(
                    f"{p.name} is read-only while configured: cleanup, set it, configure"))
            if not self.has_parameter(p.name):
                return SetParametersResult(successful=False,
                                           reason=f"{p.name} is not a parameter of this node")
        return SetParametersResult(successful=True)

    def create_publisher(self, msg_type, topic, qos_profile, **kwargs):
        """joint_torques and joint_torques_std: lifecycle publishers (silent unless active)."""
        if msg_type is JointState:
            return self.create_lifecycle_publisher(msg_type, topic, qos_profile, **kwargs)
        return super().create_publisher(msg_type, topic, qos_profile, **kwargs)

    def _snapshot(self) -> tuple[set, set, set]:
        return set(self.publishers), set(self.subscriptions), set(self.timers)

    def _release(self) -> None:
        """Everything configure made: topics, timers, the worker thread, the callbacks."""
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
            self._worker = None
        pubs, subs, timers = self._entities or (set(), set(), set())
        for p in set(self.publishers) - pubs:
            self.destroy_lifecycle_publisher(p)  # a plain publisher too (Node.destroy_publisher)
        for s in set(self.subscriptions) - subs:
            self.destroy_subscription(s)
        for t in set(self.timers) - timers:
            self.destroy_timer(t)
        for cb in (self._on_set, self._refuse_system):
            try:
                self.remove_on_set_parameters_callback(cb)
            except ValueError:
                pass
        try:
            self.remove_post_set_parameters_callback(self._after_set)
        except ValueError:
            pass
        self.stats = None  # destroy_node's summary: only for a configured node
        self._configured = False

    @property
    def _refuse_system(self):
        from .params import _refuse_system_changes  # Params adds it (module function)

        return _refuse_system_changes

    # -- transitions ------------------------------------------------------------------------
    def on_configure(self, _state: LifecycleState) -> TransitionCallbackReturn:
        t0 = time.perf_counter()
        given = {n: self.get_parameter(n).value for n in self.list_parameters([], 0).names}
        # The values the node holds now (given at start-up, set while unconfigured, or kept
        # from the last configuration) are what the Specs' declarations take, as the command
        # line's were at start-up: rclpy's declare_parameter applies its override table
        # (Node._parameter_overrides, the one place it keeps them), so it is brought up to date.
        self._parameter_overrides.update({n: Parameter(n, value=v) for n, v in given.items()
                                          if v is not None})
        self._entities = self._snapshot()
        try:
            TorqueNode.__init__(self, self.get_name())  # the plain node's start-up
        except Exception as exc:  # noqa: BLE001 - any refusal: say it, stay unconfigured
            self._release()
            self._restore(given)
            why = str(exc) if isinstance(exc, ParameterError) else f"cannot configure: {exc}"
            self.get_logger().error(f"configure refused, still unconfigured: {why}")
            return FAILURE
        self._configured = True
        for step in self._pending:  # run() asked for these before there was a node to apply
            (super().start_realtime if step == "realtime" else super().on_serving)()
        self._pending = []
        return self._done("configure", "inactive", t0)

    def _restore(self, given: dict) -> None:
        """After a refused configure: the values the node had, as plain parameters again."""
        for name, value in given.items():
            if not self.has_parameter(name) and value is not None:
                try:
                    super().declare_parameter(name, value, ParameterDescriptor(dynamic_typing=True))
                except Exception:  # noqa: BLE001, S112 - a value rclpy refuses stays dropped
                    continue

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        t0 = time.perf_counter()
        super().on_activate(state)  # enables the lifecycle publishers
        self._active = True
        return self._done("activate", "active", t0)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        t0 = time.perf_counter()
        self._active = False
        super().on_deactivate(state)
        self._drop_estimate()
        return self._done("deactivate", "inactive", t0)

    def on_cleanup(self, _state: LifecycleState) -> TransitionCallbackReturn:
        t0 = time.perf_counter()
        self._active = False
        self._release()
        return self._done("cleanup", "unconfigured", t0)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        t0 = time.perf_counter()
        self._active = False
        if self._configured:
            super().on_deactivate(state)
        result = self._done("shutdown", "finalized", t0)
        # The process ends once the reply to `shutdown` has gone out (a later executor turn).
        self._end_timer = self.create_timer(0.2, self._end)
        return result

    def _end(self) -> None:
        self._end_timer.cancel()
        if not self.done.done():
            self.done.set_result(True)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        self.get_logger().error(f"error processing in {state.label}: back to unconfigured")
        if self._configured:
            self._release()
        self.lifecycle_state = "unconfigured"
        return SUCCESS

    def _drop_estimate(self) -> None:
        """The estimator state is dropped (module docstring): the next sample is a reset."""
        self._last_t_ns = None
        self._last_dt_ns = 0
        self._have_state = False
        self._std_ready = False

    def _done(self, transition: str, state: str, t0: float) -> TransitionCallbackReturn:
        ms = (time.perf_counter() - t0) * 1e3
        self.transition_ms[transition] = ms
        self.lifecycle_state = state
        if self._configured:  # ~/config states the state at once
            self.live.restate()
            self._publish_config(self.live.in_use, 0)
        self.get_logger().info(f"{transition}: {state} ({ms:.1f} ms)")
        return SUCCESS

    # -- gated paths (the plain node's callbacks) ------------------------------------------------
    def _on_joint_state(self, data: bytes) -> None:
        if self._active:
            TorqueNode._on_joint_state(self, data)
        else:
            self.inactive_dropped += 1

    def _on_tick(self) -> None:
        if self._active:
            TorqueNode._on_tick(self)

    # -- what it states ----------------------------------------------------------------------
    def config_message(self, b, applies_from):
        out = super().config_message(b, applies_from)
        out["lifecycle_state"] = self.lifecycle_state
        return out

    def diagnostic_values(self, status) -> dict[str, str]:
        out = super().diagnostic_values(status)
        if not self._active and status.level == status.OK:
            status.message = f"{self.lifecycle_state}: not publishing"
        return {"lifecycle_state": self.lifecycle_state,
                "inactive_dropped": str(self.inactive_dropped),
                **{f"transition_ms.{k}": f"{x:.1f}" for k, x in self.transition_ms.items()},
                **out}


def main() -> None:
    main_for(ManagedTorqueNode, "torque_lifecycle_node")


if __name__ == "__main__":
    main()
