"""Joint velocity and acceleration from consecutive stamped samples, without allocation.

Choice: a first-order backward finite difference over the two latest header stamps,
optionally followed by a first-order low-pass (exponential smoothing with the real dt).
It is causal, needs one previous sample, and is exact for a constant acceleration (the
usual case between 1 kHz samples of a smooth movement).

    qdd_raw[k] = (qd[k] - qd[k-1]) / (t[k] - t[k-1])
    qdd[k]     = qdd[k-1] + a * (qdd_raw[k] - qdd[k-1]),  a = dt / (tau + dt),
                 tau = 1 / (2 pi accel_cutoff_hz)   (no filter when the cutoff is 0)

When the input has no velocity, qd is estimated the same way from positions (its own
optional low-pass, velocity_cutoff_hz) and qdd is the difference of that estimate.

Lag (time delay at low frequency, dt = sample period):
    qdd from given velocities:  dt/2 + tau_a            (0.5 ms at 1 kHz, filter off)
    qd  from positions:         dt/2 + tau_v
    qdd from positions:         dt + tau_v + tau_a       (1 ms at 1 kHz, filters off)
A first-order low-pass at fc adds tau = 1/(2 pi fc): 1.6 ms at 100 Hz, 8 ms at 20 Hz.

Warm-up: after the first sample (or a reset) there is no history; qdd = 0 (and qd = 0 when
it must be estimated) until enough samples exist: 2 samples for qdd with given velocities,
3 when velocities come from positions. `warm` says whether the output is a real estimate.
A filter starts from its first raw value, so there is no ramp from zero.

Reset: the caller calls reset() when the stamps jump by more than its max_stamp_gap (the
source paused, a bag looped, a publisher restarted): a difference across such a gap would
be meaningless, so the estimator warms up again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EstimatorConfig:
    """Estimator settings (see the module docstring for their effect on lag)."""

    accel_cutoff_hz: float = 0.0  # 0 = no low-pass on qdd
    velocity_cutoff_hz: float = 0.0  # 0 = no low-pass on qd estimated from positions

    def tau(self, cutoff_hz: float) -> float:
        return 0.0 if cutoff_hz <= 0.0 else 1.0 / (2.0 * math.pi * cutoff_hz)

    def lag(self, dt: float, velocity_given: bool = True) -> float:
        """Low-frequency delay (s) of the qdd estimate at sample period dt."""
        ta, tv = self.tau(self.accel_cutoff_hz), self.tau(self.velocity_cutoff_hz)
        return dt / 2 + ta if velocity_given else dt + tv + ta

    def as_dict(self) -> dict:
        return {
            "method": "backward_difference+lowpass1",
            "accel_cutoff_hz": self.accel_cutoff_hz,
            "velocity_cutoff_hz": self.velocity_cutoff_hz,
            "lag_at_1khz_s": self.lag(1e-3),
            "lag_at_1khz_from_positions_s": self.lag(1e-3, velocity_given=False),
        }


class _Differentiator:
    """Backward difference + optional first-order low-pass, in place on (n,) buffers."""

    def __init__(self, n: int, tau: float):
        self.tau = tau
        self.out = np.zeros(n)
        self._prev = np.zeros(n)
        self._raw = np.zeros(n)
        self.has_prev = False  # a previous input sample exists
        self.valid = False  # `out` holds an estimate

    def reset(self) -> None:
        self.has_prev = False
        self.valid = False
        self.out.fill(0.0)

    def update(self, x: np.ndarray, dt: float) -> None:
        """Feed sample x taken dt s after the previous one (dt ignored for the first)."""
        if self.has_prev:
            if self.valid and self.tau > 0.0:
                np.subtract(x, self._prev, out=self._raw)
                self._raw *= 1.0 / dt
                a = dt / (self.tau + dt)
                self._raw -= self.out
                self._raw *= a
                self.out += self._raw
            else:  # no filter (or its first value): the difference straight into out
                np.subtract(x, self._prev, out=self.out)
                self.out *= 1.0 / dt
            self.valid = True
        np.copyto(self._prev, x)
        self.has_prev = True


class DerivativeEstimator:
    """qd (when not given) and qdd from stamped samples; see the module docstring."""

    def __init__(self, n: int, config: EstimatorConfig):
        self.config = config
        self._vel = _Differentiator(n, config.tau(config.velocity_cutoff_hz))
        self._acc = _Differentiator(n, config.tau(config.accel_cutoff_hz))
        self._t_ns: int | None = None

    def reset(self) -> None:
        self._vel.reset()
        self._acc.reset()
        self._t_ns = None

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray, velocity_given: bool) -> bool:
        """Advance to the sample at t_ns; fill qd (if not given) and return warm.

        The caller guarantees t_ns is later than the previous sample (or calls reset()).
        qd is read when velocity_given, else written with the estimate. qdd is `self.qdd`.
        """
        dt = 0.0 if self._t_ns is None else (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        if velocity_given:
            if self._vel.has_prev:
                self._vel.reset()
        else:
            self._vel.update(q, dt)
            np.copyto(qd, self._vel.out)
            if not self._vel.valid:
                # No velocity yet: keep the acceleration history empty too.
                self._acc.reset()
                return False
        self._acc.update(qd, dt)
        return self._acc.valid

    @property
    def qdd(self) -> np.ndarray:
        return self._acc.out
