"""What the σ needs from a state estimator, read in ONE place (the adapter of issue 19).

The propagation needs the covariance of each joint's (q, q̇, q̈) estimate and the
estimator's steady-state error per unit jerk (its lag). Today only the Kalman filter
(estimation/kalman.py) carries a covariance: one 3x3 posterior P shared by all joints
(same dt, same noise belief), in private attributes. When the estimator exposes a public
per-joint covariance, `state_source()` is the one function to switch; nothing else in the
package reads estimator internals.

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

from ..estimation.kalman import KalmanCA, measurement_update, observation, transition
from .lag import MAX_BASELINE

#: the gain-derived quantities are re-derived at most this often (s of stream time) unless the
#: sample period or the noise belief moved: they change only with those
_REFRESH_S = 0.25
_DT_MOVE = math.log(1.05)
_IDX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


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
    over `baseline` samples) for gain k (3, m), period dt, measurement covariance r (m, m)."""
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


class StateSource:
    """Reads one Kalman estimator after each update(): `cov()` the (6,) covariance tuple
    (COV_KEYS order, shared by the joints), `lag` (3,) per unit jerk, `baseline` and
    `delta_noise_var` for the jerk estimate."""

    def __init__(self, est: KalmanCA, covariance: str = "noise"):
        if covariance not in ("noise", "posterior"):
            raise ValueError(f"covariance must be 'noise' or 'posterior', not {covariance!r}")
        self.est = est
        self.kind = covariance
        self.lag = np.zeros(3)
        self.delta_noise_var = 0.0
        self.baseline = 1
        self._noise: tuple[float, ...] | None = None
        self._t = -math.inf
        self._dt: float | None = None
        self._dt_seat = 1.0
        self._key: tuple | None = None
        what = ("the covariance of (q, qd, qdd) that the measurement noise drives through the "
                f"{est.name} filter's gain (discrete Lyapunov, noise belief of the filter)"
                if covariance == "noise" else f"{est.name} posterior covariance P of (q, qd, qdd)")
        self.description = {"estimation": f"{what}, one 3x3 shared by the joints, through "
                                          "computeRNEADerivatives (dtau/dq, dtau/dqd, M)"}

    def refresh(self, t_s: float, velocity_given: bool) -> None:
        """Re-derive gain, lag, noise covariance if the mean period or the noise belief moved,
        or every 0.25 s of stream time (about 100 us each: never per sample)."""
        est = self.est
        if est._P is None:
            return
        # the MEAN period (exponential, ~20 samples), against the one of the last refresh with
        # 5 % of hysteresis: a jittered stream's dt moves every sample, its settled gain hardly
        self._dt = dt = est._dt if self._dt is None else self._dt + 0.05 * (est._dt - self._dt)
        key = (velocity_given, est._r, est._r_v if velocity_given else 0.0)
        if (key == self._key and t_s - self._t < _REFRESH_S
                and abs(math.log(dt / self._dt_seat)) < _DT_MOVE):
            return
        self._dt_seat = dt
        r2 = est._r**2
        rv2 = est._r_v**2 if velocity_given else None
        g, _ = measurement_update(est._prior(dt), r2, rv2)
        k = np.array(g).reshape(3, 1 if rv2 is None else 2)
        self.lag = lag_per_jerk(k, dt, velocity_given)
        self.baseline = int(min(MAX_BASELINE, max(1, round(abs(self.lag[2]) / dt))))
        n2, nv2 = self.measured_noise()
        rm = np.diag([n2] if rv2 is None else [n2, nv2])
        sig, self.delta_noise_var = noise_covariance(k, dt, rm, self.baseline)
        self._noise = tuple(float(sig[i, j]) for i, j in _IDX)
        self._key, self._t = key, t_s

    def measured_noise(self) -> tuple[float, float]:
        """(position, velocity) noise variances that drive the error: the filter's online
        statistics BEFORE its floor (kalman_noise_floor_deg keeps the gain sane on exact
        input; it is a belief, not noise that is there), or the fixed values when set. Until
        the first online estimate, the filter's default belief."""
        est = self.est
        r2, rv2 = est._r**2, est._r_v**2
        if est._fixed_r is None and est._qcount >= 7:
            r2 = max(float(np.median(est._ms)), 0.0) / 20.0
        if est._fixed_rv is None and est._vcount >= 6:
            rv2 = max(float(np.median(est._ms_v)), 0.0)
        return r2, rv2

    def cov(self) -> tuple[float, ...] | None:
        if self.kind == "posterior":
            return self.est._P
        return self._noise


def state_source(est, covariance: str = "noise") -> StateSource | None:
    """The adapter: a StateSource for estimators that carry a covariance, else None."""
    if isinstance(est, KalmanCA):
        return StateSource(est, covariance)
    return None
