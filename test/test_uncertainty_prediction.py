"""The σ of an extrapolated estimate (torque_node's output_rate_hz > 0): the covariance and the
lag moved over the horizon (uncertainty.propagation.extrapolated), checked against the
Kalman filter itself predicting ahead — under a constant jerk (the lag) and on pure noise
(the covariance) — and TorqueStd.predict against the propagation at the extrapolated state.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from forearm_dynamics.dynamics import build_model
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.movements import movement_library
from forearm_dynamics.uncertainty import TorqueStd
from forearm_dynamics.uncertainty.propagation import Propagator, cov_matrix, extrapolated
from forearm_dynamics.uncertainty.state_source import state_source

pytestmark = pytest.mark.unit

RATE = 100.0


@pytest.mark.parametrize("h", [0.0, 0.004, 0.03, 0.1])
def test_extrapolated_lag_is_the_filters_error_under_constant_jerk(h):
    """A constant jerk through the filter, then est.predict h ahead: the error of the
    extrapolated (q, qd, qdd) against the truth at t + h is e_h·j (all three components)."""
    jerk = 3.0
    est = make_estimator("kalman", 1, {"kalman_noise_deg": 0.5})
    src = state_source(est)
    t = np.arange(600) / RATE
    for k in range(len(t)):
        est.update(round(t[k] * 1e9), np.array([jerk * t[k] ** 3 / 6]), None)
    src.refresh(t[-1], False)
    te = t[-1] + h
    est.predict(round(t[-1] * 1e9) + round(h * 1e9))
    err = np.array([est.q[0] - jerk * te**3 / 6, est.qd[0] - jerk * te**2 / 2, est.qdd[0] - jerk * te])
    _cov, lag_h = extrapolated(src.cov(), src.lag, h)
    np.testing.assert_allclose(err, lag_h * jerk, rtol=1e-3, atol=1e-9)
    if h > 0:  # the extrapolation is worse than the estimate it starts from, in every component
        assert np.all(np.abs(lag_h) > np.abs(src.lag))


@pytest.mark.slow  # seconds of CPU: not in `-m unit`
def test_extrapolated_covariance_matches_the_filter_predicting_pure_noise():
    """A still joint through 0.5 deg white noise: the covariance of the filter's prediction
    h = 30 ms ahead (20 000 samples x 8 joints) equals F Σ Fᵀ within 5 % on the diagonal, and
    is wider than Σ in q and qd. The model's own q̈ (the practice filter off: on its joints the
    q̈ noise part is the blend's measured error, test_sigma_parts)."""
    n, h = 8, 0.03
    est = make_estimator("kalman", n, {"kalman_noise_deg": 0.5, "practice_filter": 0.0})
    src = state_source(est)
    z = np.random.default_rng(7).normal(0.0, math.radians(0.5), (20000, n))
    out = np.empty((len(z), 3, n))
    for k in range(len(z)):
        t_ns = round(k * 1e9 / RATE)
        est.update(t_ns, z[k], None)
        if k == 100:
            src.refresh(k / RATE, False)
        est.predict(t_ns + round(h * 1e9))
        out[k] = est.q, est.qd, est.qdd
    out = out[200:]
    emp = np.einsum("kin,kjn->ij", out, out) / (out.shape[0] * n)
    cov_h, _ = extrapolated(src.cov(), None, h)
    ref = cov_matrix(np.asarray(cov_h))
    np.testing.assert_allclose(np.diag(emp), np.diag(ref), rtol=0.05)
    sig = cov_matrix(np.asarray(src.cov()))
    assert ref[0, 0] > 1.5 * sig[0, 0] and ref[1, 1] > sig[1, 1]


def test_predict_is_the_propagation_at_the_extrapolated_state():
    """TorqueStd.predict = the Propagator at est.predict's state with the extrapolated
    covariance and lag; at h = 0 it is update()'s σ; it does not depend on earlier predictions."""
    arm = build_model()
    mv = movement_library()[20]
    t = mv.sample_times(RATE)
    q, _, _ = mv.evaluate(t)
    z = q + np.random.default_rng(8).normal(0.0, math.radians(0.5), q.shape)
    est = make_estimator("kalman", arm.nv)
    ts = TorqueStd(arm, est)
    k_end = len(t) // 2
    for k in range(k_end):
        t_ns = round(t[k] * 1e9)
        est.update(t_ns, z[k], None)
        ts.update(t_ns, False)
    now = est.stamp_ns
    at_update = ts.std.copy()
    est.predict(now)
    assert ts.predict(now)
    np.testing.assert_allclose(ts.std, at_update, rtol=1e-12)
    h = 0.007
    est.predict(now + round(h * 1e9))
    assert ts.predict(now + round(h * 1e9))
    got = ts.std.copy()
    cov_h, lag_h = extrapolated(ts.src.cov(), ts.src.lag, h)
    ref = Propagator(arm.model, arm.model.createData(), ts.model_var, ts.gain)
    np.testing.assert_allclose(got, ref(est.q, est.qd, est.qdd, cov_h, lag_h, ts.jerk.ms_jerk),
                               rtol=1e-12)
    est.predict(now + round(0.003 * 1e9))
    ts.predict(now + round(0.003 * 1e9))
    est.predict(now + round(h * 1e9))
    ts.predict(now + round(h * 1e9))
    np.testing.assert_array_equal(ts.std, got)
