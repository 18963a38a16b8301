"""Causal Savitzky-Golay end-point estimate on the real stamps.

At each sample, fit a polynomial of order p (savgol_order, 2 or 3) by least squares to the
positions of the last savgol_window_s seconds, in time relative to the newest sample, and
take its value and derivatives at the newest sample: q = c0, qd = c1, qdd = 2 c2. The
design matrix is built from the actual stamps (irregular stamps and dropped samples are
just other times), so it is weighted least squares on the real times with weight 1 in the
window and 0 outside; at low rates the window widens to the newest p + 2 samples.

With velocities given, q comes from the position fit and qd, qdd from a fit of order p - 1
to the velocities over the same window (value and slope at the newest sample).

Model: polynomial of order p over the window, so the estimate is exact (to rounding) on
such polynomials. Cost: a ring buffer of the window (capacity ceil(1500 x window) + p + 2
samples, rate up to ~1.5 kHz; beyond, the oldest samples drop out of the window), one
(p+1) x capacity by capacity x n product and a (p+1)^2 solve per sample; nothing allocated.

Lag: exact on polynomials of order p means no delay at low frequency for q and qd (and for
qdd when p = 3). For p = 2 the acceleration's error on a constant jerk j is -j d with
d = -sum_i h_i tau_i^3 / 6 (h: the qdd coefficients on the sample times tau_i <= 0) -- for
a uniform grid d = W/2 (half the window W), at every rate.
lag() computes d from the coefficients at the given dt.
Noise: the variance of white position noise is multiplied by sum_i h_i^2 (per estimate).
"""

from __future__ import annotations

import math

import numpy as np

from .base import SettingSpec, StateEstimator

MAX_RATE_HZ = 1500.0


def _invert_into(g: list[list[float]], out: np.ndarray) -> None:
    """out = inv(g) for a small SPD g (Gauss-Jordan on Python floats, no array allocated)."""
    m = len(g)
    a = [row[:] + [1.0 if i == j else 0.0 for j in range(m)] for i, row in enumerate(g)]
    for c in range(m):
        piv = a[c][c]
        if not piv > 1e-300:
            raise ZeroDivisionError("singular fit")
        inv = 1.0 / piv
        rowc = a[c] = [x * inv for x in a[c]]
        for r in range(m):
            if r != c:
                f = a[r][c]
                if f != 0.0:
                    a[r] = [x - f * y for x, y in zip(a[r], rowc, strict=True)]
    for i in range(m):
        for j in range(m):
            out[i, j] = a[i][m + j]


class _EndPointFit:
    """Polynomial fit of order p to a ring of (time, (n,) value) at the newest time."""

    def __init__(self, n: int, order: int, cap: int):
        self.p = order
        self.vals = np.zeros((cap, n))
        self.pows = np.zeros((2 * order + 1, cap))
        self.mom = np.zeros(2 * order + 1)
        self.rhs = np.zeros((order + 1, n))
        self.coef = np.zeros((order + 1, n))
        self.ginv = np.zeros((order + 1, order + 1))

    def fit(self, tau: np.ndarray, w: np.ndarray) -> None:
        """Scaled times tau (cap,), weights w; coef[k] = k-th coefficient at tau = 0."""
        p, pows = self.p, self.pows
        np.copyto(pows[0], w)
        for i in range(1, 2 * p + 1):
            np.multiply(pows[i - 1], tau, out=pows[i])
        pows.sum(axis=1, out=self.mom)
        np.dot(pows[: p + 1], self.vals, out=self.rhs)
        mom = self.mom.tolist()
        g = [[mom[i + j] for j in range(p + 1)] for i in range(p + 1)]
        _invert_into(g, self.ginv)
        np.dot(self.ginv, self.rhs, out=self.coef)


