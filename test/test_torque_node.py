"""torque_node as a real process over loopback DDS: torques, name matching, rejections,
parameters, diagnostics, latched config, signals. null_echo_node shares the pipeline."""

from __future__ import annotations

import json
import signal
import time

import numpy as np
import pytest
import rosproc
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import DescribeParameters, SetParameters
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from support.jointstate import joint_state, stamp_of
from support.torque_harness import TorqueHarness

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.description import load_description
from forearm_dynamics.model_config import model_from_config
from forearm_dynamics.nodes.common import CONFIG_TOPIC, latched_qos, stream_qos

pytestmark = pytest.mark.ros

MODEL = build_model("segmented", 50)
MS = 1_000_000  # ns
RNG = np.random.default_rng(7)
POSTURE = RNG.uniform(-0.5, 0.8, 20)


@pytest.fixture(scope="module")
def tn(module_procs):
    """One torque_node (backward estimator: its every output is exactly known, so these tests
    check the node's pipeline to 1e-8; the default one end to end: below) on the session's
    domain, for the module."""
    h = TorqueHarness(module_procs, posture=POSTURE)
    yield h
    h.close()
    assert h.proc.stop(signal.SIGINT) == 0, h.proc.output()[-2000:]
    assert "Traceback" not in h.proc.output()


