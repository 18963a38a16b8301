"""arm_viz as a user runs it: a real torque_node and arm_viz (real processes, loopback DDS),
joint_states in from this test, arm_markers and robot_description out. Every marker of an
array equals the ROS-free markers of the model in force at the joint_torques it was drawn
from (positions to 1e-9 m: the same numbers, through DDS); a live body-size change of the
torque node (and then a payload) reaches the markers; arm_viz's own model parameters rule
while no torque node is there, and a bad change is refused by name."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rosproc
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.muscles import load_muscle_model
from forearm_dynamics.nodes.common import latched_qos, stream_qos
from forearm_dynamics.viz import ArmScene, MarkerMaker, TorqueColours
from forearm_dynamics.viz.colors import viridis

pytestmark = pytest.mark.ros

RNG = np.random.default_rng(20)


class Viewer:
    """The test's side: publishes joint_states, keeps joint_torques, markers, descriptions."""

    def __init__(self, peer):
        node = peer.node
        self.peer = peer
        self.pub = node.create_publisher(JointState, "joint_states", stream_qos(100))
        self.torques: dict[int, JointState] = {}
        self.arrays: list[MarkerArray] = []
        self.descriptions: list[str] = []
        node.create_subscription(JointState, "joint_torques", self._keep, stream_qos(1000))
        node.create_subscription(MarkerArray, "arm_markers", self.arrays.append, stream_qos(100))
        node.create_subscription(String, "robot_description",
                                 lambda m: self.descriptions.append(m.data), latched_qos())
        self.k = 0

    def _keep(self, m: JointState) -> None:
        self.torques[m.header.stamp.sec * 10**9 + m.header.stamp.nanosec] = m

    def feed(self, seconds: float, rate: float = 200.0) -> None:
        """joint_states at ~rate for `seconds`, a random smooth posture, spinning meanwhile."""
        for _ in range(int(seconds * rate)):
            self.k += 1
            t = self.k / rate
            m = JointState(name=list(JOINT_NAMES))
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(self.k * 5_000_000 + 10**18, 10**9)
            m.position = (0.3 + 0.3 * np.sin(t * (1 + np.arange(20) / 10))).tolist()
            m.velocity = (0.3 * (1 + np.arange(20) / 10) * np.cos(t * (1 + np.arange(20) / 10))).tolist()
            self.pub.publish(m)
            self.peer.spin_for(1.0 / rate)


def _expected(arm, msg: JointState, arrows: bool = False) -> MarkerMaker:
    maker = MarkerMaker(ArmScene(arm), TorqueColours(arm.joint_names), arrows=arrows)
    idx = [list(msg.name).index(n) for n in arm.joint_names]
    return maker.frame(np.array(msg.position)[idx], np.array(msg.effort)[idx])


def _check_array(viewer: Viewer, array: MarkerArray, arm) -> None:
    shapes = [m for m in array.markers if m.action == Marker.ADD]
    stamp = shapes[0].header.stamp.sec * 10**9 + shapes[0].header.stamp.nanosec
    assert stamp in viewer.torques, "an array not drawn from a joint_torques of ours"
    want = _expected(arm, viewer.torques[stamp])
    assert [m.ns for m in shapes] == list(want.ns)
    for m, p, o, s, c in zip(shapes, want.positions, want.orientations, want.scales, want.rgba):
        assert m.header.frame_id == "humerus"
        np.testing.assert_allclose([m.pose.position.x, m.pose.position.y, m.pose.position.z], p,
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose([m.pose.orientation.x, m.pose.orientation.y,
                                    m.pose.orientation.z, m.pose.orientation.w], o, atol=1e-9)
        np.testing.assert_allclose([m.scale.x, m.scale.y, m.scale.z], s, rtol=0, atol=1e-12)
        np.testing.assert_allclose([m.color.r, m.color.g, m.color.b, m.color.a], c, atol=1e-6)


def _set(peer, node: str, **params) -> object:
    client = peer.node.create_client(SetParameters, f"/{node}/set_parameters")
    assert client.wait_for_service(timeout_sec=rosproc.STARTUP_S)
    f = client.call_async(SetParameters.Request(
        parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in params.items()]))
    assert peer.spin_until(f.done, 20)
    peer.node.destroy_client(client)
    return f.result().results[0]


def _last_model(viewer: Viewer, arm, seconds: float = 20.0) -> MarkerArray:
    """Feed until an array of `arm`'s solids (sizes) arrives; that array."""
    scales = MarkerMaker(ArmScene(arm), TorqueColours(arm.joint_names)).scales

    def drawn() -> bool:
        if not viewer.arrays:
            return False
        shapes = [m for m in viewer.arrays[-1].markers if m.action == Marker.ADD]
        return len(shapes) == len(scales) and np.allclose(
            [[m.scale.x, m.scale.y, m.scale.z] for m in shapes], scales, rtol=0, atol=1e-12)

    for _ in range(int(seconds / 0.5)):
        viewer.feed(0.5)
        if drawn():
            return viewer.arrays[-1]
    raise AssertionError(f"no array of {arm!r} in {seconds} s")


