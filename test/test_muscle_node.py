"""muscle_node as a user runs it: a real muscle_node process on loopback DDS, joint_torques in
from this test (the torques of a library movement, Pinocchio's inverse dynamics), muscle_forces
and muscle_reserves out.

- every joint_torques message is answered once on each output, with its header (stamp and
  frame_id) and the muscle / joint names;
- node vs offline: the activations, speeds, forces and reserves equal offline/muscles.compute
  on the same torques (the same StaticOptimizer, warm-started in the same order) to 1e-9
  (activations, unitless), 1e-6 N and 1e-9 N·m: the bytes through DDS are the same numbers;
- decimation 3 answers the 1st, 4th, 7th ... message only;
- a bad message (NaN torque, names of another model, no efforts) gets one warning line naming
  it, and the node keeps answering the good messages after it.
"""

from __future__ import annotations

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.codec.jointstate import JointSeries
from forearm_dynamics.movements import get_movement
from forearm_dynamics.muscles import load_muscle_model
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.offline.muscles import compute

pytestmark = pytest.mark.ros

T0 = 1_700_000_000 * 10**9
PERIOD = 5_000_000  # 200 Hz


def _torques(n: int, movement: int = 31):
    """n samples of a library movement: q, qd, tau (N, 20)."""
    mv = get_movement(movement)
    t = np.linspace(0.1, mv.duration - 0.1, n)
    q, qd, qdd = mv.evaluate(t)
    return q, qd, build_model("segmented", 50).inverse_dynamics_batch(q, qd, qdd)


class Client:
    """The test's side: publishes joint_torques, keeps muscle_forces and muscle_reserves."""

    def __init__(self, peer: rosproc.Peer):
        self.peer = peer
        node = peer.node
        self.pub = node.create_publisher(JointState, "joint_torques", stream_qos(1000))
        self.forces: list[JointState] = []
        self.reserves: list[JointState] = []
        node.create_subscription(JointState, "muscle_forces", self.forces.append, stream_qos(1000))
        node.create_subscription(JointState, "muscle_reserves", self.reserves.append,
                                 stream_qos(1000))

    def ready(self, node: rosproc.NodeProcess) -> None:
        assert node.wait_for_output("muscle_forces", rosproc.STARTUP_S), node.output()
        assert self.peer.spin_until(lambda: self.pub.get_subscription_count() > 0, rosproc.STARTUP_S)
        # the node's writers match our readers too (discovery is two one-way exchanges)
        assert self.peer.spin_until(
            lambda: self.peer.node.count_publishers("muscle_forces") > 0
            and self.peer.node.count_publishers("muscle_reserves") > 0, rosproc.STARTUP_S)
        self.peer.spin_for(1.0)

    def send(self, stamp_ns: int, q, qd, tau, names=JOINT_NAMES, frame_id: str = "arm") -> None:
        m = JointState(name=list(names))
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 10**9)
        m.header.frame_id = frame_id
        m.position, m.velocity, m.effort = list(map(float, q)), list(map(float, qd)), \
            list(map(float, tau))
        self.pub.publish(m)

    def stream(self, q, qd, tau, t0: int = T0) -> list[int]:
        stamps = []
        for k in range(len(q)):
            stamps.append(t0 + k * PERIOD)
            self.send(stamps[-1], q[k], qd[k], tau[k])
            self.peer.spin_for(0.002)
        return stamps

    def wait_for(self, n: int, seconds: float = 60.0) -> bool:
        return self.peer.spin_until(lambda: len(self.forces) >= n and len(self.reserves) >= n,
                                    seconds)


def _stamp(m: JointState) -> int:
    return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec


@pytest.fixture
def peer():
    p = rosproc.Peer("muscle_test")
    yield p
    p.close()


