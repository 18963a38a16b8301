"""The estimation part of the torque σ: the covariance of (q, q̇, q̈) through the linearised RNEA.

τ = RNEA(q, q̇, q̈), so a small state error (δq, δq̇, δq̈) moves the torque by
    δτ = ∂τ/∂q δq + ∂τ/∂q̇ δq̇ + M δq̈
(Pinocchio's computeRNEADerivatives: A = dtau_dq, B = dtau_dv, C = M, symmetric). The
estimators treat joints independently, so with P_j the 3x3 covariance of joint j's
(q, q̇, q̈),
    Var τ_i = Σ_j d_ij^T P_j d_ij,   d_ij = (A_ij, B_ij, C_ij).
computeRNEADerivatives also leaves τ in data.tau (checked in the tests), so a caller that
wants σ does not run pin.rnea as well: the σ costs the derivatives minus one RNEA plus a
few small array products (benchmarks/uncertainty.py measures it in the node's callback).

Lag: a causal estimate under a sustained jerk j is biased by e·j (e per unit jerk, (3,),
the estimator's steady-state error; estimation.kalman.KalmanCA.lag computes it). The
torque bias of joint j's lag is G_ij j_j with G = e0 A + e1 B + e2 C; with the jerk
known only as its recent mean square s_j² (lag.JerkTracker), the lag part of the variance is
    σ_lag,i² = k² Σ_j G_ij² s_j²,
k the calibration factor (lag.LAG_GAIN, from benchmarks/uncertainty.py).

All arrays are preallocated per propagator; a call allocates nothing but numpy's own
temporaries.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

#: σ never below this (N·m²: 1e-12 N·m): at exact rest the estimate, hence the error, is zero
#: but for float64 round-off (1e-17-1e-15 N·m on these torques), and a σ of exactly 0 would
#: claim more than that
NUMERIC_FLOOR_VAR = 1e-24

#: order of the six covariance entries everywhere in this package (symmetric 3x3 of q, q̇, q̈)
COV_KEYS = ("qq", "qv", "qa", "vv", "va", "aa")


def cov_matrix(c) -> np.ndarray:
    """(…, 6) entries in COV_KEYS order -> (…, 3, 3) symmetric matrices."""
    c = np.asarray(c, float)
    out = np.empty((*c.shape[:-1], 3, 3))
    for k, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        out[..., i, j] = c[..., k]
        out[..., j, i] = c[..., k]
    return out


def cholesky_rows(c) -> np.ndarray:
    """(…, 6) covariances -> (…, 3, 3) L^T with L L^T = P (a singular P keeps its rank:
    eigen-decomposition with negative round-off clipped), so Var = |L^T d|²."""
    p = cov_matrix(c)
    w, v = np.linalg.eigh(p)
    w = np.clip(w, 0.0, None)
    return np.swapaxes(v * np.sqrt(w)[..., None, :], -1, -2)  # (V sqrt(W))^T


def derivatives(model, data, q, qd, qdd) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(τ, ∂τ/∂q, ∂τ/∂q̇, M) at one state: copies, safe to keep."""
    pin.computeRNEADerivatives(model, data, q, qd, qdd)
    return data.tau.copy(), data.dtau_dq.copy(), data.dtau_dv.copy(), data.M.copy()


def torque_variance(a: np.ndarray, b: np.ndarray, m: np.ndarray, cov) -> np.ndarray:
    """Var τ (n,) from the Jacobians (n, n) and the state covariance, (6,) shared by all
    joints or (n, 6) per joint, entries in COV_KEYS order (rad, rad/s, rad/s²)."""
    lt = cholesky_rows(cov)  # (3, 3) or (n, 3, 3)
    d = np.stack([a, b, m])  # (3, i, j)
    if lt.ndim == 2:
        y = np.tensordot(lt, d, axes=(1, 0))  # (3, i, j)
    else:
        y = np.einsum("jkl,lij->kij", lt, d)
    return np.einsum("kij,kij->i", y, y)


def lag_variance(a: np.ndarray, b: np.ndarray, m: np.ndarray, lag_per_jerk, jerk_rms: np.ndarray,
                 gain: float) -> np.ndarray:
    """σ_lag² (n,): Σ_j (gain G_ij s_j)², G = e0 A + e1 B + e2 C (see the module docstring)."""
    e = np.asarray(lag_per_jerk, float)
    g = e[0] * a + e[1] * b + e[2] * m
    g *= gain * np.asarray(jerk_rms, float)[None, :]
    return np.einsum("ij,ij->i", g, g)