def expect_torques(reply: JointState, q, qd, qdd, atol: float = 1e-9) -> None:
    assert list(reply.name) == list(JOINT_NAMES)
    np.testing.assert_allclose(reply.position, q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(reply.velocity, qd, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reply.effort, MODEL.inverse_dynamics(q, qd, qdd), rtol=0, atol=atol)


# -- torques --------------------------------------------------------------------------------
def test_config_is_latched(tn) -> None:
    got: list[String] = []
    tn.peer.node.create_subscription(String, CONFIG_TOPIC, got.append, latched_qos())
    assert tn.peer.spin_until(lambda: got, 10)
    cfg = json.loads(got[0].data)
    assert cfg["model"] == "segmented"
    assert cfg["body_size"]["label"] == "p50" and cfg["body_size"]["mass"] == 1.0
    assert cfg["placement"]["split"] == load_description().simplified.split
    assert cfg["placement"]["axis_offset_distal"] == load_description().simplified.axis_offset_distal.tolist()
    assert cfg["joint_names"] == list(JOINT_NAMES)
    assert cfg["version"] and cfg["estimator"]["settings"]["accel_cutoff_hz"] == 0.0
    assert cfg["config_id"] == 1 and cfg["applies_from_stamp_ns"] == 0  # from the start
    assert got[0] is not None and model_from_config(cfg).arm.kind == "segmented"  # strict reader


def test_static_posture_gives_gravity_torques(tn) -> None:
    msgs = [joint_state(tn.stamp(500 * MS if k == 0 else MS), POSTURE, np.zeros(20))
            for k in range(5)]
    replies = tn.exchange(msgs)
    assert [stamp_of(r) for r in replies] == [stamp_of(m) for m in msgs]
    gravity = MODEL.gravity_torques(POSTURE)
    for r in replies:
        np.testing.assert_allclose(r.effort, gravity, rtol=0, atol=1e-9)
        assert r.header.frame_id == "humerus"
    assert np.abs(gravity).max() > 0.1  # the posture is not trivially torque-free


def constant_acceleration(n: int, dt_ns, t_first: int):
    """Samples of q = q0 + v0 t + a t^2 / 2 at stamps t_first + cumulative dt (ns)."""
    q0, v0, a = POSTURE, RNG.uniform(-1, 1, 20), RNG.uniform(-20, 20, 20)
    stamps = t_first + np.concatenate([[0], np.cumsum(dt_ns)])[:n]
    t = (stamps - stamps[0]) / 1e9
    q = q0 + v0 * t[:, None] + 0.5 * a * t[:, None] ** 2
    qd = v0 + a * t[:, None]
    return stamps, q, qd, a


def test_constant_acceleration_from_velocities(tn) -> None:
    jitter = np.array([0, 150, -200, 80, 0, -120, 60, 0, 30, -90]) * 1000  # ns, irregular
    dt = MS + jitter
    # a stamp jump > max_stamp_gap first: the estimator restarts (warm-up sample)
    stamps, q, qd, a = constant_acceleration(10, dt, tn.stamp(500 * MS))
    # 1.25 s of the suite's +-20 rad/s^2 would move a joint by up to 16 rad: far outside every
    # range, refused as units (ranges.py). A twentieth of it stays an arm's motion.
    t = (stamps - stamps[0])[:, None] / 1e9
    v0, a = qd[0] / 5, a / 20
    q, qd = q[0] + v0 * t + 0.5 * a * t ** 2, v0 + a * t
    tn.t_ns = int(stamps[-1])
    replies = tn.exchange([joint_state(s, qk, qdk) for s, qk, qdk in zip(stamps, q, qd, strict=True)])
    assert len(replies) == 10
    expect_torques(replies[0], q[0], qd[0], np.zeros(20))  # warm-up: qdd = 0, documented
    for k in range(1, 10):
        expect_torques(replies[k], q[k], qd[k], a)


def test_constant_acceleration_from_positions_only(tn) -> None:
    stamps, q, qd, a = constant_acceleration(8, np.full(8, MS), tn.stamp(500 * MS))
    tn.t_ns = int(stamps[-1])
    replies = tn.exchange([joint_state(s, qk) for s, qk in zip(stamps, q, strict=True)])
    assert len(replies) == 8
    expect_torques(replies[0], q[0], np.zeros(20), np.zeros(20))  # no history yet
    for k in range(1, 8):
        v_est = (q[k] - q[k - 1]) / 1e-3  # backward difference: qd lags dt/2
        np.testing.assert_allclose(v_est, qd[k] - a * 0.5e-3, atol=1e-9)
        np.testing.assert_allclose(replies[k].velocity, v_est, atol=1e-9)
        qdd = a if k >= 2 else np.zeros(20)
        np.testing.assert_allclose(
            replies[k].effort, MODEL.inverse_dynamics(q[k], replies[k].velocity, qdd), atol=1e-6
        )


def test_shuffled_names_and_extra_joints(tn) -> None:
    order = RNG.permutation(20)
    names = [JOINT_NAMES[i] for i in order] + ["shoulder_elevation", "gripper", "thumb_tip"]
    q = np.concatenate([POSTURE[order], [np.nan, 1e308, -3.0]])  # extras are ignored
    qd = np.concatenate([np.zeros(20), [np.inf, 0.0, 1.0]])
    # first sample after a stamp jump: the estimator restarts, so qdd = 0 throughout
    msgs = [joint_state(tn.stamp(500 * MS if k == 0 else MS), q, qd, names=names) for k in range(3)]
    msgs.append(joint_state(tn.stamp(), POSTURE, np.zeros(20)))  # the plain order again
    replies = tn.exchange(msgs)
    assert len(replies) == 4
    for r in replies:
        expect_torques(r, POSTURE, np.zeros(20), np.zeros(20))


# -- rejections -----------------------------------------------------------------------------
def _drop(names, q, qd):
    return names[1:], q[1:], qd[1:]


def _dup(names, q, qd):
    return [*names, names[3]], [*q, q[3]], [*qd, qd[3]]


def _short_position(names, q, qd):
    return names, q[:-1], qd


def _bad_velocity_length(names, q, qd):
    return names, q, qd[:5]


def _nan_position(names, q, qd):
    q = list(q)
    q[2] = float("nan")
    return names, q, qd


def _inf_velocity(names, q, qd):
    qd = list(qd)
    qd[7] = float("inf")
    return names, q, qd


BAD_CONTENT = {
    "missing_joint": _drop,
    "duplicate_name": _dup,
    "length_mismatch/position": _short_position,
    "length_mismatch/velocity": _bad_velocity_length,
    "non_finite/position": _nan_position,
    "non_finite/velocity": _inf_velocity,
}
BAD_STAMP = {  # offset (ns) of the bad sample from the good one before it
    "stamp_not_increasing/equal": 0,
    "stamp_not_increasing/backwards": -300_000,
    "stamp_missing": None,
}


def _bad_sample(case: str, good_stamp: int) -> JointState:
    if case in BAD_CONTENT:
        names, q, qd = BAD_CONTENT[case](list(JOINT_NAMES), list(POSTURE), [0.0] * 20)
        return joint_state(good_stamp + MS // 2, q, qd, names=names)
    if case == "empty":
        return joint_state(good_stamp + MS // 2, names=(), frame_id="")
    offset = BAD_STAMP[case]
    return joint_state(0 if offset is None else good_stamp + offset, POSTURE, np.zeros(20))


@pytest.mark.parametrize("case", [*BAD_CONTENT, *BAD_STAMP, "empty"])
def test_bad_sample_is_dropped_counted_and_warned(tn, case: str) -> None:
    reason = case.split("/")[0]
    before = int(tn.diag.get(f"rejected.{reason}", 0))
    good1 = joint_state(tn.stamp(500 * MS), POSTURE, np.zeros(20))  # estimator restarts
    bad = _bad_sample(case, stamp_of(good1))
    good2 = joint_state(tn.stamp(), POSTURE, np.zeros(20))
    replies = tn.exchange([good1, bad, good2])
    # nothing for the bad sample, correct torques right after it
    assert [stamp_of(r) for r in replies] == [stamp_of(good1), stamp_of(good2)]
    expect_torques(replies[-1], POSTURE, np.zeros(20), np.zeros(20))
    assert tn.proc.running()
    assert tn.proc.wait_for_output(f"[{reason}]", 5), tn.proc.output()[-2000:]
    assert f"[{reason}]" in tn.proc.stderr()
    diag = tn.diag.fresh(lambda d: int(d.get(f"rejected.{reason}", 0)) >= before + 1)
    assert int(diag[f"rejected.{reason}"]) == before + 1


def test_stamp_gap_resets_the_estimator(tn) -> None:
    before = int(tn.diag.get("reset.stamp_gap", 0))
    stamps, q, qd, a = constant_acceleration(4, np.full(4, MS), tn.stamp(500 * MS))
    tn.t_ns = int(stamps[-1]) + 2000 * MS  # the 4th sample comes 2 s late
    stamps[3] = tn.t_ns
    replies = tn.exchange([joint_state(s, qk, qdk) for s, qk, qdk in zip(stamps, q, qd, strict=True)])
    assert len(replies) == 4
    expect_torques(replies[2], q[2], qd[2], a)
    expect_torques(replies[3], q[3], qd[3], np.zeros(20))  # restarted: warm-up again
    tn.diag.fresh(lambda d: int(d["reset.stamp_gap"]) >= before + 2)  # this jump and the first


def test_slow_streams_are_not_gaps(tn) -> None:
    """The adaptive max_stamp_gap (default 0): a 20 Hz then 5 Hz stream keeps its history
    (every sample after the first is a real estimate, exact for constant acceleration);
    only the 0.5 s jump to the stream's first sample resets the estimator (two samples 1 ms
    apart first: the stream's step before that jump is 1 ms, whatever the tests before sent)."""
    s1 = tn.stamp(500 * MS)
    tn.t_ns = s1 + MS
    zero = np.zeros(20)
    assert len(tn.exchange([joint_state(s1, POSTURE, zero), joint_state(s1 + MS, POSTURE, zero)])) == 2
    before = int(tn.diag.fresh(lambda d: True)["reset.stamp_gap"])
    dt = np.array([50] * 5 + [200] * 5) * MS  # 20 Hz, then 5 Hz
    stamps, q, qd, a = constant_acceleration(10, dt, tn.stamp(500 * MS))
    # 1.25 s of the suite's +-20 rad/s^2 would move a joint by up to 16 rad: far outside every
    # range, refused as units (ranges.py). A twentieth of it stays an arm's motion.
    t = (stamps - stamps[0])[:, None] / 1e9
    v0, a = qd[0] / 5, a / 20
    q, qd = q[0] + v0 * t + 0.5 * a * t ** 2, v0 + a * t
    tn.t_ns = int(stamps[-1])
    replies = tn.exchange([joint_state(s, qk, qdk) for s, qk, qdk in zip(stamps, q, qd, strict=True)])
    assert len(replies) == 10
    expect_torques(replies[0], q[0], qd[0], np.zeros(20))
    for k in range(1, 10):
        expect_torques(replies[k], q[k], qd[k], a)
    assert int(tn.diag.fresh(lambda d: True)["reset.stamp_gap"]) == before + 1


def test_parameters_are_described(tn) -> None:
    """Descriptors as `ros2 param describe` shows them: units, ranges, read-only."""
    client = tn.peer.node.create_client(DescribeParameters, "/torque_node/describe_parameters")
    assert client.wait_for_service(timeout_sec=10)
    names = ["qos_depth", "body_size", "payload_mass", "stature", "output_rate_hz",
             "estimator.accel_cutoff_hz", "max_stamp_gap"]
    future = client.call_async(DescribeParameters.Request(names=names))
    assert tn.peer.spin_until(future.done, 10)
    tn.peer.node.destroy_client(client)
    d = dict(zip(names, future.result().descriptors, strict=True))
    assert d["qos_depth"].read_only and "Read-only" in d["qos_depth"].description
    depth_range = d["qos_depth"].integer_range[0]
    assert (depth_range.from_value, depth_range.to_value) == (1, 100000)
    assert not d["body_size"].read_only and d["body_size"].dynamic_typing
    assert "[kg]" in d["payload_mass"].description and "[m]" in d["stature"].description
    assert not d["payload_mass"].read_only and d["payload_mass"].floating_point_range[0].from_value == 0.0
    assert d["output_rate_hz"].read_only and "[Hz]" in d["output_rate_hz"].description
    assert "[Hz]" in d["estimator.accel_cutoff_hz"].description
    assert not d["estimator.accel_cutoff_hz"].read_only
    assert "[s]" in d["max_stamp_gap"].description and "QOS_NOTE" not in d["qos_depth"].description


def test_diagnostics_report_the_pipeline(tn) -> None:
    """The node's own counters agree with what this test sent and got back (the timing
    figures of a period are checked on PipelineStats itself, test_diagnostics.py)."""
    before = tn.diag.fresh(lambda d: True)
    replies = tn.exchange([joint_state(tn.stamp(), POSTURE, np.zeros(20)) for _ in range(20)])
    n0 = int(before["processed_total"])
    diag = tn.diag.fresh(lambda d: int(d["processed_total"]) >= n0 + 20)
    assert len(replies) == 20
    assert int(diag["received_total"]) - int(before["received_total"]) == 20
    assert int(diag["processed_total"]) - n0 == 20
    assert diag["rejected_total"] == before["rejected_total"]
    assert int(diag["received_total"]) == int(diag["processed_total"]) + int(diag["rejected_total"])
    # the estimator states its lag at the observed period (1 ms, velocities given: dt/2)
    assert diag["estimator"] == "backward" and diag["config_id"] == "1"
    assert float(diag["estimator.lag_qdd_s"]) == pytest.approx(0.5e-3, abs=1e-9)
    assert float(diag["estimator.lag_q_s"]) == 0.0
    reasons = {k: int(v) for k, v in diag.items() if k.startswith("rejected.")}
    assert sum(reasons.values()) == int(diag["rejected_total"]) and reasons


def _set(tn, name: str, value: ParameterValue):
    client = tn.peer.node.create_client(SetParameters, "/torque_node/set_parameters")
    assert client.wait_for_service(timeout_sec=10)
    future = client.call_async(SetParameters.Request(parameters=[Parameter(name=name, value=value)]))
    assert tn.peer.spin_until(future.done, 10)
    tn.peer.node.destroy_client(client)
    return future.result().results[0]


def test_read_only_and_invalid_live_changes_are_refused(tn) -> None:
    """Transport parameters are read-only; a model parameter with an invalid value is
    refused with the reason (valid live changes: test_torque_node_live.py)."""
    r = _set(tn, "qos_depth", ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=10))
    assert not r.successful and "read-only" in r.reason and "qos_depth" in r.reason
    r = _set(tn, "model", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="wooden"))
    assert not r.successful and r.reason.startswith("invalid parameter 'model'"), r.reason
    r = _set(tn, "body_size", ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=51))
    assert not r.successful and "invalid parameter 'body_size'" in r.reason and "dict" not in r.reason
    # the node runs on with the same model
    msgs = [joint_state(tn.stamp(), POSTURE, np.zeros(20)) for _ in range(3)]
    for reply in tn.exchange(msgs):
        np.testing.assert_allclose(reply.effort, MODEL.gravity_torques(POSTURE), rtol=0, atol=1e-9)


