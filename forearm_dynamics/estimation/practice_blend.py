"""The blend of the model's q̈ and the practice filter's, per joint, weighted by what the data say.

Why (issue 29). The practice filter (practice_fir.py) was designed on raw recordings of real
arm movements, whose q̈ in the practice's band is mostly noise the practice averages: it
shrinks and smooths. On a fast movement with little noise (the library's 0.5 s movements
through a simulated mocap sensor: elbow q̈ RMS 14 rad/s² against ~0.5 of noise) the model's
q̈, less late, is the better estimate, against the practice as against the truth. Which one
is right is a property of the joint's movement and sensor, so it is measured: per joint, the
least-squares weight of the model's estimate in the blend against the practice itself,
    out = f + beta (k - f),   beta = clip(E[(y - f)(k - f)] / E[(k - f)^2], 0, 1),
y the practice's q̈ of a sample, k and f the two causal estimates made for it.

How. The practice's q̈ of the sample D = REF_DELAY_S back is a finite kernel on the D s of
samples either side of it (practice_kernels: the zero-phase filter's impulse response
differentiated as the practice does, truncated to +-D, its moments restored: exact on
cubics); the two estimates made for that sample wait in a ring (PracticeWindow). Every
EVERY_S, per joint, exponentially weighted sums (time constant TAU_S) of the products give
beta, pulled towards PRIOR_BETA (the filter alone) with the weight of PRIOR_S of evaluations
against those the average holds (at most TAU_S of them: a lasting pull of PRIOR_S / (TAU_S +
PRIOR_S), 14 %; the library's elbow through the simulated mocap noise settles at 0.86).
`error_variance()` is the blended estimate's error variance for the σ
(uncertainty/state_source.py): measured against the practice, and following the movement.

Tuning-half numbers, costs and the alternatives tried: docs/estimation.md ("The practice
filter").
"""

from __future__ import annotations

import functools

import numpy as np

from ..filtering import lowpass  # scipy.signal: imported with the estimator, not in a callback

#: the practice's kernel half-width (s): the estimates are judged this late
REF_DELAY_S = 0.2
#: an evaluation every EVERY_S, exponentially weighted over TAU_S
EVERY_S = 0.01
TAU_S = 3.0
#: before the data: the practice filter alone (beta 0), worth PRIOR_S of evaluations
PRIOR_BETA = 0.0
PRIOR_S = 0.5
#: the time constant (s) of the two estimates' disagreement, the σ's measure of the movement
DISAGREE_S = 0.1
#: the share of the long-run measured error in the σ's q̈ variance (error_variance)
LONG_SHARE = 0.3
#: before the data, the blend's error variance over the disagreement (error_variance)
PRIOR_RATIO = 1.0


def practice_kernels(dt: float, cutoff_hz: float, half_s: float) -> np.ndarray:
    """A read-only copy of the cached kernels (_kernels: built once per rate and process)."""
    return _kernels(round(dt, 12), cutoff_hz, half_s)


