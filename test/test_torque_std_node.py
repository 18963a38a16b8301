"""joint_torques_std through the real torque_node (a process, loopback DDS): one σ message per
torque message with the same header and names, the σ the offline API computes for the same
samples, and a 95 % band that covers the error against the noiseless truth on a simulated
noisy stream (100 Hz, 0.5 deg) — a bound the model's uncalibrated σ (no lag part, the
practice filter off: the model's own q̈ and its noise covariance alone) misses on its error.
"""

from __future__ import annotations

import json
import math
import signal
import time

import numpy as np
import pytest
import rosproc
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from support.jointstate import publish_positions

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.movements import movement_library
from forearm_dynamics.nodes.common import latched_qos, stream_qos
from forearm_dynamics.uncertainty import inverse_dynamics_with_std

pytestmark = pytest.mark.ros

RATE = 100.0
NOISE = math.radians(0.5)
MOVEMENTS = (3, 20, 37, 54)
LEAD = 50  # samples of held start posture before each movement
#: the band must cover 90-98.5 % of the samples (pooled over joints): the calibrated σ
#: covers ~95 % (benchmarks/uncertainty.py), the noise covariance alone ~85 %
COVERAGE = (0.90, 0.985)


def stream(t0_ns: int):
    """(stamps ns, noisy positions, true q, qd, qdd): the movements back to back, each after
    a held lead, at 100 Hz, seeded noise."""
    rng = np.random.default_rng(19)
    lib = movement_library()
    parts = []
    for i in MOVEMENTS:
        mv = lib[i]
        t = np.concatenate([np.arange(-LEAD, 0) / RATE, mv.sample_times(RATE)])
        parts.append(mv.evaluate(t))
    q, qd, qdd = (np.concatenate([p[k] for p in parts]) for k in range(3))
    stamps = t0_ns + np.arange(len(q), dtype=np.int64) * round(1e9 / RATE)
    return stamps, q + rng.normal(0.0, NOISE, q.shape), q, qd, qdd


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class Run:
    def __init__(self, *args: str, domain: int | None = None):
        self.proc = rosproc.start("torque_node", "-p", "diagnostics_period:=0.0", "-p", "publish_std:=true",
                                  *args, domain=domain)
        self.peer = rosproc.Peer("std_test", domain=domain)
        node = self.peer.node
        self.pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        self.torques: dict[int, JointState] = {}
        self.stds: dict[int, JointState] = {}
        self.config: list[dict] = []
        node.create_subscription(JointState, "joint_torques",
                                 lambda m: self.torques.setdefault(stamp_of(m), m), stream_qos(1000))
        node.create_subscription(JointState, "joint_torques_std",
                                 lambda m: self.stds.setdefault(stamp_of(m), m), stream_qos(1000))
        node.create_subscription(String, "/torque_node/config",
                                 lambda m: self.config.append(json.loads(m.data)), latched_qos())
        ok = self.peer.spin_until(lambda: self.pub.get_subscription_count() > 0 and self.config,
                                  rosproc.STARTUP_S)
        assert ok, self.proc.output()

    def send(self, stamps, q) -> None:
        publish_positions(self.pub, self.peer, stamps, q)

    def close(self) -> None:
        self.peer.close()
        assert self.proc.stop(signal.SIGINT) == 0, self.proc.output()[-2000:]
        assert "Traceback" not in self.proc.output()