# -- null_echo_node -------------------------------------------------------------------------
def test_null_echo_node_shares_the_pipeline(tn) -> None:
    echo = rosproc.start("null_echo_node", "-r", "joint_torques:=null_torques")
    got: list[JointState] = []
    tn.peer.node.create_subscription(JointState, "null_torques", got.append, stream_qos(100))
    try:
        order = RNG.permutation(20)
        names = [JOINT_NAMES[i] for i in order] + ["extra"]
        deadline = time.monotonic() + 20
        while not got:
            assert time.monotonic() < deadline and echo.running(), echo.output()
            q = np.append(POSTURE[order], 0.0)
            tn.pub.publish(joint_state(tn.stamp(), q, np.arange(21.0), names=names))
            tn.peer.spin_for(0.1)
        r = got[-1]
        assert list(r.name) == list(JOINT_NAMES)
        np.testing.assert_array_equal(r.position, POSTURE)
        np.testing.assert_array_equal(r.velocity, np.argsort(order).astype(float))
        np.testing.assert_array_equal(r.effort, np.zeros(20))
        assert stamp_of(r) <= tn.t_ns
    finally:
        assert echo.stop(signal.SIGTERM) == 0, echo.output()
    assert "Traceback" not in echo.output()


# -- start-up refusals ----------------------------------------------------------------------
BAD_PARAMS = {
    "model": ["-p", "model:=banana"],
    "body_size": ["-p", "body_size:=42"],
    "qos_depth": ["-p", "qos_depth:=0"],
    "executor": ["-p", "executor:=turbo"],
    "estimator.accel_cutoff_hz": ["-p", "estimator.accel_cutoff_hz:=-5.0"],
    "stature": ["-p", "stature:=3.5", "-p", "body_mass:=80.0"],
    "input_topic": ["-p", "input_topic:=no spaces allowed"],
}


