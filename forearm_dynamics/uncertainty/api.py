"""Offline: torques and their σ from a stamped joint-angle series, as the node computes them.

    from forearm_dynamics.dynamics import build_model
    from forearm_dynamics.uncertainty import inverse_dynamics_with_std
    out = inverse_dynamics_with_std(build_model(), t, q)      # t (N,) s, q (N, 20) rad
    out.tau, out.std                                          # (N, 20) N·m each

The same estimator update() calls and the same TorqueStd as torque_node, one per sample (no
batch shortcut), so the numbers are the node's for the same input.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimation import make_estimator
from .torque_std import TorqueStd


@dataclass
class TorquesWithStd:
    t_ns: np.ndarray  # (N,) int64
    q: np.ndarray  # (N, n) estimates
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # (N, n) N·m
    std: np.ndarray  # (N, n) N·m, 1σ; NaN where not known (see `known`)
    var_est: np.ndarray  # (N, n) the parts, N·m²
    var_lag: np.ndarray
    var_model: np.ndarray  # (n,)
    var_subject: np.ndarray  # (N, n); 0 with subject "none"
    warm: np.ndarray  # (N,) bool: the estimator's state is warm
    known: np.ndarray  # (N,) bool: σ known (warm, and the noise measured): where torque_node
    # and bag_torques publish a finite σ (inf elsewhere)
    parts: dict


def inverse_dynamics_with_std(arm, t, q, qd=None, *, estimator: str = "kalman",
                              settings: dict | None = None, lag: bool = True, model: bool = True,
                              covariance: str = "noise", gain: float | None = None,
                              tau_s: float | None = None, t_in_ns: bool = False,
                              max_gap_s: float = 0.1, subject: str = "none",
                              subject_measured=()) -> TorquesWithStd:
    """τ and σ for samples at t (s, increasing; ns with t_in_ns) of positions q (N, n) in
    arm.joint_names order, velocities qd (N, n) or None. A stamp step over max_gap_s resets
    the estimator (its history, not its noise belief) as bag_torques and the node do.
    ValueError for an estimator without a covariance (NoCovariance), bad shapes or
    non-increasing stamps. subject "ansur" adds the spread of the segment parameters at the
    arm's stature and body mass (uncertainty/subject.py; subject_measured: the DIMS measured)."""
    q = np.ascontiguousarray(q, float)
    n = arm.nv
    if q.ndim != 2 or q.shape[1] != n:
        raise ValueError(f"q must be (N, {n}) in joint_names order; got {q.shape}")
    if qd is not None:
        qd = np.ascontiguousarray(qd, float)
        if qd.shape != q.shape:
            raise ValueError(f"qd must have q's shape {q.shape}; got {qd.shape}")
    t_ns = np.asarray(t, np.int64) if t_in_ns else np.round(np.asarray(t, float) * 1e9).astype(np.int64)
    if t_ns.shape != (len(q),):
        raise ValueError(f"t must be ({len(q)},); got {t_ns.shape}")
    est = make_estimator(estimator, n, settings)
    extra = {k: v for k, v in (("gain", gain), ("tau_s", tau_s)) if v is not None}
    ts = TorqueStd(arm, est, lag=lag, model=model, covariance=covariance, subject=subject,
                   subject_measured=subject_measured, **extra)
    N = len(q)
    out = {k: np.full((N, n), np.nan) for k in ("q", "qd", "qdd", "tau", "std", "var_est", "var_lag",
                                              "var_subject")}
    warm = np.zeros(N, bool)
    known = np.zeros(N, bool)
    vel = qd is not None
    gap = round(max_gap_s * 1e9)
    for k in range(N):
        if k and not 0 < t_ns[k] - t_ns[k - 1] <= gap:
            est.reset()
            ts.reset()
        warm[k] = est.update(int(t_ns[k]), q[k], qd[k] if vel else None)
        out["q"][k], out["qd"][k], out["qdd"][k] = est.q, est.qd, est.qdd
        out["tau"][k] = arm.inverse_dynamics(est.q, est.qd, est.qdd)  # the node's pin.rnea
        # ts.update on every sample (it keeps the jerk read current); as the node, no σ while
        # the state warms up
        if ts.update(int(t_ns[k]), vel) and warm[k]:
            known[k] = True
            out["std"][k] = ts.std
            out["var_est"][k], out["var_lag"][k] = ts.prop.var_est, ts.prop.var_lag
            out["var_subject"][k] = ts.prop.var_subject
    return TorquesWithStd(t_ns=t_ns, warm=warm, known=known, var_model=ts.model_var.copy(),
                          parts=ts.parts(), **out)
