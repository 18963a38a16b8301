"""Whole-recording state estimation (ROS-free): q, q̇, q̈ of every sample at once.

Two methods, for offline work on a recording (bag_torques, check_bag without markers):

- `backward_batch`: the torque node's causal estimator (backward.py) over a whole series,
  vectorised. Same operations in the same order as BackwardDifference with its low-pass
  filters off (difference, then times 1/dt), same warm-up after each segment start, so
  offline torques equal the node's bit for bit. With a filter on, it runs the estimator
  sample by sample (same result, slower).
- `zero_phase`: the offline practice of biomechanics (and the paper): positions resampled
  to a uniform grid (median sample period), low-passed forward-backward (Butterworth,
  filtering.py, 6 Hz by default), velocity and acceleration as central differences
  of the filtered signal, brought back to the sample times. No lag; not causal.

Segments: a stamp step larger than `max_gap_ns` (or backwards) starts a new segment, as
the node resets its estimator there (stream_node.py stamp rules); `segments()` finds them.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from ..filtering import lowpass
from . import make_estimator


def segments(stamps_ns: np.ndarray, max_gap_ns: int) -> list[slice]:
    """Runs of samples whose stamps increase by at most max_gap_ns (at least one sample)."""
    d = np.diff(np.asarray(stamps_ns, np.int64))
    cuts = np.flatnonzero((d > max_gap_ns) | (d <= 0)) + 1
    bounds = [0, *cuts.tolist(), len(stamps_ns)]
    return [slice(a, b) for a, b in itertools.pairwise(bounds) if b > a]


def _diff(x: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """Backward difference as _Differentiator does it: (x[k] - x[k-1]) * (1.0 / dt)."""
    out = np.zeros_like(x)
    if len(x) > 1:
        dt = np.diff(stamps_ns).astype(np.float64) * 1e-9
        np.subtract(x[1:], x[:-1], out=out[1:])
        out[1:] *= (1.0 / dt)[:, None]
    return out


def backward_batch(stamps_ns: np.ndarray, q: np.ndarray, qd: np.ndarray | None,
                   settings: Mapping[str, float] | None = None,
                   max_gap_ns: int = 100_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qd, qdd, warm) of every sample, as the node's 'backward' estimator gives them.

    qd None: velocities are estimated from positions. warm (N,) bool: a real estimate.
    """
    stamps_ns = np.asarray(stamps_ns, np.int64)
    q = np.asarray(q, np.float64)
    settings = dict(settings or {})
    n, nv = q.shape
    qd_out = np.zeros((n, nv))
    qdd = np.zeros((n, nv))
    warm = np.zeros(n, bool)
    filtered = any(float(v) > 0.0 for v in settings.values())
    for seg in segments(stamps_ns, max_gap_ns):
        t = stamps_ns[seg]
        if filtered:
            est = make_estimator("backward", nv, settings)
            for k, i in enumerate(range(seg.start, seg.stop)):
                warm[i] = est.update(int(t[k]), q[i], None if qd is None else qd[i])
                qd_out[i], qdd[i] = est.qd, est.qdd
            continue
        if qd is not None:
            v = np.asarray(qd[seg], np.float64)
            qd_out[seg] = v
            qdd[seg] = _diff(v, t)
            warm[seg.start + 1:seg.stop] = True
        else:
            v = _diff(q[seg], t)
            qd_out[seg] = v
            a = _diff(v, t)
            a[:2] = 0.0  # the first difference of velocities needs two real velocities
            qdd[seg] = a
            warm[seg.start + 2:seg.stop] = True
    return qd_out, qdd, warm


def zero_phase(stamps_ns: np.ndarray, q: np.ndarray, cutoff_hz: float | None = None,
               max_gap_ns: int = 100_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, qd, qdd) filtered zero-phase at cutoff_hz (config/analysis.yaml by default),
    per segment; a segment of fewer than 3 samples keeps q and gets zero derivatives."""
    stamps_ns = np.asarray(stamps_ns, np.int64)
    q = np.asarray(q, np.float64)
    qf, qd, qdd = q.copy(), np.zeros_like(q), np.zeros_like(q)
    for seg in segments(stamps_ns, max_gap_ns):
        t = (stamps_ns[seg] - stamps_ns[seg.start]) * 1e-9
        if len(t) < 3:
            continue
        dt = float(np.median(np.diff(t)))
        grid = np.arange(0.0, t[-1] + 0.5 * dt, dt)
        if len(grid) < 3:
            continue
        x = q[seg]
        on_grid = np.column_stack([np.interp(grid, t, x[:, j]) for j in range(x.shape[1])])
        fs = 1.0 / dt
        f = lowpass(on_grid, fs, cutoff_hz)
        v = np.gradient(f, dt, axis=0)
        a = np.gradient(v, dt, axis=0)
        for out, src in ((qf, f), (qd, v), (qdd, a)):
            out[seg] = np.column_stack([np.interp(t, grid, src[:, j]) for j in range(src.shape[1])])
    return qf, qd, qdd
