"""The constant-acceleration (white-jerk) model of one joint and its discretisation.

Kept apart from the filter (kalman.py), the noise estimator (noise.py), the jump gate
(gate.py) and the fixed-lag smoother (smoother.py), as filterpy keeps model, filter and
discretisation apart: everything here is a pure function of (dt, noise, psd).

State x = [q, qd, qdd]; between samples dt apart
    x' = F x + w,  F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]],
    w = integrated white jerk of spectral density S (rad^2/s^5):
    Q = S [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]].
Measurement: the position (noise std r) and, with velocities given, the velocity (std r_v).

Covariances are carried as 6-tuples (p00 p01 p02 p11 p12 p22) of plain floats: one step is
~45 multiplications, cheaper in CPython than numpy calls on 3x3 arrays.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.linalg import solve_discrete_are

Cov = tuple[float, float, float, float, float, float]


def transition(dt: float) -> np.ndarray:
    return np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def observation(velocity_given: bool) -> np.ndarray:
    """H: the position is measured, and the velocity when the message carries it."""
    return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) if velocity_given else np.array([[1.0, 0.0, 0.0]])


def process_noise(dt: float, psd: float) -> np.ndarray:
    d2, d3 = dt * dt, dt * dt * dt
    return psd * np.array([[d2 * d3 / 20, d2 * d2 / 8, d3 / 6],
                           [d2 * d2 / 8, d3 / 3, d2 / 2],
                           [d3 / 6, d2 / 2, dt]])


def steady_state(dt: float, r: float, r_v: float | None, psd: float) -> tuple[np.ndarray, np.ndarray]:
    """(gain K (3, m), prior covariance M) of the converged filter; m = 1 or 2 measurements.

    Solved in units of r (positions / r) so the equation is well scaled for any noise.
    """
    f = transition(dt)
    q = process_noise(dt, psd / (r * r))
    h = observation(r_v is not None)
    rm = np.eye(1) if r_v is None else np.diag([1.0, (r_v / r) ** 2])
    p = solve_discrete_are(f.T, h.T, q, rm)
    k = p @ h.T @ np.linalg.inv(h @ p @ h.T + rm)
    return k, p * (r * r)


def to_tuple(m: np.ndarray) -> Cov:
    return tuple(float(m[i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))


def to_matrix(c: Cov) -> np.ndarray:
    p00, p01, p02, p11, p12, p22 = c
    return np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]])


@functools.lru_cache(maxsize=512)
def steady_posterior(dt: float, r: float, r_v: float | None, psd: float) -> Cov:
    """The converged posterior covariance (where a filter is seated at its start).

    Cached per (dt, r, r_v, psd), the same numbers (a tuple: immutable): KalmanCA seats its
    noise groups with it on the callback's path, and the groups' noises are bin centres, so
    a regular stream asks for a handful of them again and again (a 200 s, 20-joint, 100 Hz
    positions-only stream: 39 Riccati solves of 4 distinct ones, ~1 ms each idle, 24 ms at
    load 5; they were its update()'s p99: 4.1 ms)."""
    k, m = steady_state(dt, r, r_v, psd)
    h = np.eye(3)[: k.shape[1]]
    return to_tuple(m - k @ (h @ m))


@functools.lru_cache(maxsize=64)
def steady_gain(dt: float, r: float, r_v: float | None, psd: float) -> np.ndarray:
    """The converged filter's gain K (3, m), read-only, cached per (dt, r, r_v, psd):
    KalmanCA.lag() describes a filter with it before a group has a gain of its own (a node's
    diagnostics ask every period, on its executor thread)."""
    k, _ = steady_state(dt, r, r_v, psd)
    k.setflags(write=False)
    return k


@functools.lru_cache(maxsize=64)
def restart_posterior(r: float, r_v: float | None, psd: float, horizon_s: float) -> Cov:
    """Where a filter restarted from one sample (q the sample, q̇ 0 or the given velocity,
    q̈ 0) is seated: the spread the white jerk gives a state over horizon_s from a known one
    (Q(horizon_s): what a movement under way for that long may be doing), measured once by
    the sample (r, r_v). q̇, q̈ are then uncertain by tens of rad/s, rad/s² where the steady
    posterior is sure of them, so the filter learns them from the samples that follow (a
    least-squares fit at first, the steady gain once converged) instead of trusting its
    zeros. Cached: the arguments are bin centres, as steady_posterior's."""
    m = prior((0.0,) * 6, horizon_s, psd)
    return measurement_update(m, r * r, None if r_v is None else r_v * r_v)[1]


def prior(p: Cov, dt: float, psd: float) -> Cov:
    """M = F P F^T + Q at dt, in plain floats."""
    p00, p01, p02, p11, p12, p22 = p
    h = 0.5 * dt * dt
    a0, a1, a2 = p00 + dt * p01 + h * p02, p01 + dt * p11 + h * p12, p02 + dt * p12 + h * p22
    b1, b2 = p11 + dt * p12, p12 + dt * p22
    s = psd * dt
    return (a0 + dt * a1 + h * a2 + s * h * h / 5,  # Q: S dt^5/20
            a1 + dt * a2 + s * h * dt / 4,  # S dt^4/8
            a2 + s * h / 3,  # S dt^3/6
            b1 + dt * b2 + s * h * 2 / 3,  # S dt^3/3
            b2 + s * dt / 2,  # S dt^2/2
            p22 + s)  # S dt


def measurement_update(m: Cov, r2: float, rv2: float | None) -> tuple[tuple[float, ...], Cov]:
    """(gain, posterior) from the prior M, position variance r2 and, velocities given,
    velocity variance rv2. Gain: (k0, k1, k2) for positions only, else row by row
    (k00, k01, k10, k11, k20, k21); posterior in M's layout."""
    m00, m01, m02, m11, m12, m22 = m
    s00 = m00 + r2
    if rv2 is None:
        k0, k1, k2 = m00 / s00, m01 / s00, m02 / s00
        return (k0, k1, k2), (m00 - k0 * m00, m01 - k0 * m01, m02 - k0 * m02,
                              m11 - k1 * m01, m12 - k1 * m02, m22 - k2 * m02)
    s11 = m11 + rv2
    det = s00 * s11 - m01 * m01
    i00, i01, i11 = s11 / det, -m01 / det, s00 / det  # S^-1
    # K = M H^T S^-1: row i is (m_i0, m_i1) S^-1
    k00, k01 = m00 * i00 + m01 * i01, m00 * i01 + m01 * i11
    k10, k11 = m01 * i00 + m11 * i01, m01 * i01 + m11 * i11
    k20, k21 = m02 * i00 + m12 * i01, m02 * i01 + m12 * i11
    return (k00, k01, k10, k11, k20, k21), (
        m00 - k00 * m00 - k01 * m01, m01 - k00 * m01 - k01 * m11, m02 - k00 * m02 - k01 * m12,
        m11 - k10 * m01 - k11 * m11, m12 - k10 * m02 - k11 * m12, m22 - k20 * m02 - k21 * m12)


def qdd_lag(dt: float, k: np.ndarray, velocity_given: bool) -> float:
    """Delay (s) of the qdd estimate under a constant jerk, for gain k (3, m) at dt."""
    h = observation(velocity_given)
    f = transition(dt)
    g = np.array([dt**3 / 6, dt**2 / 2, dt])  # true-state increment per unit jerk, on top of F x
    ikh = np.eye(3) - k @ h
    # e = est - true after update; e' = (I - K H)(F e - g j)  ->  e = -(I - (I-KH)F)^-1 (I-KH) g j
    e = -np.linalg.solve(np.eye(3) - ikh @ f, ikh @ g)
    return float(-e[2])


@functools.lru_cache(maxsize=256)
def lag_gains(dt: float, r: float, r_v: float | None, psd: float, lags: int,
              prior_cov: Cov | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-lag smoother gains of the converged filter, and the smoothed covariance.

    With M the prior covariance, K the gain, S = H M H^T + R and A = (F (I - K H))^T:
    Sigma_m = M A^m, K_m = Sigma_m H^T S^-1 (m = 1..lags), so that the estimate of sample j
    after the innovations e_{j+1} .. e_{j+L} is x_{j|j} + sum_m K_m e_{j+m}, and its
    covariance P_{j|j} - sum_m Sigma_m H^T S^-1 H Sigma_m^T. Returns (gains (lags+1, 3, m),
    gains[0] = 0 (the filter's own correction), covariance (3, 3)). prior_cov: the filter's
    converged prior M if known (no Riccati solve), else solved here.

    Cached per argument tuple, the arrays read-only (issue 29 item 5): KalmanCA rebuilds every
    group's gains on its callback's path whenever its groups change, and a group that did
    not change (converged: its M is the same tuple) asks again for the same numbers; 50 lags
    cost ~0.3 ms per group idle. Same numbers, bit for bit, as without the cache.
    """
    h = observation(r_v is not None)
    rm = np.diag([r * r] if r_v is None else [r * r, r_v * r_v])
    if prior_cov is None:
        _, m = steady_state(dt, r, r_v, psd)
    else:
        m = to_matrix(prior_cov)
    s_inv = np.linalg.inv(h @ m @ h.T + rm)
    k = m @ h.T @ s_inv
    a = (transition(dt) @ (np.eye(3) - k @ h)).T
    gains = np.zeros((lags + 1, 3, h.shape[0]))
    cov = m - k @ h @ m
    sig = m
    for i in range(1, lags + 1):
        sig = sig @ a
        gains[i] = sig @ h.T @ s_inv
        cov = cov - sig @ h.T @ s_inv @ h @ sig.T
    gains.flags.writeable = False
    cov.flags.writeable = False
    return gains, cov
