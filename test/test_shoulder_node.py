"""torque_node with a moving shoulder, real processes over loopback DDS: the shoulder angles
in joint_states (an OpenSim full-body model's names), or an Imu on the upper arm; every
sample answered, the torques those of the humerus where the input puts it."""

import time

import numpy as np
import pytest
import rosproc
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, JointState

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.shoulder import ENU_TO_WORLD

pytestmark = pytest.mark.ros

FULLBODY = ["arm_flex_r", "arm_add_r", "arm_rot_r"]
PUBLIC = ["arm_flexion", "arm_adduction", "arm_rotation"]
POSTURE = np.zeros(20)
POSTURE[0] = np.pi / 2  # elbow flexed 90°
SHOULDER = np.array([np.pi / 2, -0.3, 0.2])  # humerus swung forward, a little abducted


def joint_msg(names, q, stamp_ns: int) -> JointState:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.name = list(names)
    m.position = [float(x) for x in q]
    return m


def imu_msg(stamp_ns: int) -> Imu:
    """The orientation of SHOULDER's humerus, in REP 103's ENU world (sensor = humerus frame)."""
    r_world = Rotation.from_euler("ZXY", SHOULDER).as_matrix()
    x, y, z, w = Rotation.from_matrix(ENU_TO_WORLD.T @ r_world).as_quat()
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = x, y, z, w
    return m


def drive(node_args, names, q, n: int = 60, rate: float = 100.0, imu: bool = False):
    node = rosproc.start("torque_node", "-p", "shoulder:=fullbody", *node_args)
    peer = rosproc.Peer("shoulder_node_test")
    outs: list[JointState] = []
    peer.node.create_subscription(JointState, "joint_torques", outs.append, stream_qos(1000))
    pub = peer.node.create_publisher(JointState, "joint_states", stream_qos(1000))
    imu_pub = peer.node.create_publisher(Imu, "upper_arm/imu", stream_qos(1000)) if imu else None
    stamps = []
    try:
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, rosproc.STARTUP_S), node.output()
        if imu_pub is not None:
            assert peer.spin_until(lambda: imu_pub.get_subscription_count() > 0, rosproc.STARTUP_S)
            for _ in range(20):  # the orientation is known before the first joint sample
                imu_pub.publish(imu_msg(time.time_ns()))
                peer.spin_for(0.02)
        peer.spin_for(0.5)
        t0 = time.time_ns()
        for k in range(n):
            s = t0 + round(k * 1e9 / rate)
            if imu_pub is not None:
                imu_pub.publish(imu_msg(s))
            pub.publish(joint_msg(names, q, s))
            stamps.append(s)
            peer.spin_for(1.0 / rate)
        peer.spin_until(lambda: len(outs) >= n, 15)
    finally:
        peer.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.output(), node.output()[-2000:]
    return outs, stamps


def _expected() -> np.ndarray:
    return build_model("segmented", shoulder="fullbody").gravity_torques(np.concatenate([POSTURE, SHOULDER]))


def _check(outs, stamps) -> None:
    stamp = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in outs]
    assert stamp == stamps  # every sample answered, in order
    last = outs[-1]
    assert list(last.name) == [*JOINT_NAMES, *PUBLIC]
    expected = _expected()
    welded = build_model("segmented").gravity_torques(POSTURE)
    # a still input: the estimate is at rest, the torques are gravity's with the humerus moved
    assert np.allclose(last.effort, expected, atol=1e-6)
    assert abs(expected[0] - welded[0]) > 1.0  # the humerus' direction matters here


def test_shoulder_angles_in_joint_states_with_opensim_fullbody_names() -> None:
    outs, stamps = drive([], [*JOINT_NAMES, *FULLBODY], np.concatenate([POSTURE, SHOULDER]))
    _check(outs, stamps)


def test_shoulder_from_an_imu_on_the_upper_arm() -> None:
    outs, stamps = drive(["-p", "imu_topic:=upper_arm/imu"], JOINT_NAMES, POSTURE, imu=True)
    _check(outs, stamps)