def test_markers_follow_the_torque_node_live():
    torque = rosproc.start("torque_node", "-p", "estimator:=backward")
    viz = rosproc.start("arm_viz")
    peer = rosproc.Peer("viz_test")
    try:
        viewer = Viewer(peer)
        assert peer.spin_until(lambda: viewer.pub.get_subscription_count() > 0,
                               rosproc.STARTUP_S), torque.output()
        p50 = build_model("segmented", 50)
        first = _last_model(viewer, p50)
        _check_array(viewer, first, p50)
        assert viewer.descriptions and viewer.descriptions[-1] == p50.to_urdf()
        n = len(viewer.arrays)
        viewer.feed(1.0)
        assert len(viewer.arrays) - n >= 10  # ~30 Hz, from 200 Hz input (loaded machine)
        for array in viewer.arrays[-5:]:
            _check_array(viewer, array, p50)

        # a live body-size change of the torque node reaches the drawn arm
        assert _set(peer, "torque_node", body_size=95).successful
        p95 = build_model("segmented", 95)
        arr = _last_model(viewer, p95)
        _check_array(viewer, arr, p95)
        switch = next(a for a in viewer.arrays if any(m.action == Marker.DELETEALL for m in a.markers))
        assert switch.markers[0].action == Marker.DELETEALL  # the old arm is cleared first
        assert peer.spin_until(lambda: viewer.descriptions[-1] == p95.to_urdf(), 10)
        # and a payload appears as a sphere named payload
        assert _set(peer, "torque_node", payload_mass=0.6).successful
        held = build_model("segmented", 95, payload_mass=0.6)
        arr = _last_model(viewer, held)
        assert any(m.ns == "payload" and m.type == Marker.SPHERE for m in arr.markers)
        _check_array(viewer, arr, held)
        # arm_viz's own model parameters do not override the torque node's config
        assert _set(peer, "arm_viz", body_size=5).successful
        viewer.feed(1.0)
        _check_array(viewer, viewer.arrays[-1], held)
        # a bad value is refused by name, the node carries on
        r = _set(peer, "arm_viz", **{"color_full_scale.elbow": -1.0})
        assert not r.successful
        viewer.feed(0.5)
        _check_array(viewer, viewer.arrays[-1], held)
    finally:
        peer.close()
        for p in (viz, torque):
            assert p.stop() == 0, p.output()[-2000:]
    assert "Traceback" not in viz.output()


def test_without_a_torque_node_its_own_model_is_drawn_and_follows_its_parameters():
    """Torques from elsewhere (a replayed bag, a controller): arm_viz's own model parameters,
    arrows on; a live change of its own body size and side is drawn."""
    viz = rosproc.start("arm_viz", "-p", "arrows:=true", "-p", "side:=left")
    peer = rosproc.Peer("viz_own")
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_torques", stream_qos(100))
        arrays: list[MarkerArray] = []
        node.create_subscription(MarkerArray, "arm_markers", arrays.append, stream_qos(100))
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, rosproc.STARTUP_S), viz.output()

        def send(k: int) -> JointState:
            m = JointState(name=list(JOINT_NAMES)[::-1])  # any order: matched by name
            m.header.stamp.sec, m.header.stamp.nanosec = 1000 + k, 0
            m.position = RNG.uniform(-0.2, 0.2, 20).tolist()
            m.effort = RNG.normal(0, 0.5, 20).tolist()
            pub.publish(m)
            return m

        def drawn(arm, sent) -> bool:
            deadline = time.monotonic() + 30.0  # a loaded machine: seconds to the first array
            while time.monotonic() < deadline:
                m = send(len(sent))
                sent[1000 + len(sent)] = m
                peer.spin_for(0.1)
                if not arrays:
                    continue
                a = arrays[-1]
                stamp = a.markers[-1].header.stamp.sec
                want = _expected(arm, sent[stamp], arrows=True)
                got = [x for x in a.markers if x.action == Marker.ADD]
                if len(got) == len(want.ns) + len(want.arrow_ns) and np.allclose(
                        [[x.scale.x, x.scale.y, x.scale.z] for x in got[:len(want.ns)]],
                        want.scales, atol=1e-12):
                    for x, (s, e) in zip(got[len(want.ns):], want.arrows):
                        assert x.type == Marker.ARROW and x.ns.startswith("torque/")
                        np.testing.assert_allclose([[p.x, p.y, p.z] for p in x.points], [s, e],
                                                   atol=1e-9)
                    return True
            return False

        sent: dict[int, JointState] = {}
        assert drawn(build_model("segmented", 50, side="left"), sent), viz.output()
        assert _set(peer, "arm_viz", body_size="female_5").successful
        assert drawn(build_model("segmented", "female_5", side="left"), sent), viz.output()
        # a config that names no buildable model: one warning, the drawn arm stays
        cfg_pub = node.create_publisher(String, "torque_node/config", latched_qos())
        cfg_pub.publish(String(data='{"schema": 2, "model": "octopus"}'))
        assert viz.wait_for_output("ignoring a config message", 20), viz.output()
        assert drawn(build_model("segmented", "female_5", side="left"), sent), viz.output()
        # torques without the model's joints: one warning, the node keeps running
        bad = JointState(name=["elbow_flexion"], position=[0.1], effort=[0.2])
        pub.publish(bad)
        peer.spin_for(0.5)
        assert viz.wait_for_output("not drawing joint_torques", 10), viz.output()
        assert drawn(build_model("segmented", "female_5", side="left"), sent)
    finally:
        peer.close()
        assert viz.stop() == 0, viz.output()[-2000:]
    assert "Traceback" not in viz.output()


