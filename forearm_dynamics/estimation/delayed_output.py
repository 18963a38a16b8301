"""The Kalman filter's delayed output (estimator.delay_s > 0), apart from the filter
(kalman.py) because it is the output stage, not the estimate: the filter steps as it would
causally, and this stage turns its states into the estimate of the sample delay_s back.

The output is the fixed-lag smoothed estimate of that sample (round(delay_s / dt) samples
at the stream's nominal period: jitter does not change the count, a new rate does and loses
no sample; lag gains from each noise group's converged filter, ca_model.lag_gains, cached),
stamped with that sample's stamp (`stamp_ns`); nothing is output until the smoother has it
(stamp_ns None). With positions only, a noisy joint with coloured noise or a model wider
than delay_practice_hz (6 Hz) is moved towards the offline practice's conditional
expectation of that sample, by a weight measured online (practice_lag.py: the model's
smoother alone follows more content above the practice's band with more lag; with the blend
more lag is never worse against the practice on the real corpus's tuning half).
covariance() stays the model smoother's.

`DelayedOutput` is a mixin of KalmanCA: it reads the filter's state (_X, _E, _count, _dt,
_groups, psd, noise_estimator, _plag, _plag_use) and writes the outputs (_out, stamp_ns).
"""

from __future__ import annotations

import numpy as np

from . import ca_model
from .smoother import FixedLagSmoother


class DelayedOutput:
    """Mixin of KalmanCA: the delayed output; see above."""

    def _output_delayed(self, t_ns: int, warm: bool, vel: bool) -> bool:
        sm = self._smoother
        if sm is None or not self._smooth_dt:
            if self._count < 2:  # no period known yet: the first sample waits for the gains
                self._first = (t_ns, self._X.copy())
                self.stamp_ns = None
                return False
            self._configure_smoother(self._dt, vel)
            first, self._first = self._first, None
            if first is not None:  # the first sample (of the stream or after a reset) goes in now
                self._smoother.push(first[0], first[1], np.zeros((2 if vel else 1, self.n)))
            sm = self._smoother
        e = self._E if self._count >= 2 else self._E * 0.0
        if sm.push(t_ns, self._X, e if vel else e[:1]):
            np.copyto(self._out, sm.out)
            self.stamp_ns = sm.stamp_ns
            pl = self._plag
            use = self._plag_use
            if pl is not None and not vel and use.any() and pl.estimate(self._X, sm.out) == sm.stamp_ns:
                np.copyto(self._out, pl.out, where=use)  # the practice's blend (practice_lag.py)
            return warm
        self.stamp_ns = None
        return False

    def _configure_smoother(self, dt: float, vel: bool) -> None:
        """Lag gains per joint from each group's converged filter at the stream's nominal
        period (the noise estimator's; dt before it has one).

        The nominal period, not the last step's: on jittered stamps the last dt moved the lag
        count (round(delay_s / dt): 0.05 s is 36-83 samples at 0.6-1.4 ms) at every regroup,
        and a new smoother dropped what the old one held (1 732 of 20 000 samples never
        output; test_estimation_parts). A real rate change makes a new smoother that first
        outputs what the old one held. The gains are ca_model.lag_gains' cache of the
        steady state per (period, noise bin): a regroup costs a lookup per group, not a
        Riccati solve and `lags` matrix products (2.7 ms median at 1 kHz, on the callback)."""
        nominal = self.noise_estimator.period_s or dt
        lags = max(1, round(self.delay_s / nominal))
        old = self._smoother
        if old is None or old.lags != lags:
            self._smoother = FixedLagSmoother(self.n, lags)
            if old is not None:
                self._smoother.take_over(old)
        m = 2 if vel else 1
        gains = np.zeros((lags + 1, 3, m, self.n))
        cov = np.zeros((self.n, 3, 3))
        for g in self._groups:
            k, c = ca_model.lag_gains(nominal, g.r, g.rv if vel else None, self.psd, lags)
            gains[:, :, :, g.idx] = k[:, :, :, None]
            cov[g.idx] = c
        self._smoother.set_gains(gains, cov)
        self._smooth_dt = dt
        if self._plag is not None and not vel:
            self._plag.configure(nominal, lags)  # the same (period, lags): the ring stays

    def drain(self) -> list[tuple[int, np.ndarray]]:
        """With a delay: the samples not yet output (end of a recording), [(stamp, (3, n))]."""
        return [] if self._smoother is None else self._smoother.drain()
