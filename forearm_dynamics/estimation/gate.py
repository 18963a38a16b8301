"""The jump gate: a sample that does not fit the filter's prediction is held back one sample.

Two things make a sample's innovation (sample - prediction) far larger than its standard
deviation sigma (sqrt(P_qq + r^2) of the prior, per joint):
- an outlier: a marker swap or a tracker's glitch, a single-sample spike of 5-20 deg on a
  joint or a few; the next sample is back where the prediction says;
- a discontinuity: the posture jumps and stays (two movements played back to back, a tracker
  re-acquiring a hand).
Causally the two look alike at the sample itself, so the gate withholds it: on every joint
whose innovation exceeds SPIKE_SIGMAS sigma + SPIKE_FLOOR_RAD (4 sigma + 1 deg) the filter uses its prediction
(the innovation is set to 0) and the gate keeps the innovation. At the next sample:
- a held joint whose new innovation is within the gate again was an outlier: the held
  sample is dropped for good (`outliers` counts the samples);
- otherwise the held sample was genuine: its correction is restored exactly (the filter is
  linear: adding F K e to the new prior is the same as having applied K e one sample ago),
  so genuine fast motion that crosses the gate costs one sample of delay, nothing else;
  and if the held innovation also exceeded the discontinuity threshold (JUMP_SIGMAS sigma +
  JUMP_FLOOR_RAD on any joint) the filter restarts from the held sample (a discontinuity,
  `discontinuities` counts them): a jump's innovation would otherwise ring through q, qd and
  qdd for the filter's whole time constant (check_bag's pipeline NRMSE up to 342 % on the
  back-to-back replay of the first version).
Thresholds: the discontinuity threshold is the first version's (12 sigma + 0.15 rad: 2.3 x
the largest genuine innovation of the library's movements at 20 Hz, under the smallest jump
between two movements, 0.39 rad). The outlier threshold, 4 sigma + 1 deg, catches a 5 deg
spike on a 0.5 deg sensor (sigma, the innovation's std, is 0.92 deg there: the filter's own
uncertainty adds to the sensor's); Gaussian noise crosses it once in 16 000 joint-samples,
and such a sample is either restored exactly at the next sample or, if the next is back,
dropped (one noisy sample less): harmless either way. Genuine motion that crosses it (fast
movements at 20-30 Hz) is restored: one sample of delay.
At most MAX_PER_WINDOW held samples per noise window (0.25 s): more are not outliers but a
sensor that got noisier, and are filtered normally so that the noise estimate can follow.
The gate is armed once the noise estimate exists (at once with a fixed noise), or the white
level does (third differences, a few samples; the gate judges with it until then): a stream
whose timer stalls restarts the 10 Hz estimate at every stall over 3 periods (test_pipeline
at load 4: 100 in 7.5 s) and never had one, so its gate stayed unarmed and every jump rang
through the filter (check_bag 20-125 %).
"""

from __future__ import annotations

import math

import numpy as np

_max = np.maximum.reduce

SPIKE_SIGMAS = 4.0
SPIKE_FLOOR_RAD = math.radians(1.0)
JUMP_SIGMAS = 12.0
JUMP_FLOOR_RAD = 0.15
MAX_PER_WINDOW = 4


class JumpGate:
    """Decides which joints of a sample are held back, and what a held sample was."""

    def __init__(self, n: int):
        self.n = n
        self.outliers = 0
        self.discontinuities = 0
        self.held = np.zeros(n, bool)  # joints of the sample held back (pending)
        self.pending = False
        self.jump = False  # the held sample crossed the discontinuity threshold
        self._left = MAX_PER_WINDOW
        self._lim = np.zeros(n)
        self._abs = np.zeros(n)
        self._back = np.zeros(n, bool)

    def new_window(self) -> None:
        self._left = MAX_PER_WINDOW

    def clear(self) -> None:
        self.pending = False
        self.jump = False
        self.held.fill(False)

    def limit(self, sigma: np.ndarray, out: np.ndarray) -> np.ndarray:
        np.multiply(sigma, SPIKE_SIGMAS, out=out)
        out += SPIKE_FLOOR_RAD
        return out

    def check(self, e: np.ndarray, sigma: np.ndarray, emax: float | None = None) -> bool:
        """Innovations e (n,) with stds sigma (n,): hold the joints beyond the gate (sets
        `held`, `pending`, `jump`); True if any joint is held. emax: max |e| if the caller
        has it (the compiled predict: kalman_step.py)."""
        if emax is not None:
            if emax <= SPIKE_FLOOR_RAD or not self._left:
                return False
            np.abs(e, out=self._abs)
        # cheap on most samples: the ufunc's reduce, not ndarray.max's Python wrapper
        elif _max(np.abs(e, out=self._abs)) <= SPIKE_FLOOR_RAD or not self._left:
            return False
        lim = self.limit(sigma, self._lim)
        np.greater(self._abs, lim, out=self.held)
        if not self.held.any():
            return False
        self._left -= 1
        self.pending = True
        np.multiply(sigma, JUMP_SIGMAS, out=lim)
        lim += JUMP_FLOOR_RAD
        self.jump = bool((self._abs > lim).any())
        return True

    def resolve(self, e: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """At the sample after a held one, with its innovations e against the prediction that
        skipped the held sample: the mask of held joints that were genuine (to restore).
        Counts an outlier if some held joint came back, a discontinuity if the genuine part
        crossed the discontinuity threshold (`jump` stays True then: the caller restarts)."""
        np.abs(e, out=self._abs)
        np.less_equal(self._abs, self.limit(sigma, self._lim), out=self._back)
        self._back &= self.held
        genuine = self.held & ~self._back
        if self._back.any():
            self.outliers += 1
        self.jump = self.jump and bool(genuine.any())
        if self.jump:
            self.discontinuities += 1
        self.pending = False
        self.held.fill(False)
        return genuine