def test_invalid_parameters_exit_2_with_one_line() -> None:
    procs = {name: rosproc.start("torque_node", *args) for name, args in BAD_PARAMS.items()}
    for name, p in procs.items():
        try:
            # a hang guard, not a speed check: 7 nodes start at once (19 s seen at load 27)
            assert p.wait(timeout=180) == 2, p.output()
        finally:
            p.stop(signal.SIGKILL)
        lines = [line for line in p.output().splitlines() if line.strip()]
        assert len(lines) == 1, lines
        assert f"invalid parameter '{name}'" in lines[0]


# -- the estimator on its own (no ROS) -----------------------------------------------------
def test_estimator_lowpass_is_exact_for_constant_acceleration_and_lags_by_tau() -> None:
    from forearm_dynamics.estimation import make_estimator

    tau = 1.0 / (2.0 * np.pi * 20.0)
    est = make_estimator("backward", 20, {"accel_cutoff_hz": 20.0})
    a = RNG.uniform(-5, 5, 20)
    warm = [est.update(k * MS, POSTURE, np.array(a * k * 1e-3)) for k in range(50)]
    assert warm[0] is False and all(warm[1:])
    np.testing.assert_allclose(est.qdd, a, rtol=1e-9)  # filter starts at the first estimate
    # the acceleration steps to 0: the filtered estimate decays with time constant tau
    v_end = a * 49e-3
    n = round(tau / 1e-3)
    for k in range(50, 50 + n):
        est.update(k * MS, POSTURE, v_end.copy())
    alpha = 1e-3 / (tau + 1e-3)
    np.testing.assert_allclose(est.qdd, a * (1 - alpha) ** n, rtol=1e-9)
    assert 0.3 < (1 - alpha) ** n < 0.4  # ~ e^-1 after one time constant
    assert est.lag(1e-3, velocity_given=True)["qdd"] == pytest.approx(0.5e-3 + tau)
    est.reset()
    assert est.update(10**12, POSTURE, None) is False and not est.qdd.any()
