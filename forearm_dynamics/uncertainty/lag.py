"""The lag part of the σ: how much jerk the movement has now, per joint.

A causal constant-acceleration estimate is biased by e·j under a sustained jerk j (e: the
estimator's error per unit jerk, state_source.lag_per_jerk); its covariance, computed for
a white-jerk model, does not contain that bias, so without this part the σ is
overconfident exactly when the torque changes fastest (benchmarks/uncertainty.py, rows
"no_lag"). The jerk is not measured. One-sample differences of the q̈ estimate are useless
for it (their noise, 500-1700 rad/s³ at 0.5 deg, is 10x the library's jerk); the change of
the q̈ estimate over one q̈ lag d is what the bias itself is made of:
    D = q̈(t_k) - q̈(t_(k-m)),  m dt ≈ d,   ĵ² = (D² - (1 + NOISE_MARGIN) nv) / T²,
T = t_k - t_(k-m) the time D spans, nv what the noise alone gives D²
(state_source.StateSource.delta_noise_var: nv = 2 (Σ₂₂ - (Aᵐ Σ)₂₂) for the noise covariance
Σ and the filter's error dynamics A); ĵ² exponentially averaged (time constant JERK_TAU_S),
its positive part, scaled by LAG_GAIN.

The margin (NOISE_MARGIN): D's noise part has the mean square nv, but D is correlated over
m samples (≈ the q̈ lag, 20-80 ms), about as long as the average, so its mean square
fluctuates as nv·χ²₁ (standard deviation √2·nv); subtracting only nv and keeping the
positive part read the fluctuation as jerk: on pure noise (no movement) the jerk read
74-94 rad/s³ at 90-100 Hz (1.5 / 0.5 deg, with a 30 ms average), more than the movements'
own RMS jerk (41-68), and the glove's band (no lag part needed: its error is its noise) came
out 1.3x too wide.
So what is counted is the excess over nv·(1 + NOISE_MARGIN): a χ²₁ fluctuation exceeds
2 nv half as often as nv (P = 0.16 against 0.32) and by about half as much on average
(0.26 nv against 0.48 nv); a real jerk loses one nv, its own noise level.

The constants were calibrated on benchmarks/uncertainty.py's inputs (the --every 8
movements; the other movements are the held-out check, --offset 4), on the estimator of
issue 16 (per-joint noise, groups, gate): JERK_TAU_S 0.06 and LAG_GAIN 1.2 (0.03 and 1.0
were tuned on the estimator before it, with no margin).
"""

from __future__ import annotations

import numpy as np

#: time constant (s) of the mean square of D, and the factor on the lag bias it implies
JERK_TAU_S = 0.06
LAG_GAIN = 1.2
#: the noise's mean square is subtracted from D's with this margin (in units of itself)
NOISE_MARGIN = 1.0
MAX_BASELINE = 256  # samples of q̈ kept per joint (the baseline m is at most this)


class JerkTracker:
    """Per joint mean square of the jerk ((rad/s³)²) seen as the change of q̈ over m samples.

    Each sample's read is (D² - (1 + NOISE_MARGIN) nv) / T², T the time D spans (its own
    stamps, not m x the last period: after a camera's 50-300 ms gap D spans the gap, and
    m x the period made the jerk read up to 10x too big there, the band 2x the error for
    0.3 s), exponentially averaged over tau_s; the result is its positive part."""

    def __init__(self, n: int, tau_s: float = JERK_TAU_S):
        self.tau_s = float(tau_s)
        self.ms_jerk = np.zeros(n)
        self._ms = np.zeros(n)  # the average of the reads (signed), (rad/s³)²
        self._ring = np.zeros((MAX_BASELINE + 1, n))
        self._stamps = np.zeros(MAX_BASELINE + 1, np.int64)
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

    def push(self, t_ns: int, qdd: np.ndarray) -> None:
        """Keep the q̈ estimate at t_ns (every sample: the baseline m counts samples)."""
        c = self._count
        if c and t_ns <= int(self._stamps[(c - 1) % len(self._ring)]):
            return  # not after the last one: the read would span no time
        np.copyto(self._ring[c % len(self._ring)], qdd)
        self._stamps[c % len(self._ring)] = t_ns
        self._count = c + 1

    def read(self, m: int, noise_var, scale2=None) -> np.ndarray:
        """Mean-square jerk after the last pushed sample, averaged since the last read; m the
        baseline (samples), noise_var the mean square the noise alone gives D ((rad/s²)²,
        scalar or (n,)); scale2 (n,) or None: a per-joint factor on the result
        (state_source.lag_scale2: each joint's own lag over the reference one's, squared).
        Read every sample or every few (TorqueStd: every EVALUATE_S): the average weighs
        each read by the time since the previous one."""
        c = self._count - 1  # the last pushed sample
        if c < 0:
            return self.ms_jerk
        ring, size = self._ring, len(self._ring)
        t_ns = int(self._stamps[c % size])
        if self._t_ns is None or t_ns <= self._t_ns or c < m:
            if self._t_ns is None or t_ns <= self._t_ns:
                self._t_ns = t_ns
            return self.ms_jerk
        dt = (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        span = (t_ns - int(self._stamps[(c - m) % size])) * 1e-9
        d, out = self._tmp, self.ms_jerk
        np.subtract(ring[c % size], ring[(c - m) % size], out=d)
        d *= d
        np.multiply(noise_var, 1.0 + NOISE_MARGIN, out=out)
        d -= out
        d *= 1.0 / (span * span)
        d -= self._ms
        d *= min(1.0, dt / self.tau_s)
        self._ms += d
        np.maximum(self._ms, 0.0, out=out)
        if scale2 is not None:
            out *= scale2
        return out

    def update(self, t_ns: int, qdd: np.ndarray, m: int, noise_var, scale2=None) -> np.ndarray:
        """push() and read() in one: the mean-square jerk after the estimate q̈ at t_ns."""
        self.push(t_ns, qdd)
        return self.read(m, noise_var, scale2)
