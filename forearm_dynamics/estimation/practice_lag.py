"""The delayed estimate as the offline practice would give it, from what the delay makes available.

Why (issue 29). With estimator.delay_s = d the estimate of the sample at t is output once
the samples up to t + d are in. The offline practice that real recordings are judged
against (6 Hz zero-phase Butterworth + derivatives; offline/realscore.py) is a fixed linear
kernel over the samples around t: practice_p(t) = sum_m k_p[m] q(t + m dt), m = -h .. h
(p = 0, 1, 2: q, q̇, q̈; practice_gain.practice_kernels, the filter's impulse response
differentiated, exact on cubics). The model's fixed-lag smoother (smoother.py) is the best
estimate of the *truth* under the white-jerk model; against the practice it is wrong
wherever the model's noise and jerk beliefs keep content that the 6 Hz band removes, and
more lag then makes it worse, not better: on the real corpus's tuning half (UE-ADL
reaching/drinking at 100 Hz, running arm swing at 60 Hz) 48 of 226 series were worse at
0.1 s than at 0.05 s, and 67 at 0.2 s than at 0.1 s (benchmarks/real_corpus.py).

What. The conditional expectation of the practice given the data up to t + d: the kernel's
taps on the samples that are in (m <= L = the smoother's lag count) take the samples as
they are (the practice smooths them itself: nothing above its band is passed), and the
taps on the samples still to come (m > L) take the filter's prediction of them from its
newest state x(t + d) (constant acceleration: q + q̇ τ + q̈ τ²/2, τ the time past the
newest sample). The second part is one (3, 3) matrix per rate and lag, so the estimate is
one kernel product over the (h + L + 1) newest samples plus a 3 x 3 product per joint.
More lag replaces predicted samples by measured ones, so the estimate approaches the
practice monotonically, and from L >= h on it is the practice itself (to the kernel's
truncation at ±HALF_S). Tuning half, the model's smoother / this, median ratio of torque
NRMSE to the causal 6 Hz Butterworth against the practice: 0.48 / 0.31 at 0.05 s, 0.42 /
0.12 at 0.1 s, 0.41 / 0.04 at 0.2 s; series worse with more lag: 48, 67 / 0, 0 (a /tmp
prototype of this module, the benchmark's recordings and scoring; HALF_S 0.2 s left 6
series worse at 0.2 s than at 0.1 s: the kernel's tail beyond 0.2 s matters).

Where it is not used (KalmanCA keeps the model's smoother): with velocities given (an
encoder: the model with a measured velocity is the better estimate of the truth, and no
practice is defined on the velocity channel), and per joint on exact or held input (white
level <= EXACT_WHITE x the floor, noise_belief.py: smoothing an exact signal to 6 Hz would
be an error against the truth, the trajectory_publisher's pipeline check) and until the
first white-level estimate says which joints those are. Samples the jump gate holds back
enter as the filter's prediction (a spike is not smeared over the kernel); a held sample
found genuine at the next step is restored.
"""

from __future__ import annotations

import numpy as np

from .practice_gain import practice_kernels

#: half width (s) of the practice's kernel: 0.5 s keeps its tail (0.2 s did not: above)
HALF_S = 0.5


class PracticeLag:
    """Ring of the newest positions and the practice's kernels for one (period, lag count)."""

    def __init__(self, n: int, cutoff_hz: float, half_s: float = HALF_S):
        self.n = n
        self.cutoff_hz = cutoff_hz
        self.half_s = half_s
        self.key: tuple[float, int] | None = None
        self._W = np.zeros((3, 1))
        self._C = np.zeros((3, 3))
        self._q = np.zeros((2, n))
        self._t = [0]
        self._w = 1  # ring size: h + lags + 1
        self._h = 0
        self.count = 0
        self.out = np.zeros((3, n))
        self._tmp = np.zeros((3, n))

    def configure(self, dt: float, lags: int) -> None:
        """Kernels for period dt and `lags` samples of delay (once per rate: a repeated call
        with the same lag count and a period within 5 % keeps the kernels and the ring)."""
        if self.key is not None and lags == self.key[1] and abs(dt - self.key[0]) <= 0.05 * dt:
            return  # the nominal period moved a little (jittered stamps): same kernels, same ring
        key = (dt, lags)
        k = practice_kernels(dt, self.cutoff_hz, self.half_s)[:3]  # q, q̇, q̈ over [-h, h]
        h = (k.shape[1] - 1) // 2
        lr = min(lags, h)
        self._W = np.ascontiguousarray(k[:, :h + lr + 1])  # taps on the samples that are in
        c = np.zeros((3, 3))
        for m in range(lr + 1, h + 1):  # taps on the samples still to come: the prediction
            tau = (m - lags) * dt
            c += np.outer(k[:, m + h], (1.0, tau, 0.5 * tau * tau))
        self._C = c
        self._h, self._w = h, h + lags + 1
        self._q = np.zeros((2 * self._w, self.n))  # twice: the window is one contiguous slice
        self._t = [0] * self._w
        self.key = key
        self.count = 0

    def restart(self) -> None:
        """No kernel spans this point (a reset, a discontinuity, a new rate)."""
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

    def estimate(self, x_newest: np.ndarray) -> int | None:
        """The practice's (q, q̇, q̈) of the sample `lags` back into self.out, given the
        filter's state at the newest sample (3, n); its stamp, or None while the ring does
        not yet hold the kernel's past (h samples before it)."""
        c = self.count
        if self.key is None or c < self._w:
            return None
        start = c % self._w  # the oldest sample of the ring
        np.dot(self._W, self._q[start:start + self._W.shape[1]], out=self.out)
        np.dot(self._C, x_newest, out=self._tmp)
        self.out += self._tmp
        return self._t[(start + self._h) % self._w]