def test_every_torque_answered_with_its_header_and_the_offline_numbers(procs, peer):
    node = procs.start("muscle_node", "-p", "config_topic:=''")
    client = Client(peer)
    client.ready(node)
    q, qd, tau = _torques(300)
    stamps = client.stream(q, qd, tau)
    assert client.wait_for(len(stamps)), f"{len(client.forces)} of {len(stamps)}\n{node.output()}"
    peer.spin_for(0.5)
    mm = load_muscle_model()
    assert [_stamp(m) for m in client.forces] == stamps  # each once, in order
    assert [_stamp(m) for m in client.reserves] == stamps
    assert all(m.header.frame_id == "arm" for m in client.forces + client.reserves)
    assert all(tuple(m.name) == mm.names for m in client.forces)
    assert all(tuple(m.name) == JOINT_NAMES for m in client.reserves)
    # node vs offline, on the same torques
    n = len(stamps)
    series = JointSeries("joint_torques", JOINT_NAMES, np.array(stamps), np.array(stamps),
                         ["arm"] * n, q, qd, tau)
    off = compute(series, mm)
    a = np.array([m.position for m in client.forces])
    assert a.min() >= 0.0 and a.max() <= 1.0
    np.testing.assert_allclose(a, off.activations, rtol=0, atol=1e-9)
    np.testing.assert_allclose([m.velocity for m in client.forces], off.speeds, rtol=0, atol=1e-12)
    np.testing.assert_allclose([m.effort for m in client.forces], off.forces, rtol=0, atol=1e-6)
    np.testing.assert_allclose([m.effort for m in client.reserves], off.reserves, rtol=0, atol=1e-9)
    assert a.max() > 0.01  # muscles do work here
    assert node.stop() == 0


def test_decimation_answers_one_in_n(procs, peer):
    node = procs.start("muscle_node", "-p", "config_topic:=''", "-p", "decimation:=3")
    client = Client(peer)
    client.ready(node)
    q, qd, tau = _torques(100)
    stamps = client.stream(q, qd, tau)
    want = stamps[::3]
    assert client.wait_for(len(want)), node.output()
    peer.spin_for(1.0)
    assert [_stamp(m) for m in client.forces] == want
    assert [_stamp(m) for m in client.reserves] == want
    assert node.stop() == 0
    assert "decimated 66" in node.output(), node.output()


@pytest.mark.parametrize("bad, words", [
    ("nan_torque", ("non_finite", "effort (torque)", "elbow_flexion")),
    ("other_names", ("missing_joint",)),
    ("no_effort", ("no_effort",)),
])
def test_a_bad_message_gets_one_line_and_the_node_keeps_running(procs, peer, bad, words):
    node = procs.start("muscle_node", "-p", "config_topic:=''")
    client = Client(peer)
    client.ready(node)
    q, qd, tau = _torques(20)
    good = client.stream(q[:10], qd[:10], tau[:10])
    t_bad = good[-1] + PERIOD
    if bad == "nan_torque":
        t = tau[10].copy()
        t[0] = np.nan
        client.send(t_bad, q[10], qd[10], t)
    elif bad == "other_names":
        client.send(t_bad, q[10], qd[10], tau[10], names=[f"joint_{i}" for i in range(20)])
    else:
        m = JointState(name=list(JOINT_NAMES), position=list(map(float, q[10])),
                       velocity=list(map(float, qd[10])))
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(t_bad, 10**9)
        client.pub.publish(m)
    peer.spin_for(0.2)
    after = client.stream(q[11:], qd[11:], tau[11:], t0=t_bad + PERIOD)
    assert client.wait_for(len(good) + len(after)), node.output()
    peer.spin_for(0.5)
    assert [_stamp(m) for m in client.forces] == good + after  # the bad one unanswered
    assert node.stop() == 0
    out = node.output()
    lines = [line for line in out.splitlines() if "rejected sample" in line]
    assert len(lines) == 1, out
    assert all(w in lines[0] for w in words), lines[0]
    assert "Traceback" not in out
