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

import numpy as np

from .base import SettingSpec, StateEstimator


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


class BackwardDifference(StateEstimator):
    """qd (when not given) and qdd by backward differences; see the module docstring."""

    name = "backward"
    settings = (
        SettingSpec("accel_cutoff_hz", 0.0, "Hz", "first-order low-pass on the acceleration; 0 = off"),
        SettingSpec("velocity_cutoff_hz", 0.0, "Hz",
                    "first-order low-pass on velocities estimated from positions; 0 = off"),
    )

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        self._vel = _Differentiator(n, _tau(self.values["velocity_cutoff_hz"]))
        self._acc = _Differentiator(n, _tau(self.values["accel_cutoff_hz"]))

    def reset(self) -> None:
        self._vel.reset()
        self._acc.reset()
        self._t_ns = None

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        self.check(t_ns, q, qd)
        dt = 0.0 if self._t_ns is None else (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        np.copyto(self.q, q)
        if qd is not None:
            np.copyto(self.qd, qd)
            if self._vel.has_prev:
                self._vel.reset()
            return differences(None, self._vel, self._acc, self.qd, self.qdd, dt)
        return differences(q, self._vel, self._acc, self.qd, self.qdd, dt)

    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        ta = _tau(self.values["accel_cutoff_hz"])
        tv = _tau(self.values["velocity_cutoff_hz"])
        if velocity_given:
            return {"q": 0.0, "qd": 0.0, "qdd": dt / 2 + ta}
        return {"q": 0.0, "qd": dt / 2 + tv, "qdd": dt + tv + ta}


def differences(q: np.ndarray | None, vel: _Differentiator, acc: _Differentiator,
                qd: np.ndarray, qdd: np.ndarray, dt: float) -> bool:
    """qd from positions q (None: qd is given and already in `qd`), then qdd from qd, by
    backward differences over dt (shared by the backward and Butterworth estimators);
    returns warm. Without a velocity yet, the acceleration history stays empty too."""
    if q is not None:
        vel.update(q, dt)
        np.copyto(qd, vel.out)
        if not vel.valid:
            acc.reset()
            qdd.fill(0.0)
            return False
    acc.update(qd, dt)
    np.copyto(qdd, acc.out)
    return acc.valid


def _tau(cutoff_hz: float) -> float:
    return 0.0 if cutoff_hz <= 0.0 else 1.0 / (2.0 * math.pi * cutoff_hz)