class SavitzkyGolay(StateEstimator):
    """End-point least-squares polynomial on the real stamps; see the module docstring."""

    name = "savgol"
    settings = (
        SettingSpec("savgol_window_s", 0.2, "s", "fit window (widened to hold order + 2 samples)",
                    lo=1e-3, hi=5.0),
        SettingSpec("savgol_order", 2.0, "", "polynomial order, 2 or 3", lo=2.0, hi=3.0),
    )

    def __init__(self, n: int, settings):
        super().__init__(n, settings)
        if self.values["savgol_order"] not in (2.0, 3.0):
            raise ValueError(f"estimator setting savgol_order = {self.values['savgol_order']} must be 2 or 3")
        p = self.p = int(self.values["savgol_order"])
        self.window = self.values["savgol_window_s"]
        self.min_pts = p + 2
        cap = self.cap = math.ceil(MAX_RATE_HZ * self.window) + self.min_pts
        self._time = np.zeros(cap)  # s since the first sample after a reset
        self._tau = np.zeros(cap)
        self._w = np.zeros(cap)
        self._ok = np.zeros(cap, bool)
        self._pos = _EndPointFit(n, p, cap)
        self._velfit = _EndPointFit(n, p - 1, cap)
        self._count = 0
        self._head = -1
        self._t_ref = 0
        self._vel_mode: bool | None = None

    def reset(self) -> None:
        self._count = 0
        self._head = -1
        self._t_ns = None
        self._vel_mode = None

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        self.check(t_ns, q, qd)
        vel_mode = qd is not None
        if self._vel_mode is not None and vel_mode != self._vel_mode:
            self.reset()  # the input changed kind: the ring holds the other kind
        self._vel_mode = vel_mode
        if self._count == 0:
            self._t_ref = t_ns
        self._t_ns = t_ns
        h = self._head = (self._head + 1) % self.cap
        self._count = min(self._count + 1, self.cap)
        self._time[h] = (t_ns - self._t_ref) * 1e-9
        np.copyto(self._pos.vals[h], q)
        if vel_mode:
            np.copyto(self._velfit.vals[h], qd)
        if self._count <= self.p:  # p + 1 points determine the position fit
            np.copyto(self.q, q)
            if vel_mode:
                np.copyto(self.qd, qd)
            else:
                self.qd.fill(0.0)
            self.qdd.fill(0.0)
            return False
        self._weights(h)
        s = self._scale
        self._pos.fit(self._tau, self._w)
        c = self._pos.coef
        np.copyto(self.q, c[0])
        if vel_mode:
            self._velfit.fit(self._tau, self._w)
            cv = self._velfit.coef
            np.copyto(self.qd, cv[0])
            np.multiply(cv[1], 1.0 / s, out=self.qdd)
        else:
            np.multiply(c[1], 1.0 / s, out=self.qd)
            np.multiply(c[2], 2.0 / (s * s), out=self.qdd)
        return True

    def _weights(self, h: int) -> None:
        """tau = (t - t_newest) / scale in the window (else 0), w = 1 in the window."""
        tau, w, ok = self._tau, self._w, self._ok
        np.subtract(self._time, self._time[h], out=tau)
        np.greater_equal(tau, -self.window * (1.0 + 1e-9), out=ok)
        if self._count < self.cap:  # slots never written
            ok[self._count:] = False
        for j in range(min(self.min_pts, self._count)):  # at least p + 2 newest samples
            ok[(h - j) % self.cap] = True
        np.copyto(w, ok)
        # scale: the oldest time in the fit, so |tau| <= 1 (a well-conditioned moment matrix)
        np.multiply(tau, w, out=tau)
        self._scale = s = max(-float(tau.min()), 1e-9)
        tau *= 1.0 / s

    def window_samples(self, dt: float) -> int:
        """Samples in the fit on a uniform grid of period dt."""
        return max(math.floor(self.window / dt * (1 + 1e-9)) + 1, self.min_pts)

    def coefficients(self, dt: float, velocity_given: bool = False) -> np.ndarray:
        """(3, m) weights of the m window samples (oldest first) giving q, qd, qdd on a
        uniform grid of period dt: the linear filter the estimate is (for lag and noise).
        With velocity_given, the qd and qdd rows apply to the velocity samples."""
        m = self.window_samples(dt)
        tau = (np.arange(m) - (m - 1)) * dt
        s = -tau[0]
        rows = np.zeros((3, m))
        rows[0] = np.linalg.pinv(np.vander(tau / s, self.p + 1, increasing=True))[0]
        if velocity_given:
            hv = np.linalg.pinv(np.vander(tau / s, self.p, increasing=True))
            rows[1], rows[2] = hv[0], hv[1] / s
        else:
            hp = np.linalg.pinv(np.vander(tau / s, self.p + 1, increasing=True))
            rows[1], rows[2] = hp[1] / s, 2.0 * hp[2] / (s * s)
        return rows

    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        m = self.window_samples(dt)
        tau = (np.arange(m) - (m - 1)) * dt
        h = self.coefficients(dt, velocity_given)
        if velocity_given:  # signal = velocity; qd from a fit of order p-1, qdd its slope
            d_qd = -float(h[1] @ tau) if self.p - 1 < 1 else 0.0
            d_qdd = -float(h[2] @ (tau**2 / 2)) if self.p - 1 < 2 else 0.0
            return {"q": 0.0, "qd": abs(d_qd), "qdd": d_qdd}
        d_qdd = -float(h[2] @ (tau**3 / 6)) if self.p < 3 else 0.0
        return {"q": 0.0, "qd": 0.0, "qdd": d_qdd}
