"""The torque σ's core (forearm_dynamics/uncertainty): propagation, lag, noise, model term, API.

Each check compares with an independent computation: finite differences of the model's
inverse dynamics, a Monte Carlo of the nonlinear RNEA, the filter run on the signal whose
error it predicts, and the paper's results file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from forearm_dynamics.dynamics import build_model
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.movements import movement_library
from forearm_dynamics.uncertainty import NoCovariance, inverse_dynamics_with_std
from forearm_dynamics.uncertainty.model_term import load_table, model_variance, table_from_results
from forearm_dynamics.uncertainty.propagation import (
    NUMERIC_FLOOR_VAR,
    Propagator,
    cov_matrix,
    derivatives,
    lag_variance,
    torque_variance,
)
from forearm_dynamics.uncertainty.state_source import lag_per_jerk, noise_covariance, state_source

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def arm():
    return build_model()


def random_state(arm, rng):
    lo, hi = arm.model.lowerPositionLimit, arm.model.upperPositionLimit
    return rng.uniform(lo, hi), rng.normal(0.0, 2.0, arm.nv), rng.normal(0.0, 20.0, arm.nv)


def random_cov(rng, n=None):
    """(6,) or (n, 6) positive definite covariances of (q, qd, qdd), realistic scales."""
    shape = (3, 3) if n is None else (n, 3, 3)
    a = rng.normal(size=shape) * np.array([1e-3, 1e-2, 1.0])[:, None]
    p = a @ np.swapaxes(a, -1, -2)
    return p[..., [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]


def fd_jacobian(arm, q, qd, qdd, h=1e-6):
    """(n, 3n) dτ/d(q, qd, qdd) by central differences of arm.inverse_dynamics."""
    n = arm.nv
    cols = []
    for which in range(3):
        for j in range(n):
            x = [q.copy(), qd.copy(), qdd.copy()]
            x[which][j] += h
            up = arm.inverse_dynamics(*x)
            x[which][j] -= 2 * h
            cols.append((up - arm.inverse_dynamics(*x)) / (2 * h))
    return np.array(cols).T


def test_derivatives_match_finite_differences(arm):
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, qd, qdd = random_state(arm, rng)
        tau, a, b, m = derivatives(arm.model, arm.data, q, qd, qdd)
        n = arm.nv
        j = fd_jacobian(arm, q, qd, qdd)
        np.testing.assert_allclose(tau, arm.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-12)
        for got, ref in ((a, j[:, :n]), (b, j[:, n:2 * n]), (m, j[:, 2 * n:])):
            scale = np.abs(ref).max()
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6 * scale)


@pytest.mark.parametrize("per_joint", [False, True])
def test_torque_variance_is_j_p_jt_with_finite_difference_jacobians(arm, per_joint):
    """Var τ = diag(J blockdiag(P_j) Jᵀ), J from finite differences: the algebra of the
    shared and the per-joint paths, against the plain matrix product."""
    rng = np.random.default_rng(2)
    n = arm.nv
    for _ in range(3):
        q, qd, qdd = random_state(arm, rng)
        cov = random_cov(rng, n if per_joint else None)
        j = fd_jacobian(arm, q, qd, qdd)
        pj = cov_matrix(cov if per_joint else np.tile(cov, (n, 1)))  # (n, 3, 3)
        big = np.zeros((3 * n, 3 * n))  # state order: all q, then all qd, then all qdd
        for jj in range(n):
            idx = [jj, n + jj, 2 * n + jj]
            big[np.ix_(idx, idx)] = pj[jj]
        ref = np.diag(j @ big @ j.T)
        _, a, b, m = derivatives(arm.model, arm.data, q, qd, qdd)
        np.testing.assert_allclose(torque_variance(a, b, m, cov), ref, rtol=1e-5, atol=1e-14)
        prop = Propagator(arm.model, arm.model.createData(), np.zeros(n), gain=1.0)
        std = prop(q, qd, qdd, tuple(cov) if not per_joint else cov, None, np.zeros(n))
        np.testing.assert_allclose(prop.var_est, ref, rtol=1e-5, atol=1e-14)
        np.testing.assert_allclose(std, np.sqrt(ref + NUMERIC_FLOOR_VAR), rtol=1e-5)
        np.testing.assert_allclose(prop.tau, arm.inverse_dynamics(q, qd, qdd), atol=1e-12)


def test_linearisation_matches_monte_carlo_of_the_nonlinear_rnea(arm):
    """Small state errors (0.2 deg, 2 deg/s, 50 deg/s²): the σ of RNEA over 3000 draws
    equals the propagated one within the sampling error (~3 % at 3000 draws; 8 % allowed)."""
    rng = np.random.default_rng(3)
    q, qd, qdd = random_state(arm, rng)
    sd = np.radians([0.2, 2.0, 50.0])
    cov = (sd[0] ** 2, 0.0, 0.0, sd[1] ** 2, 0.0, sd[2] ** 2)
    prop = Propagator(arm.model, arm.model.createData(), np.zeros(arm.nv), gain=1.0)
    sigma = prop(q, qd, qdd, cov, None, np.zeros(arm.nv)).copy()
    n = arm.nv
    draws = np.array([arm.inverse_dynamics(q + rng.normal(0, sd[0], n), qd + rng.normal(0, sd[1], n),
                                           qdd + rng.normal(0, sd[2], n)) for _ in range(3000)])
    np.testing.assert_allclose(draws.std(axis=0), sigma, rtol=0.08)


def test_lag_vector_is_the_filters_steady_state_error_under_constant_jerk():
    """A constant jerk through the Kalman filter: its settled error equals e·j (all three
    components), and e₂ is minus KalmanCA.lag()'s q̈ delay."""
    rate, jerk = 100.0, 3.0
    est = make_estimator("kalman", 1, {"kalman_noise_deg": 0.5})
    src = state_source(est)
    t = np.arange(600) / rate
    q = jerk * t**3 / 6
    for k in range(len(t)):
        est.update(round(t[k] * 1e9), q[k:k + 1], None)
    src.refresh(t[-1], False)
    err = np.array([est.q[0] - q[-1], est.qd[0] - jerk * t[-1] ** 2 / 2, est.qdd[0] - jerk * t[-1]])
    np.testing.assert_allclose(err, src.lag * jerk, rtol=1e-3, atol=1e-9)
    assert src.lag[2] == pytest.approx(-est.lag(1 / rate, False)["qdd"], rel=1e-6)
    k = np.array([[0.5], [5.0], [20.0]])
    assert lag_per_jerk(k, 0.01, False).shape == (3,)


