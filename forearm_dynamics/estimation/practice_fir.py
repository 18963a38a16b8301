"""The practice filter: a causal estimate of the offline practice's q̈, a fixed kernel on positions.

Why (issue 29). A real recording is judged against the offline practice (6 Hz zero-phase
Butterworth + derivatives, offline/realscore.py); what that band removes is error for the
torque, white or coloured, movement or artefact. The white-jerk Kalman estimates the truth
under white noise: on raw recordings of real arm movements, whose content above the band is
coloured (soft tissue, marker jitter, the movement's own sharp stops), it passed what the
practice removes and was worse than the causal 6 Hz Butterworth on most series (real corpus,
held-out: median 1.10 x). Nearly all of a torque's error there is q̈'s (tuning half, /tmp
study: torque NRMSE with only q̈ estimated 0.109, only q 0.016, only q̇ 0.004).

What. The best causal estimate of a fixed non-causal filter of the data (the practice) is a
causal filter of the data; this one was designed on the real corpus's tuning half
(benchmarks/practice_fir_design.py) so that its q̈ error against the practice is below the
causal Butterworth's on every series at once (a soft minimax). Per joint,
    q̈(t) = Σ_k w_k (x(t - k dt) - x(t)),   k = 1 .. T_S / dt,
w_k the continuous-time kernel g (cubic B-splines on (0, T_S], data/practice_fir.json)
integrated against sample k's hat function (the filter acts on the
samples joined by straight lines: the same filter at every rate), corrected by the smallest
change along the ramp that makes q̈ of a constant velocity 0.
Differences to the newest sample: a constant gives 0, whatever its value. Its response (100
Hz): about 0.65 x the practice's q̈ across the band, some 35 ms late (the Butterworth's:
1 x, ~47 ms): a causal estimate of what the practice will say once the future is in is
smaller than the movement's own q̈ where the recording's in-band content is mostly what the
practice averages away. Where it is not (a fast movement with little noise) the model's q̈
is the better one: practice_blend.py weighs the two per joint.

Samples go into a ring as they come, taken on the stream's nominal period (jittered stamps
are taken as on the grid; a sample that arrives 1.5 nominal periods or more after the last
has the missed ones filled in on the straight line between the two). A restart (reset, a
discontinuity) starts the ring again; the filter is used once it holds the kernel's span.

Cost: one (K,) @ (K, n) product per sample (100 Hz: K = 25) and a ring row; in a filter,
one compiled call with the blend and the output (practice_step.py; this is its reference).
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
from scipy.interpolate import BSpline  # with the estimator, not in a node's callback

DATA = Path(__file__).resolve().parents[1] / "data" / "practice_fir.json"
#: the kernels' span (s) and B-spline knot spacing (s)
T_S = 0.25
KNOT_S = 0.00625


def taps_count(dt: float) -> int:
    """K: the number of past samples (k = 1 .. K) the kernel spans at period dt (K dt >= T_S)."""
    return max(1, math.ceil(T_S / dt - 1e-9))


def knots() -> np.ndarray:
    n = round(T_S / KNOT_S)
    inner = np.linspace(0.0, T_S, n + 1)
    return np.r_[[0.0] * 3, inner, [T_S] * 3]


def basis(tau: np.ndarray) -> np.ndarray:
    """(len(tau), nb): the cubic B-splines on (0, T_S], the last one (non-zero at T_S) dropped;
    zero outside (0, T_S)."""
    tau = np.asarray(tau, float)
    inside = (tau >= 0.0) & (tau <= T_S)
    out = np.zeros((len(tau), len(knots()) - 4))
    if inside.any():
        out[inside] = BSpline.design_matrix(tau[inside], knots(), 3).toarray()
    return out[:, :-1]


def differences(x: np.ndarray, K: int) -> np.ndarray:
    """(N, K): x[t - k] - x[t], k = 1 .. K, the samples before the first taken as the first."""
    from numpy.lib.stride_tricks import sliding_window_view

    x = np.asarray(x, float)
    w = sliding_window_view(np.r_[np.full(K, x[0]), x], K + 1)[:, ::-1]
    return w[:, 1:] - w[:, :1]


@functools.lru_cache(maxsize=32)
def tap_map(dt: float) -> np.ndarray:
    """M (K, nb): the taps at period dt are M @ theta, theta the kernel's B-spline
    coefficients. Tap k is the kernel integrated against the straight line between the
    samples, w_k = ∫ g(τ) φ_k(τ) dτ, φ_k the hat function of sample k (the filter acts on
    the samples joined by straight lines), so one kernel is the same filter at any rate: a
    kernel sampled at k dt instead was, at 30 Hz and at 1 kHz, two different filters (q̈ of
    a parabola -0.6 and 2.6 x, against 0.7 x at the 100 Hz it was fitted at). Then the
    smallest change along the ramp that makes q̈ of a constant velocity exactly 0."""
    K = taps_count(dt)
    sub = max(8, math.ceil(8 * dt / KNOT_S))  # quadrature points per sample interval
    tau = (np.arange(K * sub) + 0.5) * (dt / sub)  # midpoints over (0, K dt]
    B = basis(tau) * (dt / sub)  # (P, nb): g at the points times their width
    x = tau / dt
    hats = np.clip(1.0 - np.abs(x[None, :] - np.arange(1, K + 1)[:, None]), 0.0, None)  # (K, P)
    M = hats @ B
    a = -np.arange(1, K + 1) * dt  # taps @ a = the estimate for x(t - s) - x(t) = -s (a unit ramp)
    M = (np.eye(K) - np.outer(a, a) / (a @ a)) @ M
    M.setflags(write=False)
    return M


@functools.lru_cache(maxsize=1)
def load() -> np.ndarray:
    """The committed kernel's B-spline coefficients (data/practice_fir.json)."""
    with open(DATA, encoding="utf-8") as fh:
        return np.asarray(json.load(fh)["kernel"], float)


