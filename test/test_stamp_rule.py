"""The jump rule (estimation/stamps.py) that torque_node, bag_torques and the Python API
share: a steady slow stream is not a gap at every sample, a fast stream's pause is; and
a 10 Hz stream through the estimator gives real estimates, not static torques (issue 30).
Also the offline delay alignment (issue 29): each delayed estimate in the row of the
sample it estimates, no made-up row."""

from __future__ import annotations

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.codec.jointstate import JointSeries
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.stamps import (
    CONTINUE,
    GAP,
    JUMP_BACK,
    NOT_INCREASING,
    StampRule,
    rate_note,
    resets,
)
from forearm_dynamics.offline.torques import compute
from forearm_dynamics.uncertainty import inverse_dynamics_with_std

pytestmark = pytest.mark.unit

MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000
ARM = build_model("segmented", 50)


def test_a_steady_10hz_stream_restarts_only_at_its_first_sample() -> None:
    """100.5 ms steps: the first version reset at 79 of 80 samples."""
    stamps = T0 + np.arange(80) * 100_500_000
    keep, reset = resets(stamps)
    assert all(keep) and reset == [True] + [False] * 79
    steps = np.random.default_rng(3).uniform(75, 125, 80)  # 10 Hz +- 25 %
    keep, reset = resets(T0 + np.cumsum(steps * MS).astype(np.int64))
    assert sum(reset) == 1


@pytest.mark.parametrize("step_ms", [1000.0, 400.0, 200.0, 33.3, 1.0])
def test_every_rate_from_1hz_keeps_its_history(step_ms: float) -> None:
    stamps = T0 + np.round(np.arange(50) * step_ms * MS).astype(np.int64)
    _, reset = resets(stamps)
    # a stream's first step is judged against 0.5 s (nothing before it): a 1 Hz stream
    # restarts once more there, then never
    assert sum(reset) == (2 if step_ms > 500 else 1), step_ms


def test_a_fast_streams_pause_is_a_gap_and_a_rate_change_restarts_once() -> None:
    steps = [MS] * 100 + [150 * MS] + [MS] * 100  # 1 kHz, a 150 ms pause, 1 kHz
    _, reset = resets(T0 + np.cumsum(steps))
    assert np.flatnonzero(reset).tolist() == [0, 100]
    steps = [MS] * 100 + [200 * MS] * 50  # 1 kHz, then 5 Hz: one restart, not 50
    _, reset = resets(T0 + np.cumsum(steps))
    assert np.flatnonzero(reset).tolist() == [0, 100]


def test_jumps_back_and_repeats() -> None:
    rule = StampRule()
    rule.step(MS)
    assert rule.judge(-2 * MS) == NOT_INCREASING and rule.judge(0) == NOT_INCREASING
    assert rule.judge(-200 * MS) == JUMP_BACK and rule.judge(200 * MS) == GAP
    assert rule.judge(50 * MS) == CONTINUE
    stamps = T0 + np.array([0, 1, 2, 2, 1, 3, -5000, -4999], np.int64) * MS  # a repeat, a reorder, a loop
    keep, reset = resets(stamps)
    assert keep == [True, True, True, False, False, True, True, True]
    assert reset == [True, False, False, False, False, False, True, False]
    fixed = StampRule(0.1)  # max_stamp_gap > 0: that G whatever the stream
    fixed.step(100 * MS)
    assert fixed.judge(101 * MS) == GAP
    with pytest.raises(ValueError, match="max_stamp_gap"):
        StampRule(-1.0)


def test_rate_note_below_the_supported_rates_only() -> None:
    note = rate_note(0.1005)
    assert note is not None and "9.95 Hz" in note and "30 Hz" in note and "\n" not in note
    assert rate_note(1 / 30) is None and rate_note(1e-3) is None and rate_note(0.0) is None


def _motion(stamps: np.ndarray, seed: int = 1):
    rng = np.random.default_rng(seed)
    n = ARM.nv
    ts = (stamps - stamps[0]) * 1e-9
    amp, ph, off = rng.uniform(0.2, 0.6, n), rng.uniform(0, 6, n), rng.uniform(-0.2, 0.5, n)
    w = 2 * np.pi * 0.4
    q = off + amp * np.sin(w * ts[:, None] + ph)
    qd = amp * w * np.cos(w * ts[:, None] + ph)
    qdd = -amp * w * w * np.sin(w * ts[:, None] + ph)
    return q, qd, qdd


