"""The delayed estimate as the offline practice would give it, from what the delay makes available.

Why (issue 29). With estimator.delay_s = d the estimate of the sample at t is output once
the samples up to t + d are in. The offline practice that real recordings are judged
against (6 Hz zero-phase Butterworth + derivatives; offline/realscore.py) is a fixed linear
kernel over the samples around t: practice_p(t) = sum_m k_p[m] q(t + m dt), m = -h .. h
(p = 0, 1, 2: q, q̇, q̈; practice_blend.practice_kernels: the filter's impulse response
differentiated, exact on cubics). The model's fixed-lag smoother (smoother.py) is the best
estimate of the *truth* under the white-jerk model with white noise; against the practice
it is wrong wherever the model's noise and jerk beliefs keep content the 6 Hz band removes
(a joint whose 10 Hz band level is coloured: IK, soft tissue, marker jitter), and more lag
then makes it worse, not better: on the real corpus's tuning half 48 of 226 series were
worse at 0.1 s than at 0.05 s, 67 at 0.2 s than at 0.1 s (benchmarks/real_corpus.py).

What. p, the conditional expectation of the practice given the data up to t + d: the
kernel's taps on the samples that are in (m <= L, the smoother's lag count) take the
samples as they are (the practice smooths them itself: nothing above its band is passed),
and the taps on the samples still to come (m > L) take the filter's prediction of them from
its newest state x(t + d) (constant acceleration, q + q̇ τ + q̈ τ²/2, τ past the newest
sample): one (3, 3) matrix per rate and lag. More lag replaces predicted samples by
measured ones, so p approaches the practice monotonically; from L >= h on it is the
practice (to the kernel's truncation at ±HALF_S: 0.2 s left 6 tuning series worse at
0.2 s than at 0.1 s, its tail matters).

The output is s + alpha (p - s), s the model's smoothed estimate, alpha per (q, q̇, q̈)
and joint the least-squares weight of p against the practice itself, measured online: once
the ring holds 2 h + 1 samples, the practice of the sample h back is known exactly (the full
kernel), and the two estimates made for that sample are kept until then; every EVERY_S,
exponentially weighted over TAU_S, alpha = clip(E[(ref - s)(p - s)] / E[(p - s)²], 0, 1),
pulled towards PRIOR (p alone) with the weight of PRIOR_EVALS evaluations. Where the
future taps carry much noise no estimate can know (a 1.5 deg glove at 0.05 s), alpha < 1;
on the real recordings it stays near 1.

Where the model's smoother is kept (KalmanCA._practice_lag_joints): with velocities given
(an encoder: no practice is defined on that channel, the model with a measured velocity
is better); per joint on exact or held input (white level <= EXACT_WHITE x the floor:
smoothing exact input to 6 Hz would be an error against the truth) and until the first
white-level estimate; and per joint where the noise is white (band level <= 1.5 x the
white level; once used, down to KEEP_RATIO: no flicker) and the model already filters
narrower than the practice's band, (psd / (r² dt))^(1/6) < 2 pi band: such a joint passes
nothing the practice removes, and against the truth the model, right for white noise, is
the better estimate (glove 90 Hz, sensor zoo: thumb/fingers 0.0101 / 0.0058 with p
blended, 0.0091 / 0.0053 with the model's smoother). A joint leaves only once the rule
has said so for 1 s (noise_belief.HOLD_UPDATES): the running elbow of the tuning half left
the practice mid-swing without it. Samples the jump gate holds back enter
as the filter's prediction; one found genuine at the next step is restored.

Numbers (tuning half only; /tmp drivers over benchmarks.corpus and the benchmark's
scoring, then benchmarks/real_corpus.py --halves tuning): median ratio of torque NRMSE to
the causal 6 Hz Butterworth against the practice, model's smoother -> this: 0.476 -> 0.318
at 0.05 s, 0.415 -> 0.115 at 0.1 s, 0.413 -> 0.037 at 0.2 s; series worse with more lag
48 / 67 -> 0 / 0.
Cost: one kernel product over the h + L + 1 newest samples per output (h = HALF_S / dt;
100 Hz: 56 x n numbers), and every EVERY_S one over 2 h + 1 for the blend.
"""

from __future__ import annotations

import numpy as np

from .practice_blend import practice_kernels

#: half width (s) of the practice's kernel: 0.5 s keeps its tail (0.2 s did not: above)
HALF_S = 0.5
#: the blend's evaluations: every EVERY_S, exponentially weighted over TAU_S, pulled towards
#: PRIOR (the practice's estimate alone) with the weight of PRIOR_EVALS evaluations
EVERY_S = 0.05
TAU_S = 6.0
PRIOR = 1.0
PRIOR_EVALS = 10.0
#: shortest delay (s) with the blend: below it most of the kernel's taps are predictions; on
#: the real corpus's tuning half the blend still helps there (median ratio to the causal
#: Butterworth 0.91 -> 0.86 at 0.01 s, 0.79 -> 0.73 at 0.025 s), but against the truth of
#: the simulated mocap IK 100 Hz sensor it cost 1-2.5 % (estimation_zoo's delay curve), and
#: the zoo's committed rows are kept: the model's smoother alone below 0.04 s
MIN_DELAY_S = 0.04
#: band level / white level down to which a joint that uses the practice keeps it (entry:
#: noise_belief.COLOURED_RATIO): a ratio near the threshold does not switch every 0.25 s
KEEP_RATIO = 1.2