@pytest.fixture(scope="module")
def run():
    r = Run()
    t0 = (time.time_ns() // 1_000_000) * 1_000_000
    stamps, z, q, qd, qdd = stream(t0)
    r.send(stamps, z)
    last = int(stamps[-1])
    ok = r.peer.spin_until(lambda: last in r.torques and last in r.stds, 30)
    assert ok, r.proc.output()[-2000:]
    r.peer.spin_for(0.2)
    yield r, (stamps, z, q, qd, qdd)
    r.close()


def test_one_std_message_per_torque_message_same_header_and_names(run) -> None:
    r, (stamps, *_rest) = run
    assert len(r.torques) == len(stamps) == len(r.stds)  # nothing lost, nothing extra
    for s in stamps[::37]:
        tq, sd = r.torques[int(s)], r.stds[int(s)]
        assert sd.header == tq.header and sd.header.frame_id == "humerus"
        assert list(sd.name) == list(tq.name) == list(JOINT_NAMES)
        assert len(sd.position) == 0 and len(sd.velocity) == 0 and len(sd.effort) == 20
    cfg = r.config[-1]["std"]
    assert cfg["published"] is True and cfg["topic"] == "/joint_torques_std"
    for part in ("estimation", "lag", "model", "subject_parameters"):
        assert cfg[part], part
    assert "results/paper/results.json" in cfg["model"]


def test_node_sigma_is_the_offline_apis(run) -> None:
    """Same samples -> the same τ and σ as inverse_dynamics_with_std (the node's values
    travel as float64: equal to rounding); inf exactly where the σ is not known yet (the
    estimate warming up, the noise not measured yet: the API's `known`)."""
    r, (stamps, z, *_rest) = run
    off = inverse_dynamics_with_std(build_model(), stamps, z, t_in_ns=True)
    tau = np.array([r.torques[int(s)].effort for s in stamps])
    std = np.array([r.stds[int(s)].effort for s in stamps])
    np.testing.assert_allclose(tau, off.tau, rtol=1e-12, atol=1e-12)
    unknown = ~np.isfinite(std)
    assert np.array_equal(unknown.any(axis=1), ~off.known), "inf σ exactly where it is not known"
    assert unknown[~off.known].all() and not (off.known & ~off.warm).any()
    np.testing.assert_allclose(std[off.known], off.std[off.known], rtol=1e-12, atol=1e-15)


def test_band_covers_the_error_and_the_uncalibrated_one_would_not(run) -> None:
    r, (stamps, z, q, qd, qdd) = run
    arm = build_model()
    truth = arm.inverse_dynamics_batch(q, qd, qdd)
    tau = np.array([r.torques[int(s)].effort for s in stamps])
    std = np.array([r.stds[int(s)].effort for s in stamps])
    known = np.isfinite(std).all(axis=1)
    err = (tau - truth)[known]
    model_sd = np.sqrt(arm_model_var(r))  # truth is the same model: its part is left out
    sd = np.sqrt(np.maximum(std[known] ** 2 - model_sd**2, 0.0))
    cover = float(np.mean(np.abs(err) <= 1.96 * sd))
    ratio = float(np.sqrt(np.mean(sd**2) / np.mean(err**2)))
    # the counterfactual on the model's own q̈ (issue 29's practice filter off: on its joints
    # the σ's q̈ part is the blend's measured error, which holds the lag already)
    model_only = {"practice_filter": 0.0}
    off = inverse_dynamics_with_std(arm, stamps, z, t_in_ns=True, lag=False, model=False,
                                    settings=model_only)
    err_model = (off.tau - truth)[known]
    cover_raw = float(np.mean(np.abs(err_model) <= 1.96 * off.std[known]))
    print(f"coverage {cover:.3f} (no lag part: {cover_raw:.3f}), RMS(σ)/RMSE {ratio:.2f}, "
          f"{int(known.sum())} samples x 20")
    assert COVERAGE[0] <= cover <= COVERAGE[1], cover
    assert not COVERAGE[0] <= cover_raw <= COVERAGE[1], cover_raw
    assert 0.8 <= ratio <= 1.5, ratio


def arm_model_var(r) -> np.ndarray:
    """The model part the node states in ~/config (σ per DOF, N·m), squared."""
    sd = r.config[-1]["std"]["model_std_nm"]
    return np.array([sd[n] for n in JOINT_NAMES]) ** 2


def test_no_std_for_an_estimator_without_covariance() -> None:
    r = Run("-p", "estimator:=backward", domain=rosproc.test_domain(150, 200))  # not the fixture's
    try:
        t0 = (time.time_ns() // 1_000_000) * 1_000_000
        stamps, z, *_ = stream(t0)
        r.send(stamps[:40], z[:40])
        last = int(stamps[39])
        assert r.peer.spin_until(lambda: last in r.torques, 20), r.proc.output()[-2000:]
        r.peer.spin_for(0.2)
        assert not r.stds
        cfg = r.config[-1]["std"]
        assert cfg["published"] is False and "backward" in cfg["why"]
    finally:
        r.close()
