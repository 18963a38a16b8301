"""Causal 2nd-order Butterworth low-pass on positions, then backward differences.

What biomechanics labs do online (and the baseline of benchmarks/estimation.py at 6 Hz):
low-pass the measured angles, differentiate the filtered angles twice.

Discretisation: per real dt. H(s) = w^2 / (s^2 + sqrt(2) w s + w^2) as a state space
[y, y'] integrated with the trapezoidal rule over each sample's own dt (the bilinear
transform, w prewarped at the cutoff; closed form, ~20 float operations, skipped when dt
repeats). For a uniform stream this is exactly scipy.signal.butter(2, fc, fs=1/dt);
jittered stamps and dropped samples (one long dt) need no re-design step, and because the
states are y and y' (not a direct form's coefficient-dependent states) a change of dt
causes no transient. The cutoff is capped at 0.45 x the sample rate.

    y = Butterworth(q);   qd = (y[k] - y[k-1]) / dt;   qdd = (qd[k] - qd[k-1]) / dt

With velocities given, the velocities are filtered by the same filter (qd) and qdd is
their backward difference; q is the filtered position.

Lag (low-frequency group delay): the filter delays by sqrt(2) / (2 pi fc) (37.5 ms at 6 Hz,
11.3 ms at 20 Hz; lag() uses the prewarped w); each backward
difference adds dt/2:
    q: sqrt(2)/(2 pi fc)   qd: + dt/2   qdd: + dt      (velocities given: qd + 0, qdd + dt/2)
Noise: white position noise of variance s^2 comes out of the filter with variance
s^2 * 2 * B * dt, B = the noise-equivalent bandwidth pi fc / (2 sin(pi/4)) ~ 1.11 fc (the
analog value; the prewarped digital filter matches it for fc << rate).

Warm-up: the filter starts at rest on the first sample (no ramp); qd is real from the 2nd
sample (velocities given: the 1st), qdd from the 3rd (the 2nd).
"""

from __future__ import annotations

import math

import numpy as np

from .backward import _Differentiator, differences
from .base import SettingSpec, StateEstimator

SQRT2 = math.sqrt(2.0)


class _Biquad:
    """2nd-order Butterworth as a state space [y, y'] on (n,) vectors, trapezoidal per dt.

    y'' = w^2 (x - y) - sqrt(2) w y', integrated with the trapezoidal rule over each real dt
    (= the bilinear transform; w prewarped to (2/dt) tan(pi fc dt), so a uniform stream gets
    exactly scipy's butter(2, fc, fs=1/dt)). The states are y and its rate, so a new dt
    (jitter, a dropped sample) changes no state: no transient, where a direct form's
    internal states would jump with its coefficients.
    """

    def __init__(self, n: int, cutoff_hz: float):
        self.fc = cutoff_hz
        self.y = np.zeros(n)
        self._v = np.zeros(n)
        self._x = np.zeros(n)  # previous input
        self._s = np.zeros(n)
        self._t1 = np.zeros(n)
        self._t2 = np.zeros(n)
        self._dt = -1.0
        self.started = False

    def matrices(self, dt: float) -> tuple[float, ...]:
        """(m00, m01, m10, m11, n0, n1): z' = M z + N (x_prev + x), z = [y, y']."""
        if dt != self._dt:
            w = (2.0 / dt) * math.tan(math.pi * min(self.fc * dt, 0.45))
            h = 0.5 * dt
            # A = [[0, 1], [-w^2, -c]], c = sqrt(2) w; (I - A h)^-1 (I + A h) and (I - A h)^-1 B h
            c, w2 = SQRT2 * w, w * w
            det = 1.0 + c * h + w2 * h * h
            i00, i01, i10, i11 = (1.0 + c * h) / det, h / det, -w2 * h / det, 1.0 / det
            p00, p01, p10, p11 = 1.0, h, -w2 * h, 1.0 - c * h
            self._m = (i00 * p00 + i01 * p10, i00 * p01 + i01 * p11,
                       i10 * p00 + i11 * p10, i10 * p01 + i11 * p11,
                       i01 * w2 * h, i11 * w2 * h)
            self._dt = dt
        return self._m

    def reset(self) -> None:
        self.started = False

    def update(self, x: np.ndarray, dt: float) -> None:
        if not self.started:  # at rest on x: y = x, y' = 0
            np.copyto(self.y, x)
            self._v.fill(0.0)
            np.copyto(self._x, x)
            self.started = True
            return
        m00, m01, m10, m11, n0, n1 = self.matrices(dt)
        y, v, s, t1, t2 = self.y, self._v, self._s, self._t1, self._t2
        np.add(self._x, x, out=s)
        np.copyto(self._x, x)
        np.multiply(y, m10, out=t2)  # new v
        np.multiply(v, m11, out=t1)
        t2 += t1
        np.multiply(s, n1, out=t1)
        t2 += t1
        y *= m00  # new y
        np.multiply(v, m01, out=t1)
        y += t1
        np.multiply(s, n0, out=t1)
        y += t1
        np.copyto(v, t2)


class ButterworthDifference(StateEstimator):
    """Causal Butterworth on positions + backward differences; see the module docstring."""

    name = "butterworth"
    settings = (
        SettingSpec("butterworth_cutoff_hz", 6.0, "Hz",
                    "cutoff of the causal 2nd-order Butterworth on positions (capped at 0.45 x rate)",
                    lo=0.1, hi=1000.0),
    )

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        fc = self.values["butterworth_cutoff_hz"]
        self._pos = _Biquad(n, fc)
        self._vel_filter = _Biquad(n, fc)
        self._vel = _Differentiator(n, 0.0)
        self._acc = _Differentiator(n, 0.0)

    def reset(self) -> None:
        for part in (self._pos, self._vel_filter, self._vel, self._acc):
            part.reset()
        self._t_ns = None

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        self.check(t_ns, q, qd)
        dt = 0.0 if self._t_ns is None else (t_ns - self._t_ns) * 1e-9
        self._t_ns = t_ns
        self._pos.update(q, dt)
        np.copyto(self.q, self._pos.y)
        if qd is not None:
            self._vel_filter.update(qd, dt)
            np.copyto(self.qd, self._vel_filter.y)
            if self._vel.has_prev:
                self._vel.reset()
            return differences(None, self._vel, self._acc, self.qd, self.qdd, dt)
        if self._vel_filter.started:
            self._vel_filter.reset()
        return differences(self.q, self._vel, self._acc, self.qd, self.qdd, dt)

    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        # DC group delay of the digital filter: dt (sum k b_k / sum b_k - sum k a_k / sum a_k)
        # the continuous filter's DC group delay sqrt(2)/w, w prewarped as in _Biquad
        fc = self.values["butterworth_cutoff_hz"]
        d = SQRT2 * dt / (2.0 * math.tan(math.pi * min(fc * dt, 0.45)))
        if velocity_given:
            return {"q": d, "qd": d, "qdd": d + dt / 2}
        return {"q": d, "qd": d + dt / 2, "qdd": d + dt}
