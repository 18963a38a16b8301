"""A noisy, positions-only, slow sensor through the torque node with default parameters
(its estimator: DEFAULT_ESTIMATOR, `kalman`, which is also RECOMMENDED_FOR_MEASURED_INPUT):
real processes over loopback DDS.

trajectory_publisher plays movements as a motion-capture-like sensor (100 Hz, 0.5 deg
Gaussian noise on every position, no velocities); torque_node runs with no parameter at all.
Its torques are scored against the noiseless truth (the model's inverse dynamics of the
analytic movement at each output stamp), globally normalised per DOF as in the estimation
benchmark (benchmarks/estimation.py; docs/estimation.md). The bound comes from that
benchmark: at 100 Hz and 0.5 deg the default estimator gives about 10 % (elbow) and 5 %
(pro/sup) over the 65 movements, normalised by the library's range; these three movements,
normalised by their own range, gave 15 % / 14 % offline for five noise seeds (the backward
difference, the node's old default: 249 % / 226 %). The bound is 25 % for both: a node that
lost its filtering fails it by an order of magnitude, a slow machine does not change it (the
stamps, not the clock, drive the estimator). The movements are separated by a 0.3 s pause
(separate recordings, as in the benchmark): played back to back, the posture jumps between
them (e.g. the elbow from 130 deg to 0 in one sample), which no sensor reports."""

import json

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES, build_model, get_movement
from forearm_dynamics.estimation import DEFAULT_ESTIMATOR, RECOMMENDED_FOR_MEASURED_INPUT
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.nodes.trajectory_publisher import marker_qos

pytestmark = pytest.mark.ros

MOVEMENTS = [4, 14, 30]  # pronation, wrist flexion + adduction, opening the hand: elbow moving
RATE_HZ = 100.0
BOUND = 0.25  # global NRMSE, elbow and pro/sup (see the module docstring)


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


@pytest.fixture(scope="module")
def run():
    node = rosproc.start("torque_node")  # no parameter: the defaults a user gets
    peer = rosproc.Peer("measured_input_test")
    outputs: list[JointState] = []
    markers: list[dict] = []
    torques = peer.node.create_subscription(JointState, "joint_torques", outputs.append,
                                            stream_qos(1000))
    peer.node.create_subscription(String, "movement", lambda m: markers.append(json.loads(m.data)),
                                  marker_qos())
    pub = None
    try:
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        # the node's answers are volatile: listen before the first one is sent
        assert peer.spin_until(lambda: torques.get_publisher_count() > 0, rosproc.STARTUP_S), node.output()
        pub = rosproc.start("trajectory_publisher", "-p", f"movements:={MOVEMENTS}",
                            "-p", f"rate_hz:={RATE_HZ}", "-p", "noise_deg:=0.5",
                            "-p", "publish_velocity:=false", "-p", "seed:=11",
                            "-p", "gap:=0.3", "-p", "start_delay:=1.0", "-p", "min_subscribers:=1",
                            "-p", "subscriber_timeout:=30.0")
        n_expected = round(len(MOVEMENTS) * 1.5 * RATE_HZ)
        assert peer.spin_until(lambda: not pub.running() and len(outputs) >= n_expected - 3, 90), \
            (len(outputs), pub.output()[-2000:])
        peer.spin_for(0.5)
        assert pub.wait(timeout=30) == 0, pub.output()
    finally:
        if pub is not None and pub.running():
            pub.stop()
        peer.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.output(), node.output()[-2000:]
    return outputs, markers, node.output()


def test_default_node_gives_torques_near_the_noiseless_truth(run) -> None:
    outputs, markers, log = run
    assert DEFAULT_ESTIMATOR == RECOMMENDED_FOR_MEASURED_INPUT
    assert [m["id"] for m in markers] == MOVEMENTS
    assert all(m["sensor"]["noise_deg"] == 0.5 and not m["sensor"]["publish_velocity"]
               for m in markers)
    arm = build_model("segmented", 50)
    stamps = np.array([stamp_ns(m) for m in outputs])
    assert (np.diff(stamps) > 0).all()
    effort = np.array([m.effort for m in outputs])
    truth = np.full_like(effort, np.nan)
    for mk in markers:
        mv = get_movement(mk["id"])
        inside = (stamps >= mk["t0_ns"]) & (stamps < mk["t0_ns"] + round(mv.duration * 1e9))
        t = (stamps[inside] - mk["t0_ns"]) * 1e-9
        q, qd, qdd = mv.evaluate(t)
        truth[inside] = arm.inverse_dynamics(q, qd, qdd)
    scored = np.isfinite(truth).all(axis=1)
    assert scored.sum() >= 0.95 * len(outputs)
    err = effort[scored] - truth[scored]
    rmse = np.sqrt((err ** 2).mean(axis=0))
    ptp = np.ptp(truth[scored], axis=0)
    nrmse = {name: rmse[i] / ptp[i] for i, name in enumerate(JOINT_NAMES)}
    print(f"\nglobal torque NRMSE, {DEFAULT_ESTIMATOR}, {RATE_HZ:g} Hz, 0.5 deg, positions only: "
          f"elbow {100 * nrmse['elbow_flexion']:.1f} %, pro/sup {100 * nrmse['pro_sup']:.1f} %")
    assert nrmse["elbow_flexion"] < BOUND and nrmse["pro_sup"] < BOUND, nrmse
    assert f"estimator {DEFAULT_ESTIMATOR}" in log
