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
known only as its recent RMS s_j (lag.JerkTracker), the lag part of the variance is
    σ_lag,i² = k² Σ_j (G_ij s_j)²,
k the calibration factor (lag.LAG_GAIN, from benchmarks/uncertainty.py).

All arrays are preallocated per propagator; one call allocates nothing but its temporaries
of numpy's own (a few (3, n, n) products).
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
    """σ of τ for one model on the hot path: computeRNEADerivatives (τ included) and the
    variance of the estimation, lag and model parts, into preallocated arrays.

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
        self.std = np.zeros(n)
        self._d = np.zeros((3, n, n))
        self._y = np.zeros((3, n, n))
        self._g = np.zeros((n, n))
        self._cov_key: tuple | None = None
        self._lt = np.eye(3)

    def _shared_factor(self, cov: tuple[float, ...]) -> np.ndarray:
        """L^T of a shared covariance, recomputed only when it changed (a steady filter's
        covariance is constant between re-seats)."""
        if cov != self._cov_key:
            self._lt = cholesky_rows(np.asarray(cov, float))
            self._cov_key = cov
        return self._lt

    def __call__(self, q, qd, qdd, cov, lag_per_jerk, jerk_rms) -> np.ndarray:
        """σ (n,) at the state (q, qd, qdd); cov: (6,) tuple shared by the joints or (n, 6)
        array; lag_per_jerk (3,) or None (no lag part); jerk_rms (n,)."""
        data = self.data
        pin.computeRNEADerivatives(self.model, data, q, qd, qdd)
        np.copyto(self.tau, data.tau)
        d = self._d
        np.copyto(d[0], data.dtau_dq)
        np.copyto(d[1], data.dtau_dv)
        np.copyto(d[2], data.M)
        if isinstance(cov, tuple):
            y = self._y
            np.dot(self._shared_factor(cov), d.reshape(3, -1), out=y.reshape(3, -1))
            np.einsum("kij,kij->i", y, y, out=self.var_est)
        else:
            y = np.einsum("jkl,lij->kij", cholesky_rows(cov), d)  # per-joint factors
            np.einsum("kij,kij->i", y, y, out=self.var_est)
        if lag_per_jerk is None:
            self.var_lag.fill(0.0)
        else:
            g = self._g
            e0, e1, e2 = lag_per_jerk
            np.multiply(d[0], e0, out=g)
            g += e1 * d[1]
            g += e2 * d[2]
            g *= jerk_rms
            g *= self.gain
            np.einsum("ij,ij->i", g, g, out=self.var_lag)
        s = self.std
        np.add(self.var_est, self.var_lag, out=s)
        s += self.model_var
        s += NUMERIC_FLOOR_VAR
        np.sqrt(s, out=s)
        return s