@pytest.mark.slow  # seconds of CPU: not in `-m unit` (docs/testing.md)
def test_noise_covariance_matches_the_filter_run_on_pure_noise():
    """A still joint seen through 0.5 deg white noise (noise fixed, so the gain is fixed):
    the covariance of the filter's (q, qd, qdd) error over 40 000 samples x 8 joints equals
    the Lyapunov Σ within 5 %; the q̈-change noise variance likewise."""
    rate, n = 100.0, 8
    r = math.radians(0.5)
    # the model's own Σ (the practice filter off: on its joints the q̈ part is the blend's)
    est = make_estimator("kalman", n, {"kalman_noise_deg": 0.5, "practice_filter": 0.0})
    src = state_source(est)
    rng = np.random.default_rng(4)
    z = rng.normal(0.0, r, (40000, n))
    out = np.empty((len(z), 3, n))
    for k in range(len(z)):
        est.update(round(k * 1e9 / rate), z[k], None)
        out[k] = est.q, est.qd, est.qdd
        if k == 100:
            src.refresh(k / rate, False)
    out = out[200:]
    emp = np.einsum("kin,kjn->ij", out, out) / (out.shape[0] * n)
    sig = cov_matrix(np.array(src.cov()))
    np.testing.assert_allclose(np.diag(emp), np.diag(sig), rtol=0.05)
    m = src.baseline
    d = out[m:, 2] - out[:-m, 2]
    assert np.mean(d**2) == pytest.approx(src.delta_noise_var, rel=0.05)
    k = np.array([[0.5], [5.0], [20.0]])
    s, dv = noise_covariance(k, 0.01, np.eye(1) * r * r, 4)
    assert np.all(np.linalg.eigvalsh(s) > 0) and dv > 0


