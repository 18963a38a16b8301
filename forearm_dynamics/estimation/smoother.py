"""Fixed-lag smoothing for the Kalman filter: the estimate of the sample `lags` samples back.

A controller that can wait gets better torques: the estimate of sample j once the L samples
after it are in is x_{j|j+L} = x_{j|j} + sum_{m=1..L} K_m e_{j+m} (e: the filter's
innovations, K_m: the lag gains of the converged filter, ca_model.lag_gains). The buffer
holds the L + 1 newest filtered states; each new innovation updates all of them at once
(one multiply-add over (L + 1) x 3 x n numbers: the gains are stored twice, reversed, so
that the slice aligned with the ring's head is contiguous), and the oldest slot, now with
all of its L innovations, is the output, stamped with its own sample's stamp.

Per-joint gains: each joint's gains come from its noise group (kalman.py). With jittered
stamps the gains of the nominal period are used (still unbiased: any gain on zero-mean
innovations is; slightly less smoothing than the exact time-varying gains).

Restart (a reset, a discontinuity): the samples still in the buffer are final as they are
(innovations after the restart belong to another trajectory); they are queued and
emitted one per new sample while the buffer refills, so no sample is lost and the output
stamps keep increasing. `drain()` empties what is left at the end of a recording.
Cost per sample: two (three with velocities) numpy operations over (L + 1) x 3 x n numbers,
plus the copy of the output (benchmarks/estimation.py states the microseconds).
"""

from __future__ import annotations

from collections import deque

import numpy as np


class FixedLagSmoother:
    """Buffer of filtered states and their lag updates; see the module docstring."""

    def __init__(self, n: int, lags: int):
        self.n = n
        self.lags = lags
        size = lags + 1
        self._S = np.zeros((size, 3, n))  # ring of states being smoothed
        self._T = [0] * size
        self._R: np.ndarray | None = None  # (2 size, 3, m, n) reversed, doubled gains
        self._tmp = np.zeros((size, 3, n))
        self._count = 0
        self._queue: deque[tuple[int, np.ndarray]] = deque()
        self.out = np.zeros((3, n))
        self.stamp_ns: int | None = None
        self.cov: np.ndarray | None = None  # (n, 3, 3) smoothed covariance per joint

    @property
    def configured(self) -> bool:
        return self._R is not None

    def set_gains(self, gains: np.ndarray, cov: np.ndarray) -> None:
        """gains (lags + 1, 3, m, n): K_m per joint (gains[0] = 0); cov (n, 3, 3)."""
        size = self.lags + 1
        idx = [(-i) % size for i in range(2 * size)]
        self._R = np.ascontiguousarray(gains[idx])
        self.cov = cov

    def restart(self) -> None:
        """Queue what the buffer holds (final as it is) and start a new window."""
        size = self.lags + 1
        c = self._count
        # samples pushed but not yet emitted: the newest min(c, lags) ones, oldest first
        for age in range(min(c, self.lags) - 1, -1, -1):
            slot = (c - 1 - age) % size
            self._queue.append((self._T[slot], self._S[slot].copy()))
        self._count = 0

    def take_over(self, old: FixedLagSmoother) -> None:
        """Start with what `old` (a smoother for another lag count: a new sample rate) still
        holds, queued as final, so no sample is lost at the change."""
        old.restart()
        self._queue.extend(old._queue)
        old._queue.clear()

    def push(self, t_ns: int, x: np.ndarray, e: np.ndarray) -> bool:
        """Filtered state x (3, n) of the sample at t_ns and its innovations e (m, n) (zero rows
        for the first sample); True if an output (self.out, self.stamp_ns) is ready."""
        size = self.lags + 1
        c = self._count
        p = c % size
        np.copyto(self._S[p], x)
        self._T[p] = t_ns
        if c:
            c0 = (-p) % size
            g = self._R[c0:c0 + size]
            tmp = self._tmp
            np.multiply(g[:, :, 0, :], e[0], out=tmp)
            if g.shape[2] == 2:
                self._S += tmp
                np.multiply(g[:, :, 1, :], e[1], out=tmp)
            self._S += tmp
        self._count = c + 1
        ready = c >= self.lags
        if self._queue:
            if ready:  # behind: the window's output waits its turn
                oldest = (p + 1) % size
                self._queue.append((self._T[oldest], self._S[oldest].copy()))
            t, s = self._queue.popleft()
            np.copyto(self.out, s)
            self.stamp_ns = t
            return True
        if not ready:
            self.stamp_ns = None
            return False
        oldest = (p + 1) % size
        np.copyto(self.out, self._S[oldest])
        self.stamp_ns = self._T[oldest]
        return True

    def add_to_previous(self, corr: np.ndarray) -> None:
        """A correction (3, n) restored late to the previous sample (the jump gate's)."""
        if self._count:
            self._S[(self._count - 1) % (self.lags + 1)] += corr

    def drain(self) -> list[tuple[int, np.ndarray]]:
        """Everything not yet emitted, oldest first (the end of a recording)."""
        self.restart()
        out = list(self._queue)
        self._queue.clear()
        return out
