"""A raw recording of the real corpus replayed into a real torque_node with its defaults
(issue 29): its torques must be no worse than the causal 6 Hz Butterworth baseline at the
same stamps, per DOF, against the offline practice (6 Hz zero-phase + derivatives).

Recording: `ue_adl_ADL010_DR1` (UE-ADL subject ADL010, drinking from a cup, right arm,
Vicon 100 Hz, angles derived from the raw markers: benchmarks/corpus; held-out half). The
node gets every joint (the unmeasured ones at 0, as mot_to_bag sends them), stamps at the
recording's 100 Hz from now. Scored after realscore.SETTLE_S (1 s), NRMSE = RMSE / the
reference's peak-to-peak, on the stamps the node answered. The bound is the issue's target,
"never worse than the causal 6 Hz Butterworth on any DOF of any raw recording": ratio <= 1.0
per measured DOF (elbow, pro/sup, wrist flexion, wrist deviation). The model alone (the
default before issue 29's practice filter: estimator.practice_filter 0) did not meet it here
(wrist flexion 1.083 x). The last test shows the benchmark's offline path is the node's: the
node's torques equal realscore.node_outputs' at equal stamps.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState
from support.jointstate import joint_state, stamp_of

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.offline import realscore

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
RECORDING = "ue_adl_ADL010_DR1"
BOUND = 1.0  # × the causal Butterworth, per DOF (the target; see the docstring)
CHUNK = 100  # samples published before waiting for the node's answer to the last one


def _recording():
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from benchmarks.corpus import load

    return next(r for r in load("held_out") if r.name == RECORDING)


@pytest.fixture(scope="module")
def replay():
    return _replay()  # no parameter: the defaults a user gets


def _replay(*ros_args: str):
    rec = _recording()
    node = rosproc.start("torque_node", *ros_args)
    peer = rosproc.Peer("real_corpus_test")
    replies: list[JointState] = []
    sub = peer.node.create_subscription(JointState, "joint_torques", replies.append, stream_qos(1000))
    pub = peer.node.create_publisher(JointState, "joint_states", stream_qos(1000))
    t0 = (peer.node.get_clock().now().nanoseconds // 1_000_000) * 1_000_000
    stamps = t0 + (rec.stamps_ns - rec.stamps_ns[0])
    try:
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        assert peer.spin_until(lambda: sub.get_publisher_count() > 0 and pub.get_subscription_count() > 0,
                               rosproc.STARTUP_S), node.output()
        for a in range(0, len(stamps), CHUNK):
            for k in range(a, min(a + CHUNK, len(stamps))):
                pub.publish(joint_state(int(stamps[k]), rec.q[k], None))
            last = int(stamps[min(a + CHUNK, len(stamps)) - 1])
            ok = peer.spin_until(lambda last=last: any(stamp_of(r) == last for r in replies), 120)
            assert ok, f"no answer to stamp {last}\n{node.output()[-3000:]}"
        peer.spin_for(0.2)
    finally:
        peer.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.output(), node.output()[-2000:]
    out_st = np.array([stamp_of(r) for r in replies], np.int64)
    order = np.argsort(out_st)
    effort = np.array([r.effort for r in replies])[order]
    names = list(replies[0].name)
    assert names == list(JOINT_NAMES)
    return rec, stamps, out_st[order], effort


def _scores(rec, stamps, out_st, tau, arm):
    f, v, a = realscore.practice(stamps, rec.q)
    tau_ref = arm.inverse_dynamics_batch(f, v, a)
    return realscore.score(out_st, tau[:, rec.columns], stamps, tau_ref[:, rec.columns])


def test_raw_recording_through_torque_node_no_worse_than_butterworth(replay) -> None:
    _no_worse_than_butterworth(replay, "defaults")


def _no_worse_than_butterworth(replay, what: str) -> None:
    rec, stamps, out_st, effort = replay
    arm = build_model("segmented", 50, side=rec.side)
    assert (np.diff(out_st) > 0).all() and np.isin(out_st, stamps).all()
    assert len(out_st) >= len(stamps) - 5
    base = realscore.node_outputs(stamps, rec.q, "butterworth", {"butterworth_cutoff_hz": 6.0})
    common = np.intersect1d(out_st, base.stamps_ns)
    node_tau = effort[np.isin(out_st, common)]
    base_tau = arm.inverse_dynamics_batch(base.q, base.qd, base.qdd)[np.isin(base.stamps_ns, common)]
    node_sc = _scores(rec, stamps, common, node_tau, arm)
    base_sc = _scores(rec, stamps, common, base_tau, arm)
    ratio = dict(zip(rec.measured, (node_sc.settled / base_sc.settled).round(3).tolist(), strict=True))
    print(f"\n{RECORDING}: torque_node ({what}) NRMSE settled "
          + ", ".join(f"{j} {100 * x:.1f} %" for j, x in zip(rec.measured, node_sc.settled, strict=True))
          + f"; × causal 6 Hz Butterworth: {ratio}")
    worse = {j: x for j, x in ratio.items() if x > BOUND}
    assert not worse, f"torque_node ({what}) worse than the causal 6 Hz Butterworth on {worse}"


def test_node_torques_are_the_offline_replays(replay) -> None:
    from forearm_dynamics.estimation import DEFAULT_ESTIMATOR

    _equals_offline(replay, DEFAULT_ESTIMATOR)


def _equals_offline(replay, estimator: str) -> None:
    rec, stamps, out_st, effort = replay
    arm = build_model("segmented", 50, side=rec.side)
    off = realscore.node_outputs(stamps, rec.q, estimator)
    tau = arm.inverse_dynamics_batch(off.q, off.qd, off.qdd)
    both = np.intersect1d(out_st, off.stamps_ns)
    assert len(both) >= len(stamps) - 5
    dev = np.abs(effort[np.isin(out_st, both)] - tau[np.isin(off.stamps_ns, both)]).max()
    assert dev < 1e-6, dev
