"""torque_lifecycle_node (nodes/lifecycle.py) as a real process, driven through rclpy's
lifecycle services (lifecycle_msgs ChangeState / GetState) as a supervisor drives it.

- configure with body_size 200 is refused (the log names body_size), the node stays
  unconfigured; set to 50 (SetParameters) and configured again, it works;
- inactive: nothing on joint_torques; active: every sample answered;
- a JointState stream across deactivate: no torque stamped after the transition (its reply
  received) reaches a subscriber; after activate every sample is answered again;
- ~/config and /diagnostics state the lifecycle state; shutdown ends the process with 0.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import rosproc
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES

pytestmark = pytest.mark.ros

POSTURE = np.random.default_rng(3).uniform(-0.4, 0.7, 20)
WAIT_S = rosproc.STARTUP_S  # hang guard


class Supervisor:
    """A test peer: lifecycle and parameter clients, a JointState feed, a torque listener."""

    def __init__(self, domain: int):
        self.peer = rosproc.Peer("lifecycle_supervisor", domain=domain)
        n = self.peer.node
        self.change = n.create_client(ChangeState, "/torque_node/change_state")
        self.get = n.create_client(GetState, "/torque_node/get_state")
        self.set_params = n.create_client(SetParameters, "/torque_node/set_parameters")
        self.pub = n.create_publisher(JointState, "joint_states", QoSProfile(depth=1000))
        self.torques: list[int] = []  # stamps (ns) received on joint_torques
        self.sent: list[int] = []  # stamps (ns) published on joint_states
        n.create_subscription(JointState, "joint_torques",
                              lambda m: self.torques.append(m.header.stamp.sec * 10**9
                                                            + m.header.stamp.nanosec), 10000)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.config: dict = {}
        n.create_subscription(String, "/torque_node/config",
                              lambda m: self.config.update(json.loads(m.data)), latched)
        self.diag: list[str] = []
        self.events: list[str] = []  # ~/transition_event: the goal states, in order
        n.create_subscription(TransitionEvent, "/torque_node/transition_event",
                              lambda m: self.events.append(m.goal_state.label), 100)
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.msg = JointState(name=list(JOINT_NAMES), position=POSTURE.tolist(), velocity=[0.0] * 20)
        self.feeding = False
        n.create_timer(0.004, self._feed)  # ~250 Hz while feeding

    def _on_diag(self, m: DiagnosticArray) -> None:
        for s in m.status:
            kv = {v.key: v.value for v in s.values}
            if "lifecycle_state" in kv:
                self.diag.append(kv["lifecycle_state"])

    def _feed(self) -> None:
        if self.feeding:
            ns = time.time_ns()
            self.msg.header.stamp.sec, self.msg.header.stamp.nanosec = divmod(ns, 10**9)
            self.pub.publish(self.msg)
            self.sent.append(ns)

    def call(self, client, request):
        assert self.peer.spin_until(lambda: client.service_is_ready(), WAIT_S), client.srv_name
        future = client.call_async(request)
        assert self.peer.spin_until(future.done, WAIT_S), f"{client.srv_name}: no reply"
        return future.result()

    def transition(self, transition_id: int) -> tuple[bool, float, int]:
        """(success, round-trip seconds, wall clock ns when the reply was received)."""
        t0 = time.perf_counter()
        ok = self.call(self.change, ChangeState.Request(transition=Transition(id=transition_id))).success
        return ok, time.perf_counter() - t0, time.time_ns()

    def state(self) -> str:
        return self.call(self.get, GetState.Request()).current_state.label

    def set_int(self, name: str, value: int) -> bool:
        p = Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                      integer_value=value))
        return self.call(self.set_params, SetParameters.Request(parameters=[p])).results[0].successful

    def feed_for(self, seconds: float) -> None:
        self.feeding = True
        self.peer.spin_for(seconds)
        self.feeding = False

    def drain(self, stamps: list[int]) -> bool:
        """Wait until every stamp in `stamps` is answered (hang guard)."""
        want = set(stamps)
        return self.peer.spin_until(lambda: want <= set(self.torques), WAIT_S)


def test_lifecycle_walk_refusal_and_gating(procs) -> None:
    domain = rosproc.test_domain(102, 139)
    node = procs.start("torque_lifecycle_node", "-p", "body_size:=200", "-p", "estimator:=backward",
                       domain=domain)
    sup = Supervisor(domain)
    times: dict[str, float] = {}
    try:
        assert sup.state() == "unconfigured"
        ok, _, _ = sup.transition(Transition.TRANSITION_CONFIGURE)
        assert not ok, "body_size 200 must be refused"
        assert sup.state() == "unconfigured"
        assert node.wait_for_output("body_size", rosproc.STARTUP_S), node.output()
        refusal = [ln for ln in node.output().splitlines() if "configure refused" in ln]
        assert len(refusal) == 1 and "body_size" in refusal[0], node.output()
        assert "Traceback" not in node.output()

        assert sup.set_int("body_size", 50)
        ok, times["configure"], _ = sup.transition(Transition.TRANSITION_CONFIGURE)
        assert ok and sup.state() == "inactive", node.output()
        assert sup.peer.spin_until(lambda: sup.config.get("lifecycle_state") == "inactive", WAIT_S)

        # inactive: the node's subscription matches, nothing is answered
        assert sup.peer.spin_until(lambda: sup.pub.get_subscription_count() >= 1, WAIT_S)
        sup.feed_for(1.0)
        sup.peer.spin_for(1.0)
        assert sup.torques == [], "an inactive node published torques"

        ok, times["activate"], t_act = sup.transition(Transition.TRANSITION_ACTIVATE)
        assert ok and sup.state() == "active"
        sup.sent.clear()
        sup.feed_for(2.0)
        assert sup.drain(sup.sent), f"{len(set(sup.sent) - set(sup.torques))} of {len(sup.sent)} unanswered"
        assert sup.peer.spin_until(lambda: sup.config.get("lifecycle_state") == "active", WAIT_S)

        # deactivate while the stream runs: nothing stamped after the reply is published
        sup.feeding = True
        sup.peer.spin_for(0.5)
        ok, times["deactivate"], t_deact = sup.transition(Transition.TRANSITION_DEACTIVATE)
        assert ok
        sup.peer.spin_for(1.0)
        sup.feeding = False
        sup.peer.spin_for(1.0)  # anything still under way arrives
        late = [t for t in sup.torques if t > t_deact]
        assert late == [], f"{len(late)} torques stamped after deactivate"
        assert any(t > t_deact for t in sup.sent), "the stream did not go on after deactivate"
        assert sup.state() == "inactive"

        # activate again: every sample stamped after the reply is answered
        ok, _, t_act = sup.transition(Transition.TRANSITION_ACTIVATE)
        assert ok
        sup.sent.clear()
        sup.feed_for(2.0)
        after = [t for t in sup.sent if t > t_act]
        assert len(after) > 100
        assert sup.drain(after), f"{len(set(after) - set(sup.torques))} of {len(after)} unanswered"
        assert sup.peer.spin_until(lambda: "active" in sup.diag, WAIT_S), sup.diag
        assert "inactive" in sup.diag
        walk = [e for e in sup.events if e in ("inactive", "active", "unconfigured")]
        assert walk[-4:] == ["inactive", "active", "inactive", "active"], sup.events

        ok, times["shutdown"], _ = sup.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert ok
        assert node.wait(WAIT_S) == 0, node.output()
        assert "Traceback" not in node.output() and "terminate called" not in node.output()
        print("transition round trips (service call, ms):",
              {k: round(v * 1e3, 1) for k, v in times.items()})
    finally:
        sup.peer.close()


def test_cleanup_and_configure_again_keeps_values(procs) -> None:
    """cleanup releases the model and topics; configure again reads the values set meanwhile
    (a read-only parameter is settable while unconfigured, refused while configured)."""
    domain = rosproc.test_domain(102, 139)
    node = procs.start("torque_lifecycle_node", domain=domain)
    sup = Supervisor(domain)
    try:
        assert sup.transition(Transition.TRANSITION_CONFIGURE)[0]
        assert not sup.set_int("qos_depth", 500), "read-only while configured"
        assert sup.transition(Transition.TRANSITION_CLEANUP)[0]
        assert sup.state() == "unconfigured"
        assert sup.set_int("qos_depth", 500)
        assert sup.set_int("body_size", 95)
        assert sup.transition(Transition.TRANSITION_CONFIGURE)[0], node.output()
        assert sup.peer.spin_until(lambda: sup.config.get("lifecycle_state") == "inactive"
                                   and "95" in json.dumps(sup.config), WAIT_S), sup.config
        assert sup.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)[0]
        assert node.wait(WAIT_S) == 0, node.output()
    finally:
        sup.peer.close()
