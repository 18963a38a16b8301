"""The estimation part of the torque σ: the covariance of (q, q̇, q̈) through the linearised RNEA.

τ = RNEA(q, q̇, q̈), so a small state error (δq, δq̇, δq̈) moves the torque by
    δτ = ∂τ/∂q δq + ∂τ/∂q̇ δq̇ + M δq̈
(Pinocchio's computeRNEADerivatives: A = dtau_dq, B = dtau_dv, C = M, symmetric). The
estimators treat joints independently, so with P_j the 3x3 covariance of joint j's
(q, q̇, q̈),
    Var τ_i = Σ_j d_ij^T P_j d_ij,   d_ij = (A_ij, B_ij, C_ij).
computeRNEADerivatives also leaves τ in data.tau (checked in the tests). torque_node does
not use it: it publishes the torques (pin.rnea) first and computes their σ after, so the
torques never wait for the σ (benchmarks/uncertainty_cost.py measures both).

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

from ..estimation.ca_model import transition

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


def extrapolated(cov, lag_per_jerk, h: float) -> tuple[np.ndarray, np.ndarray | None]:
    """(covariance, lag per unit jerk) of an estimate extrapolated h >= 0 s ahead at
    constant acceleration (estimation.base.StateEstimator.predict). Its error moves with
    the CA transition F(h): Σ_h = F Σ Fᵀ per joint (cov (6,) or (n, 6), COV_KEYS order);
    and under a sustained jerk j the truth leaves the extrapolation by g(h) j, g(h) =
    (h³/6, h²/2, h), so the error per unit jerk e becomes e_h = F e - g(h) (None stays None)."""
    f = transition(h)
    p = f @ cov_matrix(cov) @ f.T
    cov_h = p[..., [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    if lag_per_jerk is None:
        return cov_h, None
    return cov_h, f @ np.asarray(lag_per_jerk, float) - np.array([h**3 / 6.0, h * h / 2.0, h])


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


#: the products D_a ∘ D_b (elementwise) of the stacked derivatives D = (A, B, M), in COV_KEYS
#: order, and how often each enters a quadratic form dᵀ P d (the off-diagonal entries twice)
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_TWICE = np.array([1.0, 2.0, 2.0, 1.0, 2.0, 1.0])


def quadratic_weights(e) -> np.ndarray:
    """(6,) weights w with Σ_k w_k (D_a ∘ D_b)_k = (e0 A + e1 B + e2 M)∘²: the square of a
    fixed combination of the derivatives (the lag's G) from the same six products."""
    e = np.asarray(e, float)
    return _TWICE * np.array([e[a] * e[b] for a, b in _PAIRS])


class Propagator:
    """σ of τ for one model on the hot path, in two steps of different cost.

    Both parts of the variance are quadratic forms of the derivatives d_ij = (A_ij, B_ij, M_ij),
    so both are sums over the six elementwise products D_a ∘ D_b (A∘A, A∘B, ..., M∘M):
        Var_est,i = Σ_k Σ_j (D_a ∘ D_b)_k,ij  c_k,j     c_k,j: entry k of P_j (off-diagonal x2)
        σ_lag,i²  = Σ_k w_k Σ_j (D_a ∘ D_b)_k,ij s_j²   w = quadratic_weights(gain e)
    `linearise(q, qd, qdd, cov, lag)`: computeRNEADerivatives at the state (τ included: `tau`)
    and the six products (one pass), then Var_est (one matrix-vector product); `__call__(...,
    jerk_ms, relinearise)` every sample: σ_lag² from the cached products and the current
    jerk (two matrix-vector products) and σ = sqrt(Var_est + σ_lag² + model part + floor).
    No per-joint loop and no factorisation: a new covariance or lag vector costs one product
    on the cached derivatives, which is what a prediction over a horizon needs
    (TorqueStd.predict). TorqueStd evaluates (relinearise and jerk) every EVALUATE_S of
    stream time: the Jacobians and the noise covariance move on the time scale of the
    movement, the jerk term is averaged over 60 ms.

    `var_est`, `var_lag` hold the two variable parts (N·m²) of the last call and `std` the
    total σ (N·m) with the constant model part `model_var` (per DOF, N·m², model_term.py)
    added; `tau` the torques of the last linearisation. All are overwritten by the next call.
    A covariance or lag object is taken as immutable: its weights are cached by identity.
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
        self._pp = np.zeros((n, 6, n))  # [i, k, j]: product k of the derivatives at (i, j)
        self._pp_i = self._pp.reshape(n, 6 * n)  # views for the two contractions
        self._pp_ik = self._pp.reshape(n * 6, n)
        self._lag_ik = np.zeros(n * 6)
        self._c = np.zeros((6, n))  # covariance weights c_k,j
        self._c_of: object = None  # the covariance they were made from
        self._w = np.zeros(6)  # lag weights
        self._w_of: object = None
        self._has_lag = False

    def _cov_weights(self, cov) -> np.ndarray:
        if cov is not self._c_of:
            c = np.asarray(cov, float)
            if c.ndim == 1:  # shared by every joint
                self._c[:] = (c * _TWICE)[:, None]
            else:
                np.multiply(c.T, _TWICE[:, None], out=self._c)
            self._c_of = cov
        return self._c

    def _lag_weights(self, lag) -> None:
        if lag is not self._w_of:
            self._has_lag = lag is not None
            self._w[:] = 0.0 if lag is None else quadratic_weights(self.gain * np.asarray(lag, float))
            self._w_of = lag

    def linearise(self, q, qd, qdd, cov, lag_per_jerk) -> None:
        """Derivatives at the state, τ, their products and Var_est. cov: (6,) shared by the
        joints or (n, 6) per joint (COV_KEYS order); lag_per_jerk (3,) or None (no lag part)."""
        data = self.data
        pin.computeRNEADerivatives(self.model, data, q, qd, qdd)
        np.copyto(self.tau, data.tau)
        d = (data.dtau_dq, data.dtau_dv, data.M)
        pp = self._pp
        for k, (a, b) in enumerate(_PAIRS):
            np.multiply(d[a], d[b], out=pp[:, k, :])
        self.reweigh(cov, lag_per_jerk)

    def reweigh(self, cov, lag_per_jerk) -> None:
        """Var_est and the lag weights for another covariance / lag vector at the derivatives
        of the last linearise() (a prediction over a horizon: same state, moved covariance)."""
        np.dot(self._pp_i, self._cov_weights(cov).reshape(-1), out=self.var_est)
        np.maximum(self.var_est, 0.0, out=self.var_est)  # a PSD form: round-off only
        np.add(self.var_est, self.model_var, out=self._const)
        self._const += self.var_subject
        self._const += NUMERIC_FLOOR_VAR
        self._lag_weights(lag_per_jerk)

    def __call__(self, q, qd, qdd, cov, lag_per_jerk, jerk_ms, relinearise: bool = True) -> np.ndarray:
        """σ (n,) at the state; jerk_ms (n,) the mean-square jerk of each joint ((rad/s³)²).
        relinearise False: the derivatives and Var_est of the last linearise()."""
        if relinearise:
            self.linearise(q, qd, qdd, cov, lag_per_jerk)
        s = self.std
        if self._has_lag:
            np.dot(self._pp_ik, jerk_ms, out=self._lag_ik)
            np.dot(self._lag_ik.reshape(-1, 6), self._w, out=self.var_lag)
            np.add(self._const, self.var_lag, out=s)
        else:
            self.var_lag.fill(0.0)
            np.copyto(s, self._const)
        np.sqrt(s, out=s)
        return s
