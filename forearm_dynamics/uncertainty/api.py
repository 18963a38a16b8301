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
from ..estimation.stamps import resets
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
                              max_gap_s: float = 0.0, subject: str = "none",
                              subject_measured=()) -> TorquesWithStd:
    """τ and σ for samples at t (s, increasing; ns with t_in_ns) of positions q (N, n) in
    arm.joint_names order, velocities qd (N, n) or None. The node's stamp rule (estimation/stamps.py;
    max_gap_s 0 = adaptive, the node's default) resets
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
    # the node's stamp rule (estimation/stamps.py) on the steps (times here may be <= 0)
    _keep, reset = resets(t_ns - t_ns[0] + 1 if N else t_ns, max_gap_s)
    row = {int(x): k for k, x in enumerate(t_ns)}
    for k in range(N):
        if reset[k]:
            est.reset()
            ts.reset()
        w = est.update(int(t_ns[k]), q[k], qd[k] if vel else None)
        if est.stamp_ns is None:  # a delay: this sample's estimate comes later
            continue
        i = row[est.stamp_ns]  # with a delay, the row of the sample it estimates
        warm[i] = w
        out["q"][i], out["qd"][i], out["qdd"][i] = est.q, est.qd, est.qdd
        out["tau"][i] = arm.inverse_dynamics(est.q, est.qd, est.qdd)  # the node's pin.rnea
        # ts.update after every output, as the node; no σ while the state warms up
        if ts.update(est.stamp_ns, vel) and w:
            known[i] = True
            out["std"][i] = ts.std
            out["var_est"][i], out["var_lag"][i] = ts.prop.var_est, ts.prop.var_lag
            out["var_subject"][i] = ts.prop.var_subject
    for stamp, x in est.drain():  # the last delay_s: estimates the node outputs later
        i = row[stamp]
        warm[i] = True
        out["q"][i], out["qd"][i], out["qdd"][i] = x
        out["tau"][i] = arm.inverse_dynamics(x[0], x[1], x[2])
    return TorquesWithStd(t_ns=t_ns, warm=warm, known=known, var_model=ts.model_var.copy(),
                          parts=ts.parts(), **out)