@functools.lru_cache(maxsize=32)
def kernel_taps(dt: float) -> np.ndarray:
    """(K,): the q̈ taps at period dt (read-only; k = 1 .. K, newest first)."""
    w = tap_map(dt) @ load()
    w.setflags(write=False)
    return w


class PracticeFIR:
    """A ring of the newest positions and the kernel's taps for the stream's nominal period."""

    def __init__(self, n: int):
        self.n = n
        self.dt = 0.0
        self.K = 0
        self._c = np.zeros(2, np.int64)  # [samples put in the ring, the newest's stamp (ns)]
        self.out = np.zeros(n)
        self._w = np.zeros(1)
        self._sum = 0.0
        self._ring = np.zeros((2, n))
        self._last = np.zeros(n)
        self._tmp = np.zeros(n)

    @property
    def count(self) -> int:
        """Samples put in the ring since the last restart (the dropped ones filled in count)."""
        return int(self._c[0])

    def configure(self, dt: float) -> None:
        """Kernels and ring for nominal period dt (kept while the period stays within 5 %)."""
        if self.K and abs(dt - self.dt) <= 0.05 * self.dt:
            return
        self.dt = dt
        self.K = K = taps_count(dt)
        w = kernel_taps(round(dt, 12))
        # newest first in w; the ring's window is oldest first: reversed
        self._w = np.ascontiguousarray(w[::-1])
        self._sum = float(self._w.sum())
        self._ring = np.zeros((2 * (K + 1), self.n))
        self._c[0] = 0

    @property
    def ready(self) -> bool:
        """The ring holds the kernel's whole span."""
        return self.K > 0 and self.count > self.K

    def restart(self) -> None:
        """No kernel spans this point (a reset, a discontinuity)."""
        self._c[0] = 0

    def _put(self, q: np.ndarray) -> None:
        w = self.K + 1
        j = self._c[0] % w
        self._ring[j] = q
        self._ring[j + w] = q
        self._c[0] += 1

    def push(self, t_ns: int, q: np.ndarray) -> None:
        """The newest sample (positions; the gate's prediction for a held joint)."""
        if not self.K:
            return
        if self._c[0]:
            gap = (t_ns - int(self._c[1])) * 1e-9 / self.dt
            missed = min(round(gap) - 1, self.K + 1)
            for i in range(1, missed + 1):  # dropped samples: on the line between the two
                self._put(self._last + (q - self._last) * (i / (missed + 1)))
        self._put(q)
        np.copyto(self._last, q)
        self._c[1] = t_ns

    def restore_last(self, genuine: np.ndarray, q: np.ndarray) -> None:
        """The gate found the last sample genuine on these joints: its positions back in."""
        if not self.count:
            return
        w = self.K + 1
        j = (self.count - 1) % w
        self._ring[j, genuine] = q[genuine]
        self._ring[j + w, genuine] = q[genuine]
        self._last[genuine] = q[genuine]

    def estimate(self) -> np.ndarray:
        """(n,) q̈ at the newest sample into self.out (call when ready)."""
        w = self.K + 1
        start = self.count % w  # the oldest of the window
        win = self._ring[start:start + w]
        out = self.out
        np.dot(self._w, win[:-1], out=out)
        np.multiply(win[-1], self._sum, out=self._tmp)
        out -= self._tmp
        return out