def test_lag_variance_is_zero_without_jerk_and_scales_with_it(arm):
    rng = np.random.default_rng(5)
    _, a, b, m = derivatives(arm.model, arm.data, *random_state(arm, rng))
    e = np.array([-1e-5, -1e-3, -0.04])
    assert np.all(lag_variance(a, b, m, e, np.zeros(arm.nv), 1.0) == 0.0)
    s = rng.uniform(0, 100, arm.nv)
    np.testing.assert_allclose(lag_variance(a, b, m, e, 2 * s, 1.0), 4 * lag_variance(a, b, m, e, s, 1.0))


def test_model_term_table_is_the_papers_results():
    results = json.loads((ROOT / "results/paper/results.json").read_text())
    table = load_table()
    ref = table_from_results(results)
    flat = {(p, z, d): v for p, zs in table["table"].items() for z, ds in zs.items() for d, v in ds.items()}
    assert flat == pytest.approx({(p, z, d): v for p, zs in ref.items() for z, ds in zs.items()
                                  for d, v in ds.items()})
    var, source = model_variance(build_model())
    assert "results/paper/results.json" in source and "oblique, p50" in source
    mv = results["models"]["oblique"]["p50"]["movements"]
    elbow = math.sqrt(np.mean([m["rmse"]["elbow_flexion"] ** 2 for m in mv]))
    assert math.sqrt(var[0]) == pytest.approx(elbow)
    assert not np.any(model_variance(build_model("anatomical"))[0])
    var_f, source_f = model_variance(build_model(body_size="female_50"))
    assert "largest over" in source_f and np.all(var_f >= var)


def test_api_refuses_an_estimator_without_covariance(arm):
    t = np.arange(10) / 100.0
    with pytest.raises(NoCovariance, match="butterworth"):
        inverse_dynamics_with_std(arm, t, np.zeros((10, arm.nv)), estimator="butterworth")
    with pytest.raises(ValueError, match=r"\(N, 20\)"):
        inverse_dynamics_with_std(arm, t, np.zeros((10, 3)))


def _coverage(arm, every, **kw):
    """Coverage of the 95 % band per sample, 100 Hz, 0.5 deg noise, every `every`-th movement."""
    rng = np.random.default_rng(6)
    hit, tot = 0, 0
    ratio_num, ratio_den = 0.0, 0.0
    for mv in movement_library()[::every]:
        t = np.concatenate([np.arange(-50, 0) / 100.0, mv.sample_times(100.0)])
        q, qd, qdd = mv.evaluate(t)
        out = inverse_dynamics_with_std(arm, t, q + rng.normal(0, math.radians(0.5), q.shape),
                                        model=False, **kw)
        e = (out.tau - arm.inverse_dynamics_batch(q, qd, qdd))[50:]
        s = out.std[50:]
        hit += int(np.sum(np.abs(e) <= 1.96 * s))
        tot += e.size
        ratio_num += float(np.sum(s**2))
        ratio_den += float(np.sum(e**2))
    return hit / tot, math.sqrt(ratio_num / ratio_den)


@pytest.mark.slow  # the heaviest unit-module test (~15 s at load 12): not in `-m unit`
def test_calibrated_sigma_covers_and_the_uncalibrated_ones_do_not(arm):
    """On 9 movements at 100 Hz, 0.5 deg: the calibrated σ covers 90-98 % and is 0.8-1.5x
    the RMSE (the default: the practice filter on these joints). On the model's own q̈
    (practice filter off), the calibration's counterfactuals: the noise covariance alone (no
    lag part) covers < 90 %, the raw filter P without the lag part is > 1.2x too wide
    (benchmarks/uncertainty.py: the full runs)."""
    cov, ratio = _coverage(arm, 8)
    assert 0.90 <= cov <= 0.98 and 0.8 <= ratio <= 1.5, (cov, ratio)
    model_only = {"practice_filter": 0.0}
    cov_m, ratio_m = _coverage(arm, 8, settings=model_only)
    assert 0.90 <= cov_m <= 0.98 and 0.8 <= ratio_m <= 1.5, (cov_m, ratio_m)
    cov_nolag, ratio_nolag = _coverage(arm, 8, lag=False, settings=model_only)
    assert cov_nolag < 0.90 and ratio_nolag < 0.8, (cov_nolag, ratio_nolag)
    _cov_p, ratio_p = _coverage(arm, 8, lag=False, covariance="posterior", settings=model_only)
    assert ratio_p > 1.2, ratio_p