def _series(stamps: np.ndarray, q: np.ndarray) -> JointSeries:
    n = len(stamps)
    return JointSeries("/joint_states", ARM.joint_names, stamps, stamps + 3 * MS, ["humerus"] * n,
                       q, np.full_like(q, np.nan))


def test_a_10hz_stream_through_the_default_estimator_gives_real_estimates() -> None:
    """80 samples at 10 Hz (100.5 ms) of a 0.4 Hz movement, positions only, through
    bag_torques' sample-by-sample path (the node's calls): one segment, warm from the third
    sample, and torques far closer to the true ones than static torques (zero velocity and
    acceleration: what a restart at every sample gave) on every moving DOF."""
    stamps = T0 + np.arange(80) * 100_500_000
    q, qd, qdd = _motion(stamps)
    res = compute(_series(stamps, q), ARM, "kalman", std=False)
    assert res.segments == 1 and len(res.stamps_ns) == 80
    assert np.array_equal(res.stamps_ns, stamps)
    truth = ARM.inverse_dynamics_batch(q, qd, qdd)
    static = ARM.inverse_dynamics_batch(q, 0 * qd, 0 * qdd)
    after = slice(10, None)  # after the first second

    def rmse(x):
        return np.sqrt(((x - truth)[after] ** 2).mean(axis=0))

    moving = rmse(static) > 1e-3  # N·m: DOFs whose velocity and acceleration matter
    assert moving.sum() >= 4
    ratio = rmse(res.tau)[moving] / rmse(static)[moving]
    assert (ratio < 0.5).all(), dict(zip(np.array(ARM.joint_names)[moving], ratio.round(3), strict=True))
    assert (np.abs(res.qdd[3:]).max(axis=1) > 0).all()  # every output after warm-up: a real q̈


def _by_hand(stamps, q, settings):
    """The estimator's update() calls, each output kept under the stamp it states."""
    est = make_estimator("kalman", ARM.nv, settings)
    got = {}
    for k, t in enumerate(stamps.tolist()):
        est.update(t, q[k], None)
        if est.stamp_ns is not None:
            got[est.stamp_ns] = (est.q.copy(), est.qd.copy(), est.qdd.copy())
    for t, x in est.drain():
        got[t] = tuple(x)
    return got


@pytest.mark.parametrize("delay_s", [0.0, 0.05, 0.2])
def test_offline_paths_stamp_a_delayed_estimate_with_its_own_sample(delay_s: float) -> None:
    """bag_torques' compute and the API put each estimate in the row of the sample it
    estimates (est.stamp_ns), every sample once, none at a posture no sample had."""
    stamps = T0 + np.arange(300) * 10 * MS  # 100 Hz, 3 s
    q, _qd, _qdd = _motion(stamps, seed=5)
    q = q + np.random.default_rng(9).normal(0, np.radians(0.5), q.shape)
    settings = {"delay_s": delay_s}
    want = _by_hand(stamps, q, settings)
    assert sorted(want) == stamps.tolist()
    res = compute(_series(stamps, q), ARM, "kalman", settings, std=True)
    assert np.array_equal(res.stamps_ns, stamps)  # one row per sample, in stamp order
    for k in (0, 1, 2, 3, 4, 5, 150, 299):
        t = int(stamps[k])
        np.testing.assert_array_equal(res.q[k], want[t][0])
        np.testing.assert_array_equal(res.qdd[k], want[t][2])
    # no row at the zero posture: every row's q within a few degrees of its own sample
    assert np.abs(res.q - q).max() < np.radians(5)
    # a delayed estimate is released by a later input: its log time is that input's
    lag = round(delay_s / 0.01)
    assert np.array_equal(res.log_ns[: 300 - lag], stamps[lag:] + 3 * MS)
    api = inverse_dynamics_with_std(ARM, stamps, q, settings=settings, t_in_ns=True)
    np.testing.assert_allclose(api.tau, res.tau, rtol=0, atol=1e-9)
    known = np.isfinite(res.std).all(axis=1)
    np.testing.assert_allclose(api.std[api.known], res.std[known], rtol=1e-12)