class PracticeLag:
    """Ring of the newest positions and the practice's kernels for one (period, lag count)."""

    def __init__(self, n: int, cutoff_hz: float, half_s: float | None = None):
        self.n = n
        self.cutoff_hz = cutoff_hz
        self.half_s = half_s or HALF_S
        self.key: tuple[float, int] | None = None
        self.count = 0
        self.out = np.zeros((3, n))
        self.alpha = np.full((3, n), PRIOR)  # weight of the practice's estimate, per (q, q̇, q̈) and joint
        self._sxy = np.zeros((3, n))
        self._sxx = np.zeros((3, n))
        self._evals = 0
        self._tmp = np.zeros((3, n))
        self._ref = np.zeros((3, n))

    def configure(self, dt: float, lags: int) -> None:
        """Kernels for period dt and `lags` samples of delay (once per rate: a repeated call
        with the same lag count and a period within 5 % keeps the kernels and the ring)."""
        if self.key is not None and lags == self.key[1] and abs(dt - self.key[0]) <= 0.05 * dt:
            return  # the nominal period moved a little (jittered stamps): same kernels, same ring
        k = practice_kernels(dt, self.cutoff_hz, self.half_s)[:3]  # q, q̇, q̈ over [-h, h]
        h = (k.shape[1] - 1) // 2
        lr = min(lags, h)
        self._K = np.ascontiguousarray(k)
        self._W = np.ascontiguousarray(k[:, :h + lr + 1])  # taps on the samples that are in
        c = np.zeros((3, 3))
        for m in range(lr + 1, h + 1):  # taps on the samples still to come: the prediction
            tau = (m - lags) * dt
            c += np.outer(k[:, m + h], (1.0, tau, 0.5 * tau * tau))
        self._C = c
        self._h, self._lags = h, lags
        self._need = h + lags + 1  # samples in before the first estimate
        self._w = max(2 * h + 1, self._need)  # ring: also the full kernel of the sample h back
        self._q = np.zeros((2 * self._w, self.n))  # twice: any window is one contiguous slice
        self._t = [0] * self._w
        self._r = max(1, h - lags + 1)  # estimates kept until the practice of their sample is known
        self._ps = np.zeros((self._r, 2, 3, self.n))
        self._every = max(1, round(EVERY_S / dt))
        self._a = min(1.0, self._every * dt / TAU_S)
        self.key = (dt, lags)
        self.count = 0

    def restart(self) -> None:
        """No kernel spans this point (a reset, a discontinuity); the blend stays."""
        self.count = 0

    def push(self, t_ns: int, q: np.ndarray) -> None:
        """The newest sample (positions, the gate's prediction for a held joint)."""
        if self.key is None:
            return
        j = self.count % self._w
        self._q[j] = q
        self._q[j + self._w] = q
        self._t[j] = t_ns
        self.count += 1

    def restore_last(self, genuine: np.ndarray, q: np.ndarray) -> None:
        """The gate found the last sample genuine on these joints: its positions back in."""
        if self.key is None or not self.count:
            return
        j = (self.count - 1) % self._w
        self._q[j, genuine] = q[genuine]
        self._q[j + self._w, genuine] = q[genuine]

    def estimate(self, x_newest: np.ndarray, smoothed: np.ndarray) -> int | None:
        """The delayed estimate of the sample `lags` back into self.out: the model's
        `smoothed` (3, n) moved towards the practice's by alpha; x_newest: the filter's
        state at the newest sample (3, n). Returns its stamp, or None while the ring does
        not yet hold the kernel's past (h samples before it)."""
        c = self.count
        if self.key is None or c < self._need:
            return None
        h, w = self._h, self._w
        start = (c - self._need) % w  # the window's oldest sample
        p = self.out
        np.dot(self._W, self._q[start:start + self._W.shape[1]], out=p)
        np.dot(self._C, x_newest, out=self._tmp)
        p += self._tmp
        stamp = self._t[(start + h) % w]
        if self._lags < h:
            slot = self._ps[(c - 1 - self._lags) % self._r]
            slot[0] = p
            slot[1] = smoothed
            if c >= 2 * h + 1 and not c % self._every:
                self._learn(c)
            # out = s + alpha (p - s)
            p -= smoothed
            p *= self.alpha
            p += smoothed
        return stamp

    def _learn(self, c: int) -> None:
        """The practice of the sample h back, exact (the full kernel over the ring), against
        the two estimates made for it: per (q, q̇, q̈) and joint, the least-squares weight of
        the practice's estimate, E[(ref - s)(p - s)] / E[(p - s)^2], clipped to [0, 1]."""
        h, w = self._h, self._w
        start = (c - (2 * h + 1)) % w
        np.dot(self._K, self._q[start:start + 2 * h + 1], out=self._ref)
        p, s = self._ps[(c - 1 - h) % self._r]
        d = p - s
        y = self._ref - s
        self._evals += 1
        a = max(self._a, 1.0 / self._evals)
        y *= d
        y -= self._sxy
        y *= a
        self._sxy += y
        d *= d
        d -= self._sxx
        d *= a
        self._sxx += d
        m = min(self._evals, 1.0 / self._a)
        np.divide(self._sxy, np.maximum(self._sxx, 1e-300), out=self.alpha)
        np.clip(self.alpha, 0.0, 1.0, out=self.alpha)
        self.alpha *= m / (m + PRIOR_EVALS)
        self.alpha += PRIOR * PRIOR_EVALS / (m + PRIOR_EVALS)