def test_the_forearm_takes_its_strongest_muscles_colour_while_muscle_forces_keep_up():
    """issue 31 item 4: with muscle_forces of the same stamps as the torques, the forearm's
    links are viridis of the strongest forearm muscle's activation (RI2, a hand muscle, is
    higher and ignored) and a label names it; with muscle_forces 2 s behind the torques the
    forearm is back in its torque colours and no label is drawn (a stale label would lie)."""
    viz = rosproc.start("arm_viz", "-p", "config_topic:=''")
    peer = rosproc.Peer("viz_muscles")
    try:
        node = peer.node
        tpub = node.create_publisher(JointState, "joint_torques", stream_qos(100))
        mpub = node.create_publisher(JointState, "muscle_forces", stream_qos(100))
        arrays: list[MarkerArray] = []
        node.create_subscription(MarkerArray, "arm_markers", arrays.append, stream_qos(100))
        assert peer.spin_until(lambda: tpub.get_subscription_count() > 0
                               and mpub.get_subscription_count() > 0, rosproc.STARTUP_S), \
            viz.output()
        mm = load_muscle_model()
        act = np.full(mm.n, 0.01)
        act[mm.names.index("RI2")] = 0.9
        act[mm.names.index("ECRB")] = 0.42
        arm = build_model("segmented", 50)
        sent: dict[int, JointState] = {}

        def send(k: int, skew_ns: int) -> None:
            t = 2000 * 10**9 + k * 20_000_000
            m = JointState(name=list(JOINT_NAMES))
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(t, 10**9)
            m.position = RNG.uniform(-0.2, 0.2, 20).tolist()
            m.effort = RNG.normal(0, 0.5, 20).tolist()
            f = JointState(name=list(mm.names), position=act.tolist())
            f.header.stamp.sec, f.header.stamp.nanosec = divmod(t + skew_ns, 10**9)
            mpub.publish(f)  # the muscles first: arm_viz draws on its next tick
            tpub.publish(m)
            sent[t] = m

        def newest(k0: int, skew_ns: int, seconds: float = 30.0) -> MarkerArray:
            """Send until an array drawn from torques sent from k0 on arrives; that array."""
            k, deadline = k0, time.monotonic() + seconds
            while time.monotonic() < deadline:
                send(k, skew_ns)
                k += 1
                peer.spin_for(0.05)
                for a in reversed(arrays):
                    s = a.markers[-1].header.stamp
                    t = s.sec * 10**9 + s.nanosec
                    if t in sent and t >= 2000 * 10**9 + k0 * 20_000_000 + 100_000_000:
                        return a
            raise AssertionError(f"no array in {seconds} s\n{viz.output()[-2000:]}")

        forearm = {"forearm_proximal", "forearm_distal"}
        a = newest(0, 0)
        label = [m for m in a.markers if m.ns == "muscle/strongest"]
        assert len(label) == 1 and label[0].text == "ECRB 0.42", [m.text for m in label]
        for m in a.markers:
            if m.ns in forearm:
                np.testing.assert_allclose([m.color.r, m.color.g, m.color.b], viridis(0.42),
                                           atol=1e-6)
        b = newest(1000, -2 * 10**9)  # muscle_forces 2 s behind: not drawn
        assert not [m for m in b.markers if m.ns == "muscle/strongest"]
        s = b.markers[-1].header.stamp
        plain = _expected(arm, sent[s.sec * 10**9 + s.nanosec])
        shapes = [m for m in b.markers if m.action == Marker.ADD]
        for m, c in zip(shapes, plain.rgba):
            np.testing.assert_allclose([m.color.r, m.color.g, m.color.b, m.color.a], c, atol=1e-6)
    finally:
        peer.close()
        assert viz.stop() == 0, viz.output()[-2000:]
    assert "Traceback" not in viz.output()
