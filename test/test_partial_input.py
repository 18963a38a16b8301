"""torque_node with the sensors people have, real processes over loopback DDS: a sensor
that measures two joints (missing_joints: hold answers every sample; the default refuses it
naming the missing joints), a chosen delay (estimator.delay_s: outputs stamped with the
lagged samples' stamps), and the fixed-rate output that waits for a warm estimator."""

import itertools
import json
import time

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES
from forearm_dynamics.nodes.common import latched_qos, stream_qos

pytestmark = pytest.mark.ros

TWO = ["elbow_flexion", "pro_sup"]


def msg(names, q, stamp_ns: int) -> JointState:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.name = list(names)
    m.position = [float(x) for x in q]
    return m


def stamp_of(m) -> int:
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def drive(node_args, n: int, rate: float = 100.0, names=TWO, wait_outputs: int | None = None):
    """Start torque_node, stream n samples of `names` at `rate` (stamps on this clock),
    collect outputs and configs; (outputs, input stamps, configs, node log)."""
    node = rosproc.start("torque_node", *node_args)
    peer = rosproc.Peer("partial_input_test")
    outs: list[JointState] = []
    configs: list[dict] = []
    peer.node.create_subscription(JointState, "joint_torques", outs.append, stream_qos(1000))
    peer.node.create_subscription(String, "/torque_node/config",
                                  lambda m: configs.append(json.loads(m.data)), latched_qos())
    pub = peer.node.create_publisher(JointState, "joint_states", stream_qos(1000))
    stamps = []
    try:
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, rosproc.STARTUP_S), node.output()
        peer.spin_for(0.5)
        t0 = time.time_ns()
        for k in range(n):
            s = t0 + round(k * 1e9 / rate)
            q = [0.5 + 0.3 * np.sin(2 * np.pi * 0.5 * k / rate)] * len(names)
            pub.publish(msg(names, q, s))
            stamps.append(s)
            peer.spin_for(1.0 / rate)
        want = n if wait_outputs is None else wait_outputs
        peer.spin_until(lambda: len(outs) >= want, 15)
        peer.spin_for(1.2)  # a diagnostics period: the config restated with the held joints
    finally:
        peer.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.output(), node.output()[-2000:]
    return outs, stamps, configs, node.output()


def test_hold_answers_every_sample_of_a_two_joint_stream() -> None:
    outs, stamps, configs, _ = drive(["-p", "missing_joints:=hold",
                                      "-p", "hold_posture.wrist_flexion:=0.3"], 80)
    assert [stamp_of(m) for m in outs] == stamps  # every sample answered, in order
    last = outs[-1]
    assert list(last.name) == list(JOINT_NAMES)
    held = [j for j in JOINT_NAMES if j not in TWO]
    pos = dict(zip(last.name, last.position, strict=True))
    vel = dict(zip(last.name, last.velocity, strict=True))
    assert pos["wrist_flexion"] == pytest.approx(0.3) and pos["index_mcp_flexion"] == 0.0
    assert all(vel[j] == 0.0 for j in held)
    assert np.isfinite(last.effort).all()
    stated = [c["input"] for c in configs if c.get("input", {}).get("held_joints")]
    assert stated and stated[-1]["missing_joints"] == "hold"
    assert stated[-1]["held_joints"] == held
    assert stated[-1]["hold_posture"]["wrist_flexion"] == pytest.approx(0.3)


def test_reject_by_default_names_the_missing_joints() -> None:
    outs, _, configs, log = drive([], 30, wait_outputs=1)
    assert outs == []
    assert "missing_joint" in log and "18 model joint(s) missing" in log and "wrist_flexion" in log
    assert "missing_joints:=hold" in log  # says what to do
    assert configs and configs[-1]["input"]["missing_joints"] == "reject"


def test_delay_outputs_carry_the_lagged_samples_stamps() -> None:
    n, lags = 60, 5  # 0.05 s at 100 Hz
    outs, stamps, configs, _ = drive(["-p", "estimator.delay_s:=0.05"], n, names=list(JOINT_NAMES),
                                     wait_outputs=n - lags)
    assert [stamp_of(m) for m in outs] == stamps[: n - lags]
    assert configs[-1]["estimator"]["delay_s"] == 0.05


def test_fixed_rate_output_waits_for_a_warm_estimator() -> None:
    """output_rate_hz 1000: one input sample alone publishes nothing (it used to repeat it,
    7 identical outputs before the second sample); after three (positions only) it runs."""
    node = rosproc.start("torque_node", "-p", "output_rate_hz:=1000.0", "-p", "input_timeout:=1.0")
    peer = rosproc.Peer("partial_input_rate")
    outs: list[JointState] = []
    peer.node.create_subscription(JointState, "joint_torques", outs.append, stream_qos(1000))
    pub = peer.node.create_publisher(JointState, "joint_states", stream_qos(1000))
    try:
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0, rosproc.STARTUP_S), node.output()
        peer.spin_for(0.5)
        t0 = time.time_ns()
        pub.publish(msg(JOINT_NAMES, [0.2] * 20, t0))
        peer.spin_for(0.4)
        assert outs == []  # one sample: not warm, nothing published
        pub.publish(msg(JOINT_NAMES, [0.2] * 20, t0 + 10_000_000))
        pub.publish(msg(JOINT_NAMES, [0.2] * 20, t0 + 20_000_000))
        assert peer.spin_until(lambda: len(outs) >= 20, 10)
    finally:
        peer.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.output(), node.output()[-2000:]
    stamps = [stamp_of(m) for m in outs]
    assert all(b > a for a, b in itertools.pairwise(stamps))