@functools.lru_cache(maxsize=16)
def _kernels(dt: float, cutoff_hz: float, half_s: float) -> np.ndarray:
    """(k1, k2): weights over 2 h + 1 samples (oldest first, h = round(half_s / dt)) that
    give the practice's q̇ and q̈ at the middle sample: the response of the zero-phase
    filter (filtering.lowpass: forward-backward Butterworth) to an impulse, differentiated
    as estimation/offline.zero_phase does (np.gradient twice), truncated to +-h."""
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
    estimates made for that same sample."""

    def __init__(self, n: int, kernels: np.ndarray, every: int):
        self.k = kernels  # (p, 2h + 1) or (2h + 1,), oldest sample first
        self.h = h = (kernels.shape[-1] - 1) // 2
        self.every = every
        self._q = np.zeros((2 * (2 * h + 1), n))
        self._x = np.zeros((h + 1, 2, n))
        self.ref = np.zeros(kernels.shape[:-1] + (n,))  # the practice of the sample h back
        self._c = np.zeros(1, np.int64)  # samples pushed since the last restart

    @property
    def count(self) -> int:
        return int(self._c[0])

    def restart(self) -> None:
        """No kernel spans this point (a gap, a restarted filter)."""
        self._c[0] = 0

    def push(self, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """The sample's positions and two causal estimates for it. Every `every` samples once
        the window is full: the (2, n) estimates stored for the sample h back, whose practice
        is then in `ref`; else None."""
        h = self.h
        c = int(self._c[0])
        w = 2 * h + 1
        j = c % w
        self._q[j] = q  # twice: the window is always one contiguous slice
        self._q[j + w] = q
        xs = self._x[c % (h + 1)]
        xs[0] = a
        xs[1] = b
        self._c[0] = c = c + 1
        if c < w or c % self.every:
            return None
        start = c % w  # the window's oldest sample
        np.dot(self.k, self._q[start:start + w], out=self.ref)
        return self._x[c % (h + 1)]


class PracticeBlend:
    """Per joint, beta: the model's weight in the blend of two causal q̈ estimates; see above."""

    def __init__(self, n: int, cutoff_hz: float):
        self.n = n
        self.cutoff_hz = cutoff_hz
        self.beta = np.full(n, PRIOR_BETA)
        self.share = 1.0 - self.beta  # the practice filter's weight, 1 - beta
        self._s = np.zeros((6, n))  # E[kk], E[kf], E[ff], E[yk], E[yf], E[yy]
        self.disagreement = np.zeros(n)  # mean square of (k - f) over the last DISAGREE_S
        self._d = np.zeros(n)
        self._t = np.zeros((6, n))
        self._win: PracticeWindow | None = None
        self._dt = 0.0
        self._c = np.zeros(1, np.int64)  # evaluations in the sums
        self._alpha = 1.0
        self._prior_evals = 1.0
        self._fast = 1.0

    def configure(self, dt: float) -> None:
        """Kernel and ring for sample period dt (kept while the period stays within 25 %)."""
        if self._dt and abs(dt - self._dt) <= 0.25 * self._dt:
            return
        every = max(1, round(EVERY_S / dt))
        self._win = PracticeWindow(self.n, practice_kernels(dt, self.cutoff_hz, REF_DELAY_S)[2], every)
        self._dt = dt
        self._alpha = min(1.0, every * dt / TAU_S)
        self._prior_evals = PRIOR_S / (every * dt)
        self._fast = min(1.0, dt / DISAGREE_S)

    def restart(self) -> None:
        """No kernel spans this point (a reset, a discontinuity); the sums stay."""
        if self._win is not None:
            self._win.restart()

    def add(self, q: np.ndarray, k: np.ndarray, f: np.ndarray) -> None:
        """The sample's positions and the two q̈ estimates made for it (model, filter)."""
        if self._win is None:
            return
        d = self._d
        np.subtract(k, f, out=d)
        d *= d
        d -= self.disagreement
        d *= self._fast
        self.disagreement += d
        x = self._win.push(q, k, f)
        if x is None:
            return
        y = self._win.ref
        self._c[0] += 1
        evals = int(self._c[0])
        t = self._t
        kx, fx = x
        np.multiply(kx, kx, out=t[0])
        np.multiply(kx, fx, out=t[1])
        np.multiply(fx, fx, out=t[2])
        np.multiply(y, kx, out=t[3])
        np.multiply(y, fx, out=t[4])
        np.multiply(y, y, out=t[5])
        t -= self._s
        t *= max(self._alpha, 1.0 / evals)
        self._s += t

    @property
    def evaluations(self) -> int:
        """Evaluations against the practice in the sums (they never restart)."""
        return int(self._c[0])

    def update(self) -> np.ndarray:
        """beta (n,) from the sums so far (asked at the filter's noise updates, not per sample)."""
        evals = self.evaluations
        if evals:
            kk, kf, ff, yk, yf, _ = self._s
            dd = kk - 2.0 * kf + ff
            b = np.divide(yk - yf - kf + ff, dd, out=np.full(self.n, PRIOR_BETA), where=dd > 0.0)
            np.clip(b, 0.0, 1.0, out=b)
            m = min(evals, 1.0 / self._alpha)  # the average's own weight, at most TAU_S
            w = m / (m + self._prior_evals)
            np.multiply(b, w, out=self.beta)
            self.beta += (1.0 - w) * PRIOR_BETA
            np.subtract(1.0, self.beta, out=self.share)
        return self.beta

    def residual(self) -> np.ndarray:
        """(n,) mean square of (practice - blend) for the beta in use, as measured ((rad/s²)²)."""
        kk, kf, ff, yk, yf, yy = self._s
        b = self.beta
        c = 1.0 - b
        r = yy - 2.0 * (b * yk + c * yf) + b * b * kk + 2.0 * b * c * kf + c * c * ff
        return np.maximum(r, 0.0)

    def error_variance(self) -> np.ndarray:
        """(n,) the blend's q̈ error variance now ((rad/s²)²), for the σ: LONG_SHARE of it
        the blend's error against the practice as measured over TAU_S (residual), the rest
        that error's ratio to the two estimates' disagreement over TAU_S times the recent
        disagreement (DISAGREE_S: large while the movement is fast, small at rest), so that
        the σ follows the movement. Before the data (PRIOR_S of weight) the disagreement
        stands for the error (ratio 1).

        Why both: with the tracking part alone the σ was right on average (RMS(σ)/RMSE
        1.01-1.18 on the real corpus's tuning half) but the error's tails outran it (wrist
        flexion 0.90 inside ±1.96σ); with LONG_SHARE 0.3: 0.95-0.98 inside, 1.08-1.24 RMS,
        and 0.904 on the simulated sensors' 9 movements (test_uncertainty). /tmp sweeps of
        LONG_SHARE 0-0.5 and DISAGREE_S 0.1-0.2 s on the tuning half only."""
        kk, kf, ff = self._s[:3]
        dd = kk - 2.0 * kf + ff
        res = self.residual()
        ratio = np.divide(res, dd, out=np.ones(self.n), where=dd > 0.0)
        m = self.evaluations
        w = m / (m + self._prior_evals) if m else 0.0
        ratio *= w
        ratio += (1.0 - w) * PRIOR_RATIO
        out = ratio * self.disagreement
        out *= 1.0 - LONG_SHARE
        res *= w
        res += (1.0 - w) * PRIOR_RATIO * self.disagreement
        res *= LONG_SHARE
        out += res
        return out
