"""bag_torques against inverse_dynamics: the output bag (read with rosbags) holds every input
message plus joint_torques equal to the model's inverse dynamics of the estimated state."""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest
from bagkit import MS, T0, smooth_motion, write_stream_bag
from rosbags.highlevel import AnyReader
from rosproc import BIN, ros_env

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.bag import BagWriter
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.offline import backward_batch

pytestmark = pytest.mark.cli

N = 3000


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "bag_torques"), *map(str, args)], env=ros_env(), capture_output=True,
                          text=True, timeout=120, check=False)


def read(path) -> dict:
    out = {"topics": {}, "torques": [], "config": None}
    with AnyReader([path]) as r:
        for c, _t, raw in r.messages():
            out["topics"][c.topic] = out["topics"].get(c.topic, 0) + 1
            if c.topic == "/joint_torques":
                m = r.deserialize(raw, c.msgtype)
                out["torques"].append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                       list(m.name), m.position, m.velocity, m.effort))
            elif c.topic == "/torque_node/config":
                out["config"] = json.loads(r.deserialize(raw, c.msgtype).data)
    return out


@pytest.fixture(scope="module")
def src(tmp_path_factory):
    path = tmp_path_factory.mktemp("torques") / "in.mcap"
    return path, write_stream_bag(path, N, extra_topic=True)


def test_backward_equals_inverse_dynamics_of_the_node_estimate(src, tmp_path):
    path, written = src
    out = tmp_path / "out.mcap"
    r = run(path, out, "--body-size", "95", "--estimator", "backward")
    assert r.returncode == 0, r.stderr
    got = read(out)
    assert got["topics"]["/joint_states"] == N and got["topics"]["/status"] == N // 10
    assert got["topics"]["/joint_torques"] == N
    assert got["config"]["model"] == "segmented" and got["config"]["body_size"]["label"] == "p95"
    assert got["config"]["estimator"]["method"] == "backward"
    stamps = np.array([t[0] for t in got["torques"]])
    np.testing.assert_array_equal(stamps, written["stamps"])
    assert all(t[1] == list(JOINT_NAMES) for t in got["torques"])
    eff = np.array([t[4] for t in got["torques"]])
    # independent: qdd = backward difference of the given velocities, first sample 0
    q, qd = written["q"], written["qd"]
    dt = np.diff(written["stamps"]) * 1e-9
    qdd = np.vstack([np.zeros(20), (qd[1:] - qd[:-1]) / dt[:, None]])
    arm = build_model("segmented", 95)
    np.testing.assert_allclose(eff, arm.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.array([t[2] for t in got["torques"]]), q)


def test_zero_phase_close_to_exact_dynamics(src, tmp_path):
    path, written = src
    out = tmp_path / "zp.mcap"
    r = run(path, out, "--estimator", "zero_phase", "--cutoff", "20")
    assert r.returncode == 0, r.stderr
    got = read(out)
    eff = np.array([t[4] for t in got["torques"]])
    # the analytic state of the synthetic motion (sines of 0.3..1.25 Hz, far below 20 Hz)
    t = (written["stamps"] - T0) / 1e9
    q, qd = smooth_motion(t)
    h = 1e-6
    qdd = (smooth_motion(t + h)[1] - smooth_motion(t - h)[1]) / (2 * h)
    exact = build_model("segmented", 50).inverse_dynamics(q, qd, qdd)
    inner = slice(300, N - 300)  # edges: the filter's padding
    err = np.abs(eff[inner] - exact[inner]).max(axis=0)
    ptp = np.ptp(exact, axis=0)
    assert (err <= 0.01 * ptp + 1e-6).all(), err / ptp
    assert got["config"]["estimator"]["method"] == "zero_phase"


def test_batch_estimator_is_the_node_estimator_bit_for_bit():
    """backward_batch == BackwardDifference sample by sample (positions only, with a gap)."""
    rng = np.random.default_rng(5)
    stamps = T0 + np.cumsum(rng.integers(900_000, 1_100_000, 500)).astype(np.int64)
    stamps[250:] += 300 * MS  # a gap beyond max_stamp_gap: the estimator restarts
    q = rng.normal(size=(500, 20))
    qd_b, qdd_b, warm_b = backward_batch(stamps, q, None)
    est = make_estimator("backward", 20)
    for k in range(500):
        if k == 250:
            est.reset()
        warm = est.update(int(stamps[k]), q[k], None)
        assert np.array_equal(est.qd, qd_b[k]) and np.array_equal(est.qdd, qdd_b[k]), k
        assert warm == warm_b[k]


@pytest.mark.parametrize("case", ["missing", "not_mcap", "no_topic", "exists", "bad_size", "garbage",
                                  "truncated_to_header"])
def test_bad_input_one_line_exit_2(src, tmp_path, case):
    path, _ = src
    out = tmp_path / "o.mcap"
    args = [path, out]
    if case == "missing":
        args = [tmp_path / "nope.mcap", out]
    elif case == "not_mcap":
        bad = tmp_path / "bad.mcap"
        bad.write_text("not a bag")
        args = [bad, out]
    elif case == "no_topic":
        args = [path, out, "--input-topic", "nothing_here"]
    elif case == "exists":
        out.write_text("keep me")
    elif case == "bad_size":
        args = [path, out, "--body-size", "42"]
    elif case == "garbage":  # a JointState channel whose payloads are noise
        bad = tmp_path / "noise.mcap"
        with BagWriter(bad) as w:
            ch = w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
            for k in range(20):
                w.write(ch, os.urandom(200), T0 + k)
        args = [bad, out]
    elif case == "truncated_to_header":
        bad = tmp_path / "cut.mcap"
        bad.write_bytes(path.read_bytes()[:40])
        args = [bad, out]
    r = run(*args)
    assert r.returncode == 2, r.stdout + r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    if case == "exists":
        assert out.read_text() == "keep me"
    elif case != "missing":
        assert not out.exists()


def test_every_node_estimator_sample_by_sample(src, tmp_path):
    """--estimator kalman: its update() sample by sample, q and qd as it estimates them (what
    the node computes with), with a setting passed through --setting."""
    path, written = src
    out = tmp_path / "kalman.mcap"
    r = run(path, out, "--estimator", "kalman", "--setting", "kalman_jerk_psd=1000")
    assert r.returncode == 0, r.stderr
    got = read(out)
    assert got["config"]["estimator"]["method"] == "kalman"
    assert got["config"]["estimator"]["settings"]["kalman_jerk_psd"] == 1000.0
    est = make_estimator("kalman", 20, {"kalman_jerk_psd": 1000.0})
    q, qd, qdd, _ = est.run(written["stamps"], written["q"], written["qd"])
    eff = np.array([t[4] for t in got["torques"]])
    np.testing.assert_allclose(eff, build_model("segmented", 50).inverse_dynamics(q, qd, qdd),
                               rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.array([t[2] for t in got["torques"]]), q)
    # and it is not the backward estimator's
    assert np.abs(eff - build_model("segmented", 50).inverse_dynamics(
        written["q"], written["qd"], np.zeros_like(qd))).max() > 1e-6


def test_bad_estimator_settings_are_one_line(src, tmp_path):
    path, _ = src
    for args, word in ((["--setting", "kalman_jerk_psd"], "NAME=VALUE"),
                       (["--setting", "no_such=1"], "no_such"),
                       (["--estimator", "zero_phase", "--setting", "kalman_jerk_psd=1"], "zero_phase"),
                       (["--estimator", "kalman", "--accel-cutoff", "5"], "backward")):
        r = run(path, tmp_path / "x.mcap", *args)
        assert r.returncode == 2 and word in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
