"""Per-joint calibration of the causal derivatives against the offline practice, online.

Opt-in (KalmanCA's estimator.practice_band_hz, 0 by default; measured with 6 Hz and
kalman_min_bandwidth_hz 0): on the real corpus's held-out half it beats the default
(benchmarks/real_corpus.json, docs/estimation.md), but the σ is not yet calibrated with it
on the simulated sensors and the simulated sensor zoo is worse with it.

Why (issue 29). On raw recordings of real arm movements the torques are judged against the
offline practice: 6 Hz zero-phase Butterworth + derivatives. Whatever that band removes
is error for the torque, white or coloured, signal or artefact; and what it keeps in its
top octave (3-6 Hz) is, on a raw marker recording, mostly the recording's own jitter,
which no causal estimate can predict. A causal q̈ that follows it is wrong twice (its own
lag, and content the practice has not yet averaged); the estimate that is right on
average is a *shrunk* one: the least-squares regression of the practice's q̈ on the causal
q̈, x_out = g x, g = E[x_ref x] / E[x²]. That coefficient is a property of the joint's
movement and of its sensor (how much of its q̈ is predictable: a slow reach with marker
noise ~0.2-0.5, an exact input 1), not a constant: it is measured per joint from the data.

How. The practice's own q̇ and q̈ of the sample D = REF_DELAY_S back are computed from the
D s of samples on either side of it (a finite kernel: the derivative of the practice's
impulse response at the stream's period, truncated to +-D, exact to ~1e-3 for a 6 Hz
4th-order forward-backward filter at D = 0.2 s); the causal estimate the filter gave for
that sample is kept in a ring. Every EVERY_S, per joint, exponentially weighted sums of
x_ref x and x² (time constant TAU_S) give g = clip(Sxy / Sxx, 0, 1). Until MIN_S of
evaluations, g = 1 (no calibration yet: the filter's own estimate).

Cost. Per sample: two row copies into rings; every EVERY_S one kernel product over
(2 D / dt + 1) x n numbers per derivative (a few us). The kernels are built once per rate
(`configure`; the filter calls it at its first step and when the rate changes).
Joints with no noise (held, exact input) are left at g = 1 by the filter.
"""

from __future__ import annotations

import functools

import numpy as np

REF_DELAY_S = 0.2
TAU_S = 6.0
EVERY_S = 0.01
MIN_S = 0.2
GAIN_MAX = 1.0
PRIOR_GAIN = 0.5
PRIOR_EVALS = 50.0


def practice_kernels(dt: float, cutoff_hz: float, half_s: float) -> np.ndarray:
    """A read-only copy of the cached kernels (_kernels: built once per rate and process)."""
    return _kernels(round(dt, 12), cutoff_hz, half_s)