class Propagator:
    """σ of τ for one model on the hot path, in two steps of different cost.

    `linearise(q, qd, qdd, cov, lag)` (~50 us loaded): computeRNEADerivatives at the state
    (τ included), the estimation part Var_est and the lag weights GG_ij = (gain G_ij)²;
    `__call__(..., jerk_ms, relinearise)` every sample: τ (RNEA, or the derivatives' when
    relinearising), σ_lag² = GG · jerk² (one product with the current jerk) and
    σ = sqrt(Var_est + σ_lag² + model part + floor). TorqueStd relinearises every
    RELINEARISE_S of stream time (and whenever the covariance or the lag vector changed):
    the Jacobians and the noise covariance move on the time scale of the movement, the
    jerk term is what changes fast, and it is current on every sample.

    `tau` (n,) holds the torques of the last call, `var_est`, `var_lag` the two variable
    parts (N·m²) and `std` the total σ (N·m) with the constant model part `model_var`
    (per DOF, N·m², model_term.py) added. All of them are overwritten by the next call.
    """

    def __init__(self, model, data, model_var: np.ndarray, gain: float):
        self.model, self.data = model, data
        n = model.nv
        self.model_var = np.asarray(model_var, float).reshape(n)
        self.gain = float(gain)
        self.tau = np.zeros(n)
        self.var_est = np.zeros(n)
        self.var_lag = np.zeros(n)
        self.var_subject = np.zeros(n)  # set by the caller before a linearise (subject.py)
        self.std = np.zeros(n)
        self._const = np.zeros(n)  # var_est + model part + floor, since the last linearise
        self._gg = np.zeros((n, n))
        self._d = np.zeros((3, n, n))
        self._y = np.zeros((4, n, n))  # rows: L^T d (3, the estimation part), gain e·d (lag)
        self._s = np.zeros((3, n))
        self._w = np.zeros((4, 3))
        self._w_key: tuple | None = None

    def _weights(self, cov: tuple[float, ...], lag) -> np.ndarray:
        """W (4, 3): L^T of the shared covariance over gain x the lag vector; rebuilt only when
        either changed (both are constant between the estimator's refreshes)."""
        key = (cov, None if lag is None else tuple(lag))
        if key != self._w_key:
            self._w[:3] = cholesky_rows(np.asarray(cov, float))
            self._w[3] = 0.0 if lag is None else self.gain * np.asarray(lag, float)
            self._w_key = key
        return self._w

    def linearise(self, q, qd, qdd, cov, lag_per_jerk) -> None:
        """Derivatives at the state, τ, Var_est and the lag weights. cov: (6,) tuple shared by
        the joints or (n, 6) array (COV_KEYS order); lag_per_jerk (3,) or None (no lag part).

        Shared covariance: ONE product W D of the stacked derivatives D = (A, B, M) gives
        both: rows 0-2 squared and summed over j are Var_est, row 3 squared is GG."""
        data = self.data
        pin.computeRNEADerivatives(self.model, data, q, qd, qdd)
        np.copyto(self.tau, data.tau)
        d = self._d
        np.copyto(d[0], data.dtau_dq)
        np.copyto(d[1], data.dtau_dv)
        np.copyto(d[2], data.M)
        if isinstance(cov, tuple):
            y = self._y
            np.dot(self._weights(cov, lag_per_jerk), d.reshape(3, -1), out=y.reshape(4, -1))
            np.multiply(y, y, out=y)
            np.sum(y[:3], axis=2, out=self._s)
            np.sum(self._s, axis=0, out=self.var_est)
            np.copyto(self._gg, y[3])
        else:
            yj = np.einsum("jkl,lij->kij", cholesky_rows(cov), d)  # per-joint factors
            np.einsum("kij,kij->i", yj, yj, out=self.var_est)
            if lag_per_jerk is None:
                self._gg.fill(0.0)
            else:
                e = np.asarray(lag_per_jerk, float)
                g = self.gain * (e[0] * d[0] + e[1] * d[1] + e[2] * d[2])
                np.multiply(g, g, out=self._gg)
        np.add(self.var_est, self.model_var, out=self._const)
        self._const += self.var_subject
        self._const += NUMERIC_FLOOR_VAR

    def __call__(self, q, qd, qdd, cov, lag_per_jerk, jerk_ms, relinearise: bool = True) -> np.ndarray:
        """σ (n,) at the state; jerk_ms (n,) the mean-square jerk of each joint ((rad/s³)²).
        relinearise False: τ by RNEA, Var_est and GG from the last linearise()."""
        if relinearise:
            self.linearise(q, qd, qdd, cov, lag_per_jerk)
        else:
            np.copyto(self.tau, pin.rnea(self.model, self.data, q, qd, qdd))
        np.dot(self._gg, jerk_ms, out=self.var_lag)
        s = self.std
        np.add(self._const, self.var_lag, out=s)
        np.sqrt(s, out=s)
        return s
