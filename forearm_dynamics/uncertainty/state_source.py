"""What the σ needs from a state estimator, read in ONE place (the adapter of issue 19).

The propagation needs the covariance of each joint's (q, q̇, q̈) estimate and the
estimator's steady-state error per unit jerk (its lag). Only the Kalman filter
(estimation/kalman.py) carries a covariance: per joint, from the gain of the joint's noise
group (issue 16: joints are grouped by their own noise level), read through its public API
(noise_groups(), measured_noise(), covariance(), period_s); nothing else in the package
reads estimator internals.

Which covariance. The filter's P is the error covariance IF the motion were white jerk of
the model's spectral density (kalman_jerk_psd): it adds the measurement noise seen through
the gain and a motion part for that random jerk. Real movements are smooth with bursts of
jerk, so P is too wide on most samples (3.7x the RMSE on exact 1 kHz input, where the error
is all lag) and too narrow in the fast ones (benchmarks/uncertainty.py, the "posterior"
rows). So the σ splits it: the NOISE part is kept exactly, the covariance of the estimate
driven by the measurement noise through the filter's own gain,
    Σ = A Σ Aᵀ + K R Kᵀ,  A = (I - K H) F   (a discrete Lyapunov equation),
and the motion part is replaced by the lag term (lag.py) computed from the jerk the
movement actually has. `covariance="posterior"` gives the raw P instead (the uncalibrated
σ that the tests must tell apart).

The jerk is estimated from the change of the q̈ estimate over `baseline` samples (about the
q̈ lag, lag.py); the noise alone gives that change the variance `delta_noise_var` =
2 (Σ₂₂ - (Aᵐ Σ)₂₂), for lag.JerkTracker to take away.

Estimators without a covariance (backward differences, Butterworth, Savitzky-Golay) give
None: no σ is computed for them (the node then publishes no joint_torques_std and says so in
its config message; the offline API raises NoCovariance naming the estimator).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from ..estimation.ca_model import observation, transition
from ..estimation.kalman import KalmanCA
from .lag import MAX_BASELINE

#: the gain-derived quantities are re-derived at most this often (s of stream time) unless the
#: sample period or the noise belief moved: they change only with those
_REFRESH_S = 0.25
_DT_MOVE = math.log(1.05)
#: after a regroup, re-derive for at most this many sample periods (the gain of a uniform
#: 1 kHz stream settles to 1e-3 within 28-90 samples)
_SETTLE_MAX = 100
#: ... and while settling, re-derive at most this often (s of stream time)
_SETTLE_EVERY_S = 0.004
_IDX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_ROWS, _COLS = (np.array(x) for x in zip(*_IDX))


def lag_per_jerk(k: np.ndarray, dt: float, velocity_given: bool) -> np.ndarray:
    """e (3,): steady-state (estimate - truth) of (q, q̇, q̈) per unit constant jerk for a
    constant-acceleration filter of gain k (3, m) at period dt (KalmanCA.lag's algebra,
    all three components)."""
    h = observation(velocity_given)
    f = transition(dt)
    g = np.array([dt**3 / 6, dt**2 / 2, dt])
    ikh = np.eye(3) - k @ h
    return -np.linalg.solve(np.eye(3) - ikh @ f, ikh @ g)


def noise_covariance(k: np.ndarray, dt: float, r: np.ndarray, baseline: int) -> tuple[np.ndarray, float]:
    """(Σ (3, 3) of the noise-driven estimation error, the noise variance of the q̈ change
    over `baseline` samples) for gain k (3, m), period dt, measurement covariance r (m, m).
    The reference (scipy's Lyapunov solver, one gain); StateSource uses unit_noise_covariances,
    which solves every group at once and is tested against this."""
    m = k.shape[1]
    h = observation(m == 2)
    f = transition(dt)
    a = (np.eye(3) - k @ h) @ f
    t = np.array([1.0, dt, dt * dt])  # scaled state (q, qd dt, qdd dt²): well conditioned
    ts = a * t[:, None] / t[None, :]
    ks = k * t[:, None]
    sig = solve_discrete_lyapunov(ts, ks @ r @ ks.T) / np.outer(t, t)
    cross = np.linalg.matrix_power(a, baseline) @ sig  # Cov(e_k, e_{k-m}) = A^m Σ
    return sig, 2.0 * float(sig[2, 2] - cross[2, 2])


def lags_per_jerk(k: np.ndarray, dt: float, velocity_given: bool) -> np.ndarray:
    """lag_per_jerk for a stack of gains k (G, 3, m): (G, 3)."""
    h = observation(velocity_given)
    f = transition(dt)
    g = np.array([dt**3 / 6, dt**2 / 2, dt])
    ikh = np.eye(3) - k @ h  # (G, 3, 3)
    return -np.linalg.solve(np.eye(3) - ikh @ f, (ikh @ g)[..., None])[..., 0]


def unit_noise_covariances(k: np.ndarray, dt: float, baseline: int) -> tuple[np.ndarray, np.ndarray]:
    """noise_covariance for a stack of gains k (G, 3, m) and each unit measurement noise
    (R = e_i e_iᵀ, i < m; Σ is linear in R): (Σ (G, m, 3, 3), q̈-change variance (G, m)).

    One batched solve of the Lyapunov equations in Kronecker form, vec Σ = (I - A⊗A)⁻¹ vec Q,
    in the scaled state (q, q̇ dt, q̈ dt²): 9x9 systems, one per group, instead of one scipy
    call per group and unit (a regroup took ~1 ms of the 1 kHz node's callback that way)."""
    gn, _, m = k.shape
    h = observation(m == 2)
    a = (np.eye(3) - k @ h) @ transition(dt)  # (G, 3, 3)
    t = np.array([1.0, dt, dt * dt])
    ts = a * (t[:, None] / t[None, :])
    ks = k * t[:, None]  # (G, 3, m)
    op = np.eye(9) - np.einsum("gij,gkl->gikjl", ts, ts).reshape(gn, 9, 9)
    rhs = np.einsum("gim,gkm->gikm", ks, ks).reshape(gn, 9, m)  # vec(k_i k_iᵀ) per unit i
    sig = np.linalg.solve(op, rhs).reshape(gn, 3, 3, m).transpose(0, 3, 1, 2) / np.outer(t, t)
    am = np.linalg.matrix_power(a, baseline)  # (G, 3, 3): Cov(e_k, e_{k-m}) = A^m Σ
    cross22 = np.einsum("gj,gmj->gm", am[:, 2, :], sig[:, :, :, 2])
    return sig, 2.0 * (sig[:, :, 2, 2] - cross22)


class StateSource:
    """Reads one Kalman estimator after each update(), through its public API
    (noise_groups(), measured_noise(), period_s): `cov()` the covariance in COV_KEYS order,
    a (6,) tuple when every joint has the same (one noise group, same measured noise), else
    an (n, 6) array per joint, None until the filter runs with a measured noise (the first
    ~0.5 s: the default belief it starts with, 0.5 deg, is no measurement: a 3 deg camera's
    σ would be computed for a sixth of its noise); `lag` (3,) per unit jerk of the noisiest
    group, `lag_scale2` (n,) each joint's own q̈ lag over that one's, squared; `baseline` and
    `delta_noise_var` (scalar or (n,)) for the jerk estimate."""

    def __init__(self, est: KalmanCA, covariance: str = "noise"):
        if covariance not in ("noise", "posterior"):
            raise ValueError(f"covariance must be 'noise' or 'posterior', not {covariance!r}")
        self.est = est
        self.kind = covariance
        self.lag = np.zeros(3)
        self.lag_scale2 = np.ones(est.n)
        self.delta_noise_var: float | np.ndarray = 0.0
        self.baseline = 1
        self._known = False
        self._settling = False
        self._settle_until = 0.0  # stream time (s) settling stops at regardless
        self._gains: np.ndarray | None = None
        self._noise: tuple[float, ...] | np.ndarray | None = None
        self._t = -math.inf
        self._dt: float | None = None
        self._dt_seat = 1.0
        self._key: tuple | None = None
        self._pf: np.ndarray | None = None  # the practice filter's shares at the last refresh
        what = ("the covariance of (q, qd, qdd) that the measurement noise drives through the "
                f"{est.name} filter's gain (discrete Lyapunov, noise measured per joint)"
                if covariance == "noise" else f"{est.name} posterior covariance P of (q, qd, qdd)")
        self.description = {"estimation": f"{what}, per joint (its noise group's gain), through "
                                          "computeRNEADerivatives (dtau/dq, dtau/dqd, M)"}

    def refresh(self, t_s: float, velocity_given: bool) -> None:
        """Re-derive gains, lag, noise covariance if the mean period or the noise groups
        moved, or every 0.25 s of stream time (never per sample)."""
        est = self.est
        if not self._known:  # once measured it stays measured (a reset keeps the noise)
            self._known = est.noise_known(velocity_given)
        # the MEAN period (exponential, ~20 samples), against the one of the last refresh with
        # 5 % of hysteresis: a jittered stream's dt moves every sample, its settled gain hardly
        p = est.period_s
        self._dt = dt = p if self._dt is None else self._dt + 0.05 * (p - self._dt)
        key = (velocity_given, est.groups_version)
        if key == self._key:
            if self._settling:
                if t_s < self._settle_until and t_s - self._t < _SETTLE_EVERY_S:
                    return
            elif t_s - self._t < _REFRESH_S and abs(math.log(dt / self._dt_seat)) < _DT_MOVE:
                return
        groups = est.noise_groups()
        if not groups or dt <= 0.0:
            return
        # a regrouped filter's gain is not settled yet (a new group starts from a scaled or
        # steady-state P and converges over some samples): Σ and nv from the first step's
        # gain were off by up to 4000x (a 1 kHz encoder's joint: nv 0.002 against 8.6
        # (rad/s²)² once settled), held for 0.25 s; so re-derive every _SETTLE_EVERY_S (every
        # sample at 250 Hz and below) until two successive gains agree to 1e-3, for at most
        # _SETTLE_MAX samples: on real stamps the gain moves with each sample's dt (2 % stamp
        # jitter at 1 kHz: 2e-3 per sample) and never agrees. A derivation on every sample
        # of a 1 kHz stream (one scipy Lyapunov solve per group, ~0.3-1 ms) put the node
        # 30-50 ms behind its input after each regroup; batched (~0.1 ms) and every 4 ms it
        # stays within the sample period
        gains = np.concatenate([g.gain.ravel() for g in groups])
        last = self._gains
        if key != self._key:
            self._settle_until = t_s + _SETTLE_MAX * dt
        self._settling = key != self._key or (
            self._settling and t_s < self._settle_until
            and (last is None or last.shape != gains.shape
                 or not np.allclose(gains, last, rtol=1e-3, atol=0.0)))
        self._gains = gains
        self._dt_seat = dt
        m = 2 if velocity_given else 1
        if any(g.gain.shape[1] != m for g in groups):
            return
        gains3 = np.stack([g.gain for g in groups])  # (G, 3, m)
        lags = lags_per_jerk(gains3, dt, velocity_given)  # (G, 3)
        worst = max(range(len(groups)), key=lambda i: groups[i].r)
        self.lag = lags[worst]
        self.baseline = int(min(MAX_BASELINE, max(1, round(abs(self.lag[2]) / dt))))
        # each joint lags by its own group's gain (a 0.1 deg elbow beside a 1 deg pro/sup, as
        # mocap IK gives, lags less than the pro/sup): the torque's lag weights take the
        # reference group's vector, so each joint's jerk is scaled by its q̈ lag over the
        # reference's (`lag_scale2`, squared): exact for the M·e₂ term; the smaller ∂τ/∂q·e₀
        # and ∂τ/∂q̇·e₁ terms are scaled alike (an approximation)
        n = est.n
        gi = np.full(n, -1, np.intp)  # each joint's group (-1: in none yet)
        for i, g in enumerate(groups):
            gi[g.idx] = i
        scale = np.ones(n)
        if self.lag[2] != 0.0:
            scale = np.where(gi >= 0, lags[gi, 2] / self.lag[2], 1.0)
        np.multiply(scale, scale, out=self.lag_scale2)
        r2, rv2 = est.measured_noise()
        # no noise where the samples show none: a joint whose white level (near Nyquist, no
        # movement there) is at the floor is exact or held, its 10 Hz level is the movement's
        # own content; a velocity noise measured below the floor is the exact velocities'
        # second difference (0.001 deg/s at 1 kHz). Counted as noise, they made the exact
        # input's σ 1.1-1.8x its error from this part alone (fingers)
        r2 = np.where(est.noiseless(), 0.0, r2)
        floor = math.radians(est.values["kalman_noise_floor_deg"])
        rv2 = np.where(rv2 < floor * floor, 0.0, rv2)
        # Σ is linear in R = diag(n2, nv2): one solve per unit measurement, combined per joint
        sig, dvar = unit_noise_covariances(gains3, dt, self.baseline)  # (G, m, 3, 3), (G, m)
        unit = sig[:, :, _ROWS, _COLS]  # (G, m, 6) in COV_KEYS order
        w = np.stack([r2, rv2][:m], axis=1) * (gi >= 0)[:, None]  # (n, m): R per joint
        g0 = np.maximum(gi, 0)
        cov = np.einsum("jm,jmc->jc", w, unit[g0])
        dnv = np.einsum("jm,jm->j", w, dvar[g0])
        self._pf = None
        if not velocity_given:
            w = est.practice_filter_weight()
            if w.any():  # cov() adds the blend's error variance at every evaluation
                self._pf = w
        if np.ptp(cov, axis=0).max() <= 1e-15 * max(np.abs(cov).max(), 1e-300):
            self._noise = tuple(float(x) for x in cov[0])  # shared: the propagator's fast path
            self.delta_noise_var = float(dnv[0])
        else:
            self._noise = cov
            self.delta_noise_var = dnv
        self._key, self._t = key, t_s

    def _practice_filter(self, base) -> np.ndarray:
        """The practice filter's joints (estimation/practice_output.py): their q̈ is the blend
        of the model's and the filter's, share w of the blend (w as at the last refresh).
        Its error variance now (practice_blend.error_variance: the two estimates' recent
        disagreement scaled by the blend's error against the practice over it, as measured)
        is their q̈ noise part, w² of it beside (1 - w)² of the model's; the model's q̈
        covariances with q and q̇ keep (1 - w) of their weight. The lag part (lag.py: the
        model's error per unit jerk times the jerk read) stays whole: the measured error is
        against the practice, and a fast movement has content the practice removes that the
        truth keeps. Without it the simulated sensors' σ (benchmarks/uncertainty.py --every
        8, scored against the truth) was too narrow on 4 inputs (0.89-0.90 inside ±1.96σ, or
        RMS(σ)/RMSE 0.75-0.80); with it 10 of 11 meet the targets, and the real corpus's
        tuning half stays within them (0.95-0.98). Per evaluation, not per refresh: the
        disagreement follows the movement."""
        w = self._pf
        cov = np.empty((self.est.n, 6))
        cov[:] = base
        keep = 1.0 - w
        cov[:, 2] *= keep
        cov[:, 4] *= keep
        cov[:, 5] *= keep * keep
        cov[:, 5] += w * w * self.est.practice_filter_variance()
        return cov

    def measured_noise(self) -> tuple[np.ndarray, np.ndarray]:
        """Per joint (position, velocity) noise variances that drive the error (the filter's
        measurement before its floor; KalmanCA.measured_noise)."""
        return self.est.measured_noise()

    def cov(self) -> tuple[float, ...] | np.ndarray | None:
        if self.kind == "posterior":
            p = self.est.covariance()
            c = np.stack([p[:, i, j] for i, j in _IDX], axis=1)
            if np.ptp(c, axis=0).max() == 0.0:
                return tuple(float(x) for x in c[0])
            return c
        if not self._known:
            return None
        return self._noise if self._pf is None else self._practice_filter(self._noise)


def state_source(est, covariance: str = "noise") -> StateSource | None:
    """The adapter: a StateSource for estimators that carry a covariance, else None."""
    if isinstance(est, KalmanCA):
        return StateSource(est, covariance)
    return None