@functools.lru_cache(maxsize=16)
def _kernels(dt: float, cutoff_hz: float, half_s: float) -> np.ndarray:
    """(k1, k2): weights over 2 h + 1 samples (oldest first, h = round(half_s / dt)) that
    give the practice's q̇ and q̈ at the middle sample: the response of the zero-phase
    filter (filtering.lowpass: forward-backward Butterworth) to an impulse, differentiated
    as estimation/offline.zero_phase does (np.gradient twice), truncated to +-h."""
    from ..filtering import lowpass

    h = max(2, round(half_s / dt))
    fs = 1.0 / dt
    if not 0.0 < cutoff_hz < 0.5 * fs:
        cutoff_hz = 0.45 * fs
    m = 8 * h + 1
    imp = np.zeros(m)
    imp[m // 2] = 1.0
    y = lowpass(imp[:, None], fs, cutoff_hz)[:, 0]
    d1 = np.gradient(y, dt)
    d2 = np.gradient(d1, dt)
    d3 = np.gradient(d2, dt)
    c = m // 2
    # the value at the middle from input sample (c - k): response at lag k; oldest sample
    # first -> reversed
    k = np.stack([x[c - h:c + h + 1][::-1] for x in (y, d1, d2, d3)])
    # the truncation leaks (the filter rings past +-h): restore the moments of the untruncated
    # kernels, exact on cubics (value, slope, curvature, jerk), with the smallest correction
    # weighted by a Hann window (smooth, central)
    t = np.arange(-h, h + 1) * dt
    v = np.stack([t**p for p in range(4)], axis=1)  # (2h + 1, 4)
    win = np.hanning(2 * h + 3)[1:-1]
    target = np.diag([1.0, 1.0, 2.0, 6.0])  # kernel p on t^j: d^p t^j / dt^p at 0
    a = v.T @ (win[:, None] * v)
    for p in range(4):
        k[p] += win * (v @ np.linalg.solve(a, target[p] - v.T @ k[p]))
    k.setflags(write=False)
    return k


class PracticeWindow:
    """The raw positions of the last 2h + 1 samples and two causal estimates of each of the
    last h + 1: the practice of the sample h back (kernels on the window) beside the causal
    estimates made for that same sample. One ring for both judges of the causal estimate
    against the practice: the practice gain (below) and the selector (selector.py)."""

    def __init__(self, n: int, kernels: np.ndarray, every: int):
        self.k = kernels  # (p, 2h + 1) or (2h + 1,), oldest sample first
        self.h = h = (kernels.shape[-1] - 1) // 2
        self.every = every
        self._q = np.zeros((2 * (2 * h + 1), n))
        self._x = np.zeros((h + 1, 2, n))
        self.ref = np.zeros(kernels.shape[:-1] + (n,))  # the practice of the sample h back
        self.count = 0

    def restart(self) -> None:
        """No kernel spans this point (a gap, a restarted filter)."""
        self.count = 0

    def push(self, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """The sample's positions and two causal estimates for it. Every `every` samples once
        the window is full: the (2, n) estimates stored for the sample h back, whose practice
        is then in `ref`; else None."""
        h = self.h
        c = self.count
        w = 2 * h + 1
        j = c % w
        self._q[j] = q  # twice: the window is always one contiguous slice
        self._q[j + w] = q
        xs = self._x[c % (h + 1)]
        xs[0] = a
        xs[1] = b
        self.count = c = c + 1
        if c < w or c % self.every:
            return None
        start = c % w  # the window's oldest sample
        np.dot(self.k, self._q[start:start + w], out=self.ref)
        return self._x[c % (h + 1)]


class PracticeGain:
    """Per-joint regression gains of the practice's (q̇, q̈) on the causal ones; see above."""

    def __init__(self, n: int, cutoff_hz: float):
        self.n = n
        self.cutoff_hz = cutoff_hz
        self.gain = np.ones((2, n))  # applied to (qd, qdd)
        self._sxy = np.zeros((2, n))
        self._sxx = np.zeros((2, n))
        self._syy = np.zeros((2, n))  # mean square of the practice's (qd, qdd)
        self._t4 = np.zeros((4, n))
        self.ms_jerk = np.zeros(n)  # mean square of the practice's jerk ((rad/s^3)^2)
        self._win: PracticeWindow | None = None
        self._dt = 0.0
        self._evals = 0
        self._every = 1
        self._min = 1

    def configure(self, dt: float) -> None:
        """Kernels and rings for sample period dt (built once per rate, not per sample)."""
        if self._dt and abs(dt - self._dt) <= 0.25 * self._dt:
            return
        self._every = max(1, round(EVERY_S / dt))
        # the practice's (q, qd, qdd, jerk) kernels, (4, 2h + 1)
        self._win = PracticeWindow(self.n, practice_kernels(dt, self.cutoff_hz, REF_DELAY_S),
                                   self._every)
        self._dt = dt
        self._min = max(1, round(MIN_S / (self._every * dt)))
        self._alpha = min(1.0, self._every * dt / TAU_S)

    def restart(self) -> None:
        """No kernel spans this point (a gap, a restarted filter); the gains stay."""
        if self._win is not None:
            self._win.restart()

    def add(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        """The sample's positions and the filter's causal (qd, qdd) for it."""
        if self._win is None:
            return
        x = self._win.push(q, qd, qdd)  # the causal estimate of the sample h back
        if x is None:
            return
        ref = self._win.ref  # the practice's (q, qd, qdd, jerk) there
        self._evals += 1
        a = max(self._alpha, 1.0 / self._evals)
        t = self._t4
        np.multiply(ref[3], ref[3], out=t[3])
        np.multiply(ref[1:3], x, out=t[:2])
        t[:2] -= self._sxy
        t[3] -= self.ms_jerk
        t *= a
        self._sxy += t[:2]
        self.ms_jerk += t[3]
        np.multiply(x, x, out=t[:2])
        t[:2] -= self._sxx
        t[:2] *= a
        self._sxx += t[:2]
        np.multiply(ref[1:3], ref[1:3], out=t[:2])
        t[:2] -= self._syy
        t[:2] *= a
        self._syy += t[:2]

    @property
    def ready(self) -> bool:
        return self._evals >= self._min

    def update_gain(self) -> np.ndarray:
        """The gains from the sums so far (the filter asks at its noise updates, every
        0.25 s: not per sample): clip(Sxy / Sxx, 0, 1) blended with PRIOR_GAIN, weight
        PRIOR_EVALS evaluations against the ones averaged; 1 before MIN_S."""
        if self._evals >= self._min:
            np.divide(self._sxy, np.maximum(self._sxx, 1e-300), out=self.gain)
            if PRIOR_EVALS:
                m = min(self._evals, 1.0 / self._alpha)
                self.gain *= m / (m + PRIOR_EVALS)
                self.gain += PRIOR_GAIN * PRIOR_EVALS / (m + PRIOR_EVALS)
            np.clip(self.gain, 0.0, GAIN_MAX, out=self.gain)
        return self.gain

    def residual(self, gain: np.ndarray) -> np.ndarray:
        """(2, n) mean square of (practice - gain x) for (qd, qdd): the scaled estimate's
        error against the practice as measured (noise, lag and what the shrink leaves), for
        the σ (uncertainty/state_source.py)."""
        return np.maximum(self._syy - 2.0 * gain * self._sxy + gain * gain * self._sxx, 0.0)

    def jerk_psd(self) -> np.ndarray:
        """Per joint white-jerk spectral density (rad^2/s^5) with the practice's jerk power
        over its band: mean square / (2 band)."""
        return self.ms_jerk / (2.0 * self.cutoff_hz)
