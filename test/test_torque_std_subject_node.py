"""The σ's subject part through the real torque_node (a process, loopback DDS): started with
`subject_std:=ansur` its σ is the offline API's with subject="ansur" and ~/config states the
ANSUR group; switched live to `none`, the samples from the new config on carry the σ without
it (the σ a TorqueStd rebuilt at that sample gives, as the node rebuilds it), and the
config says "off".
"""

from __future__ import annotations

import json
import math
import signal
import time

import numpy as np
import pytest
import rosproc
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.movements import get_movement
from forearm_dynamics.nodes.common import latched_qos, stream_qos
from forearm_dynamics.uncertainty import TorqueStd, inverse_dynamics_with_std

pytestmark = pytest.mark.ros

RATE = 100.0


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def switched(arm, stamps, q, switch: int, after: str = "none") -> np.ndarray:
    """σ offline as the node computes it across a live switch from subject ansur to none: one
    estimator throughout, a new TorqueStd (fresh state source, the jerk history carried on, as
    nodes/torque_config.build_bundle does) from the first sample at or after `switch`, with
    subject `after` ("none": the node's switch; "ansur": the same path with the part kept)."""
    est = make_estimator("kalman", arm.nv)
    ts = TorqueStd(arm, est, subject="ansur")
    out = np.full(q.shape, np.nan)
    fresh = False
    for k, s in enumerate(stamps):
        if s >= switch and not fresh:
            fresh = True
            jerk, ts = ts.jerk, TorqueStd(arm, est, subject=after)
            ts.jerk = jerk
        est.update(int(s), q[k], None)
        if ts.update(int(s), False):
            out[k] = ts.std
    return out


def test_subject_part_through_the_node_and_its_live_switch() -> None:
    mv = get_movement(4)
    # 0.6 s held first: the σ is known once the filter runs with a measured noise (~0.5 s)
    t = np.concatenate([np.arange(-60, 0) / RATE, mv.sample_times(RATE)])
    q = mv.evaluate(t)[0] + np.random.default_rng(7).normal(0.0, math.radians(0.5), (len(t), 20))
    t0 = (time.time_ns() // 1_000_000) * 1_000_000
    stamps = t0 + np.arange(len(q), dtype=np.int64) * round(1e9 / RATE)
    arm = build_model(body_size="female_50")
    on = inverse_dynamics_with_std(arm, stamps, q, t_in_ns=True, subject="ansur")
    off = inverse_dynamics_with_std(arm, stamps, q, t_in_ns=True)
    proc = rosproc.start("torque_node", "-p", "diagnostics_period:=0.0", "-p", "publish_std:=true",
                         "-p", "subject_std:=ansur", "-p", "body_size:=female_50")
    peer = rosproc.Peer("subject_std_test")
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        stds: dict[int, JointState] = {}
        configs: list[dict] = []
        node.create_subscription(JointState, "joint_torques_std",
                                 lambda m: stds.setdefault(stamp_of(m), m), stream_qos(1000))
        node.create_subscription(String, "/torque_node/config",
                                 lambda m: configs.append(json.loads(m.data)), latched_qos())
        client = node.create_client(SetParametersAtomically, "/torque_node/set_parameters_atomically")
        assert client.wait_for_service(timeout_sec=rosproc.STARTUP_S), proc.output()
        assert peer.spin_until(lambda: pub.get_subscription_count() > 0 and configs,
                               rosproc.STARTUP_S), proc.output()
        assert "ANSUR II female (n = 1986)" in configs[-1]["std"]["subject_parameters"]

        msg = JointState()
        msg.name = list(JOINT_NAMES)

        def send(ks) -> None:
            for k in ks:
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamps[k]), 1_000_000_000)
                msg.position = q[k].tolist()
                pub.publish(msg)
                peer.spin_for(0.0005)

        half = len(q) // 2
        send(range(half))
        assert peer.spin_until(lambda: int(stamps[half - 1]) in stds, 30), proc.output()[-2000:]
        req = SetParametersAtomically.Request(parameters=[Parameter("subject_std", value="none")
                                                          .to_parameter_msg()])
        fut = client.call_async(req)
        assert peer.spin_until(fut.done, 20) and fut.result().result.successful, proc.output()[-2000:]
        # the new model built (announced, not yet applied: it applies at the next sample)
        assert peer.spin_until(lambda: any(c["std"]["subject_parameters"].startswith("off")
                                           for c in configs), 20), proc.output()[-2000:]
        send(range(half, len(q)))
        assert peer.spin_until(lambda: int(stamps[-1]) in stds and any(
            c.get("applies_from_stamp_ns") and c["std"]["subject_parameters"].startswith("off")
            for c in configs), 30), proc.output()[-2000:]
        peer.spin_for(0.3)
    finally:
        peer.close()
        assert proc.stop(signal.SIGINT) == 0, proc.output()[-2000:]
    assert "Traceback" not in proc.output()
    assert len(stds) == len(stamps)  # one σ per sample, none lost
    switch = min(c["applies_from_stamp_ns"] for c in configs if c.get("applies_from_stamp_ns")
                 and c["std"]["subject_parameters"].startswith("off"))
    got = np.array([stds[int(s)].effort for s in stamps])
    warm = on.known  # σ known: warm and the noise measured
    before, after = warm & (stamps < switch), warm & (stamps >= switch)
    assert before.sum() > 50 and after.sum() > 50
    np.testing.assert_allclose(got[before], on.std[before], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got[after], switched(arm, stamps, q, switch)[after], rtol=1e-12, atol=1e-15)
    assert np.all(on.std[warm] > off.std[warm])  # the part is there: the two differ everywhere
    # and it is gone after the switch: the node's σ is below the σ with it on every sample
    # (the same path with the part kept: a fresh state source re-derives Σ from the noise
    # measured at the switch, which moves the σ by a few % against the one it replaced)
    assert np.all(got[after] < switched(arm, stamps, q, switch, after="ansur")[after])
