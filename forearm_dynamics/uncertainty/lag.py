"""The lag part of the σ: how much jerk the movement has now, per joint.

A causal constant-acceleration estimate is biased by e·j under a sustained jerk j (e: the
estimator's error per unit jerk, state_source.lag_per_jerk); its covariance, computed for
a white-jerk model, does not contain that bias, so without this part the σ is
overconfident exactly when the torque changes fastest (benchmarks/uncertainty.py, rows
"no_lag"). The jerk is not measured. One-sample differences of the q̈ estimate are useless
for it (their noise, 500-1700 rad/s³ at 0.5 deg, is 10x the library's jerk); the change of
the q̈ estimate over one q̈ lag d is what the bias itself is made of:
    D = q̈(t) - q̈(t - m dt),  m dt ≈ d,   ĵ = D / (m dt),
its mean square exponentially averaged (time constant JERK_TAU_S), less what the noise
alone gives it (state_source.StateSource.delta_noise_var: 2 (Σ₂₂ - (Aᵐ Σ)₂₂) for the noise
covariance Σ and the filter's error dynamics A), scaled by LAG_GAIN. Both constants are
calibrated on the estimation benchmark's streams (benchmarks/uncertainty.py --gain --tau).
"""

from __future__ import annotations

import numpy as np

#: time constant (s) of the mean square of D, and the factor on the lag bias it implies
JERK_TAU_S = 0.03
LAG_GAIN = 1.0
MAX_BASELINE = 256  # samples of q̈ kept per joint (the baseline m is at most this)


class JerkTracker:
    """Per joint mean square of the jerk ((rad/s³)²) seen as the change of q̈ over m samples."""

    def __init__(self, n: int, tau_s: float = JERK_TAU_S):
        self.tau_s = float(tau_s)
        self.ms_jerk = np.zeros(n)
        self._ms = np.zeros(n)
        self._ring = np.zeros((MAX_BASELINE + 1, n))
        self._tmp = np.zeros(n)
        self._count = 0
        self._t_ns: int | None = None

    def reset(self) -> None:
        self._t_ns = None
        self._count = 0
        self._ms.fill(0.0)
        self.ms_jerk.fill(0.0)

    @property
    def rms(self) -> np.ndarray:
        return np.sqrt(self.ms_jerk)

    def update(self, t_ns: int, qdd: np.ndarray, m: int, noise_var: float) -> np.ndarray:
        """Mean-square jerk after the estimate q̈ at t_ns; m the baseline (samples), noise_var
        the mean square the noise alone gives D ((rad/s²)²)."""
        ring, c = self._ring, self._count
        np.copyto(ring[c % len(ring)], qdd)
        self._count = c + 1
        if self._t_ns is None or t_ns <= self._t_ns or c < m:
            if self._t_ns is None or t_ns <= self._t_ns:
                self._t_ns = t_ns
            return self.ms_jerk
        dt = (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        d = self._tmp
        np.subtract(qdd, ring[(c - m) % len(ring)], out=d)
        d *= d
        d -= self._ms
        d *= min(1.0, dt / self.tau_s)
        self._ms += d
        out = self.ms_jerk
        np.subtract(self._ms, noise_var, out=out)
        np.maximum(out, 0.0, out=out)
        out *= 1.0 / (m * dt) ** 2
        return out
