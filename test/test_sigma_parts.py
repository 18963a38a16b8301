"""The σ parts added when the lag term was re-calibrated on the per-joint estimator (issue 19).

Each is checked against an independent computation or a counterfactual: each joint's own lag
(against the filter's own lag algebra at that joint's noise), no σ before the noise is
measured, the jerk read's noise margin (the filter run on pure noise and on a constant jerk),
Σ re-derived from the settled gain after a regroup (against the value the same noise gives
once settled), and no noise part on exact input.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from forearm_dynamics.dynamics import build_model
from forearm_dynamics.estimation import ca_model, make_estimator
from forearm_dynamics.movements import movement_library
from forearm_dynamics.uncertainty import inverse_dynamics_with_std, lag, torque_std
from forearm_dynamics.uncertainty.state_source import (
    lag_per_jerk,
    lags_per_jerk,
    noise_covariance,
    state_source,
    unit_noise_covariances,
)
from forearm_dynamics.uncertainty.torque_std import TorqueStd

pytestmark = pytest.mark.unit

RATE = 100.0


@pytest.fixture(scope="module")
def arm():
    return build_model()


def still(levels_deg, seconds, rng, rate=RATE):
    """Stamps (ns) and a still posture seen through white noise of the given std per joint."""
    n = int(seconds * rate)
    t = 1_000_000_000 + np.round(np.arange(n) / rate * 1e9).astype(np.int64)
    return t, 0.3 + rng.normal(0.0, 1.0, (n, len(levels_deg))) * np.radians(levels_deg)


def run(est, src, t, z, qd=None):
    for k in range(len(t)):
        est.update(int(t[k]), z[k], None if qd is None else qd[k])
        src.refresh(t[k] * 1e-9, qd is not None)


def test_each_joint_lags_by_its_own_noise_groups_gain():
    """Joint 0 at 0.1 deg, joint 1 at 1 deg (as mocap IK's elbow beside its pro/sup): each
    joint's q̈ lag over the noisiest group's is the lag of a filter run at that joint's own
    noise (KalmanCA.lag, fixed noise), not 1 for both. The model's own q̈ (practice filter
    off: on the joints it serves, the q̈ part is the blend's measured error, next test)."""
    rng = np.random.default_rng(1)
    t, z = still([0.1, 1.0], 6.0, rng)
    est = make_estimator("kalman", 2, {"practice_filter": 0.0})
    src = state_source(est)
    run(est, src, t, z)
    groups = est.noise_groups()
    assert len(groups) == 2
    ref = max(groups, key=lambda g: g.r)
    lags = {}
    for g in groups:
        fixed = make_estimator("kalman", 1, {"kalman_noise_deg": math.degrees(g.r)})
        for k in range(400):  # settle its gain at the same period
            fixed.update(int(t[k]), z[k, :1], None)
        lags[int(g.idx[0])] = fixed.lag(1 / RATE, False)["qdd"]
    ratio = np.array([lags[0], lags[1]]) / lags[int(ref.idx[0])]
    np.testing.assert_allclose(src.lag_scale2, ratio**2, rtol=1e-3)
    assert src.lag_scale2[1] == pytest.approx(1.0) and src.lag_scale2[0] < 0.5


def test_no_sigma_until_the_noise_is_measured(arm):
    """Until the filter runs with a measured noise (its default belief is 0.5 deg, no
    measurement), σ is not known (NaN offline, inf from the node); with the noise fixed by
    the user it is known as soon as the state is warm."""
    rng = np.random.default_rng(2)
    t, z = still([3.0] * arm.nv, 1.5, rng)
    out = inverse_dynamics_with_std(arm, t, z, t_in_ns=True)
    est = make_estimator("kalman", arm.nv, None)
    first = None
    for k in range(len(t)):
        est.update(int(t[k]), z[k], None)
        if first is None and est.noise_known(False):
            first = k
    assert first is not None and first > 10  # later than the state's own warm-up (3 samples)
    assert not out.known[:first].any() and np.isnan(out.std[:first]).all()
    assert out.known[first:].all() and np.isfinite(out.std[first:]).all()
    fixed = inverse_dynamics_with_std(arm, t, z, t_in_ns=True, settings={"kalman_noise_deg": 3.0})
    assert np.array_equal(fixed.known, fixed.warm) and fixed.known[3:].all()


def _jerk_read(jerk, margin, monkeypatch, noise_deg=0.5, seconds=12.0, settings=None):
    """RMS of the jerk the tracker reads on one joint: a constant jerk through 0.5 deg noise,
    the model's q̈ (practice filter off: on its joints the measured error replaces the lag
    part, test_the_practice_filters_joints_take_...)."""
    monkeypatch.setattr(lag, "NOISE_MARGIN", margin)
    rng = np.random.default_rng(3)
    t, z = still([noise_deg], seconds, rng)
    s = (t - t[0]) * 1e-9
    z = z + jerk * s[:, None] ** 3 / 6
    est = make_estimator("kalman", 1, {"practice_filter": 0.0, **(settings or {})})
    src = state_source(est)
    tracker = lag.JerkTracker(1)
    ms = []
    for k in range(len(t)):
        est.update(int(t[k]), z[k], None)
        src.refresh(t[k] * 1e-9, False)
        m = tracker.update(int(t[k]), est.qdd, src.baseline, src.delta_noise_var, src.lag_scale2)
        if s[k] > 3.0:
            ms.append(m[0])
    return math.sqrt(np.mean(ms))


def test_the_noise_margin_reads_less_noise_as_jerk_and_keeps_a_real_one(monkeypatch):
    """On pure noise (no movement) the jerk read is the noise's fluctuation: the margin of
    one nv at least halves it (the χ²₁ excess over 2 nv is half of that over nv; measured
    106 -> 49 rad/s³ at 100 Hz, 0.5 deg). A real jerk loses one nv (here ~200 rad/s³ in
    quadrature): 1000 rad/s³ is read within 10 %, 300 (a fast movement's) above 60 %."""
    fake0 = _jerk_read(0.0, 0.0, monkeypatch)
    fake1 = _jerk_read(0.0, 1.0, monkeypatch)
    assert fake1 < 0.5 * fake0, (fake0, fake1)
    assert _jerk_read(1000.0, 1.0, monkeypatch) == pytest.approx(1000.0, rel=0.1)
    assert _jerk_read(300.0, 1.0, monkeypatch) > 0.6 * 300


def test_the_practice_filters_joints_take_the_blends_measured_error_as_their_qdd_variance():
    """The same two joints with the practice filter (the default): the 0.1 deg joint (the
    model wider than 6 Hz there) gets the blend's q̈; its q̈ variance is the blend's error
    variance (practice_blend.error_variance), its q̈ covariances with q, q̇ are gone, its lag
    part stays (state_source._practice_filter: against the truth a fast movement has what the
    practice removes); the 1 deg joint (the model narrower, white noise) keeps the model's,
    equal to the filter-off source's."""
    rng = np.random.default_rng(1)
    t, z = still([0.1, 1.0], 6.0, rng)
    est = make_estimator("kalman", 2, None)
    off = make_estimator("kalman", 2, {"practice_filter": 0.0})
    src, src_off = state_source(est), state_source(off)
    run(est, src, t, z)
    run(off, src_off, t, z)
    src._t = src_off._t = -math.inf  # derive again now (refresh: every 0.25 s of stream time)
    src.refresh(t[-1] * 1e-9, False)
    src_off.refresh(t[-1] * 1e-9, False)
    assert est.practice_filter_weight().tolist() == [1.0, 0.0]
    cov, cov_off = np.asarray(src.cov()), np.asarray(src_off.cov())
    var = est.practice_filter_variance()
    assert cov[0, 5] == pytest.approx(var[0], rel=1e-12) and var[0] > 0.0
    assert cov[0, 2] == 0.0 and cov[0, 4] == 0.0
    np.testing.assert_array_equal(cov[0, [0, 1, 3]], cov_off[0, [0, 1, 3]])
    np.testing.assert_array_equal(cov[1], cov_off[1])
    np.testing.assert_array_equal(src.lag_scale2, src_off.lag_scale2)


@pytest.mark.parametrize("rate, after_s", [(RATE, 0.2), (1000.0, 0.12)])
def test_the_noise_part_follows_the_settled_gain_after_a_regroup(rate, after_s):
    """The noise steps 0.3 -> 1.2 deg: the filter regroups (a few times, as its estimate
    climbs) and each new group's gain settles over some samples. `after_s` after each regroup
    (inside the 0.25 s refresh period) the gain the σ's parts were derived from (seen in its
    lag vector, a function of the gain alone) is the converged gain at that group's noise
    (ca_model.steady_state, an independent Riccati solve); the first step's gain, held for
    0.25 s, made the q̈-change noise variance up to 4000x off (a 1 kHz encoder's joint). At
    1 kHz the settling re-derivations run every 4 ms, not every sample (state_source)."""
    rng = np.random.default_rng(4)
    t, z = still([0.3], 8.0, rng, rate)
    step = int(4.0 * rate)
    z[step:] = 0.3 + (z[step:] - 0.3) * 4.0
    est = make_estimator("kalman", 1, None)
    src = state_source(est)
    last, version, checked = None, est.groups_version, 0
    for k in range(len(t)):
        est.update(int(t[k]), z[k], None)
        src.refresh(t[k] * 1e-9, False)
        if est.groups_version != version:
            version, last = est.groups_version, k
        if last is not None and k == last + round(after_s * rate) and k > step:
            (g,) = est.noise_groups()
            gain, _ = ca_model.steady_state(1 / rate, g.r, None, est.psd)
            np.testing.assert_allclose(src.lag, lag_per_jerk(gain, 1 / rate, False), rtol=0.01)
            checked += 1
    assert checked >= 1, "the noise step regrouped the joint"


@pytest.mark.parametrize("m", [1, 2])
def test_the_batched_derivation_equals_the_per_group_reference(m):
    """unit_noise_covariances / lags_per_jerk (one batched solve for every group, what
    refresh() runs) against noise_covariance (scipy's Lyapunov solver) and lag_per_jerk, one
    gain at a time, on settled gains of noise levels 0.05-3 deg at 30 Hz-1 kHz."""
    rng = np.random.default_rng(11)
    for dt in (1e-3, 4e-3, 1 / 30):
        gains = np.stack([ca_model.steady_state(dt, math.radians(r), math.radians(2.0) if m == 2 else None,
                                                1e4)[0] for r in rng.uniform(0.05, 3.0, 4)])
        base = int(rng.integers(1, 60))
        sig, dvar = unit_noise_covariances(gains, dt, base)
        lags = lags_per_jerk(gains, dt, m == 2)
        for g, k in enumerate(gains):
            np.testing.assert_allclose(lags[g], lag_per_jerk(k, dt, m == 2), rtol=1e-9)
            for i in range(m):
                unit = np.zeros((m, m))
                unit[i, i] = 1.0
                s_ref, d_ref = noise_covariance(k, dt, unit, base)
                np.testing.assert_allclose(sig[g, i], s_ref, rtol=1e-7, atol=1e-12 * np.abs(s_ref).max())
                assert dvar[g, i] == pytest.approx(d_ref, rel=1e-6)


def test_exact_input_has_no_noise_part(arm):
    """trajectory_publisher's exact input (1 kHz, exact velocities): the samples show no
    noise (white level at the floor, velocity noise below it), so the estimation part is 0
    and the σ is the lag part; with 0.1 deg of noise on the positions it is not."""
    mv = movement_library()[16]
    rate = 1000.0
    t = np.concatenate([np.arange(-500, 0) / rate, mv.sample_times(rate)])
    q, qd, _ = mv.evaluate(t)
    exact = inverse_dynamics_with_std(arm, t, q, qd, model=False)
    k = exact.known
    assert k.sum() > 0.5 * len(t)
    assert np.all(exact.var_est[k] == 0.0) and np.any(exact.var_lag[k] > 0.0)
    rng = np.random.default_rng(5)
    noisy = inverse_dynamics_with_std(arm, t, q + rng.normal(0, math.radians(0.1), q.shape), qd, model=False)
    assert np.all(noisy.var_est[noisy.known][:, 0] > 0.0)


def test_torque_std_reads_the_scaled_jerk(arm):
    """TorqueStd (the node's path and the API's: one call) hands each joint's lag scale to
    the jerk read: the mean-square jerk it propagates is the noise-corrected one times
    lag_scale2, per joint (a quiet joint beside a noisy one: scale < 1). The model's q̈
    (practice filter off, as in _jerk_read)."""
    est = make_estimator("kalman", arm.nv, {"practice_filter": 0.0})
    ts = TorqueStd(arm, est, model=False)
    rng = np.random.default_rng(6)
    levels = [0.1] * arm.nv
    levels[1] = 1.0
    t, z = still(levels, 3.0, rng)
    s = (t - t[0]) * 1e-9
    z[:, :2] += 300.0 * s[:, None] ** 3 / 6  # a jerk the tracker reads on both
    for k in range(len(t)):
        est.update(int(t[k]), z[k], None)
        ts.update(int(t[k]), False)
    src, tr = ts.src, ts.jerk
    assert src.lag_scale2[1] == pytest.approx(1.0) and src.lag_scale2[0] < 0.5
    want = np.maximum(tr._ms, 0.0) * src.lag_scale2  # the noise-corrected average, scaled
    assert want[0] > 0 and want[1] > 0
    np.testing.assert_allclose(tr.ms_jerk, want, rtol=1e-9)


def test_the_sigma_is_evaluated_every_4_ms_and_held_in_between(arm, monkeypatch):
    """At 1 kHz TorqueStd evaluates (covariance source, jerk read, derivatives) every
    EVALUATE_S of stream time and keeps that σ for the samples in between; at 100 Hz every
    sample. The held σ is the σ an evaluation on every sample gives to within 5 % (RMS per
    joint; noise fixed, so that both see the same covariance: the jerk average is the only
    difference)."""
    mv = movement_library()[4]
    rng = np.random.default_rng(8)
    for rate, every in ((1000.0, 4), (RATE, 1)):
        t = mv.sample_times(rate)
        z = mv.evaluate(t)[0] + rng.normal(0.0, math.radians(0.1), (len(t), arm.nv))
        est = make_estimator("kalman", arm.nv, {"kalman_noise_deg": 0.1})
        ts = TorqueStd(arm, est)
        stamps, held = [], 0
        for k in range(len(t)):
            t_ns = round(t[k] * 1e9)
            est.update(t_ns, z[k], None)
            before = ts.std.copy()
            known = ts.update(t_ns, False)
            if ts.evaluated_ns == t_ns:
                stamps.append(t_ns)
            elif known:
                np.testing.assert_array_equal(ts.std, before)
                held += 1
        steps = np.diff(stamps[5:])
        assert np.all(steps == round(every * 1e9 / rate)), np.unique(steps)
        assert (held > 0) == (every > 1)
    t = mv.sample_times(1000.0)
    z = mv.evaluate(t)[0] + rng.normal(0.0, math.radians(0.1), (len(t), arm.nv))
    held = inverse_dynamics_with_std(arm, t, z, settings={"kalman_noise_deg": 0.1})
    monkeypatch.setattr(torque_std, "EVALUATE_S", 0.0)
    fresh = inverse_dynamics_with_std(arm, t, z, settings={"kalman_noise_deg": 0.1})
    k = held.known & fresh.known
    ratio = np.sqrt((held.std[k] ** 2).mean(0) / (fresh.std[k] ** 2).mean(0))
    np.testing.assert_allclose(ratio, 1.0, atol=0.05)
