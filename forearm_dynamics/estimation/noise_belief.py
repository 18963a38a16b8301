"""The Kalman filter's noise belief per joint: what it measures, caps and applies.

Why apart from the filter (kalman.py): the belief is where the filter meets the data
(noise.py's estimates every NOISE_EVERY_S, the 7 Hz cap for coloured noise, which joints
blend the practice into a delayed estimate: practice_lag.py),
and where the σ reads what the filter believes (measured_noise, noiseless,
noise_known). `NoiseBelief` is a mixin of KalmanCA; the reasons for each rule are in
kalman.py's module docstring.
"""

from __future__ import annotations

import math

import numpy as np

from . import practice_lag

EXACT_WHITE = 0.1  # white level (x the floor) under which a joint's q̈ is taken as exact
COLOURED_RATIO = 1.5  # band level / white level above which the noise counts as coloured
# the white level's evaluations before it may arm the gate without the 10 Hz estimate (fewer:
# a 5 deg sensor read low enough for a false jump on a fast 30 Hz movement)
WHITE_ARM_EVALUATIONS = 25
#: ... and only at sample periods up to this (s): the third difference passes a movement at
#: f by (2 sin(pi f dt))^6, 1e-9 at 5 Hz and 1 kHz, 1.5e-5 at 200 Hz, but 1 at 30 Hz, where
#: the "white level" is the movement's and the gate it armed held the first second of the
#: simulated 30 Hz camera (estimation_zoo: kalman fingers NRMSE 0.077 -> 0.138, every
#: group worse, from commit 8f13e4e on; with this limit 0.077 again)
WHITE_ARM_MAX_PERIOD_S = 0.005
#: noise updates in a row (kalman.NOISE_EVERY_S: 1 s) the practice rule must answer "the
#: model" before a joint that uses the practice leaves it; it enters at once. A fast movement
#: raises the white level (third differences) as white noise would, for a moment: the running
#: elbow swing of the corpus's tuning half (Hamner, 60 Hz) left the practice for 1.5 s
#: mid-swing, its delayed estimates went to the model's smoother there, and more delay bought
#: nothing (torque NRMSE 0.30 / 0.27 x the Butterworth at 0.1 / 0.2 s, median 0.12 / 0.04);
#: a sensor's own noise does not change within a second. Entering is not held: a movement
#: does not make noise look coloured, and holding both ways froze a short stream's first
#: answer (the sensor zoo's held_exact σ rows moved more)
HOLD_UPDATES = 4


def _summary(r: np.ndarray, floor: float) -> float:
    above = r[r > floor * 1.0001]
    return float(np.median(above)) if len(above) else float(r.max())


class NoiseBelief:
    """Mixin of KalmanCA: the per-joint noise it believes and its online update."""

    def noise_per_joint(self) -> np.ndarray:
        """The position noise std each joint believes (rad), (n,) copy."""
        return self._r.copy()

    def noise(self) -> float | None:
        """One summary of the believed position noise (rad): the median over the joints
        above the floor (the measured ones; held and exact joints believe the floor), or
        the floor. Each joint's own: noise_per_joint()."""
        return _summary(self._r, self._floor)

    def velocity_noise(self) -> float | None:
        return _summary(self._rv, self._floor)

    def measured_noise(self) -> tuple[np.ndarray, np.ndarray]:
        """Per joint (position, velocity) noise variances as measured, BEFORE the floor (the
        floor keeps the gain sane on exact input; it is a belief, not noise that is there);
        the fixed values where set, the default belief before the first estimate."""
        self.learn()
        ne = self.noise_estimator
        r2 = self._r**2
        rv2 = self._rv**2
        if self._fixed_r is None and ne.ready:
            r2 = ne.position(np.zeros(self.n)) ** 2
        if self._fixed_rv is None and ne.velocity_ready:
            rv2 = ne.velocity(np.zeros(self.n)) ** 2
        return r2, rv2

    def noise_known(self, velocity_given: bool) -> bool:
        """Whether the noise the filter runs with is measured (or fixed), not the default
        belief it starts with: the estimate needs ~0.3-0.5 s of samples (noise.py) and is
        applied at the next noise update (every NOISE_EVERY_S), longer than the state's
        warm-up; until then the gain, hence the error, is that of a guess."""
        known = self._fixed_r is not None or self._applied[0]
        if velocity_given:
            known = known and (self._fixed_rv is not None or self._applied[1])
        return known

    def noiseless(self) -> np.ndarray:
        """(n,) bool: joints whose white level (third differences of consecutive samples,
        near Nyquist, where no movement is) is within 2 x the floor: exact or held input,
        the jump gate's rule for exact input; their 10 Hz level is the movement's own
        content, not noise. None with the noise fixed (kalman_noise_deg > 0) or before the
        first white-level estimate."""
        self.learn()
        if self._fixed_r is not None or not self.noise_estimator.white_evaluations:
            return np.zeros(self.n, bool)
        return self.noise_estimator.white(np.empty(self.n)) <= 2.0 * self._floor

    def _update_noise(self, vel: bool, dt: float) -> None:
        ne = self.noise_estimator
        moved = False
        if self._fixed_r is None and ne.ready:
            ne.position(self._r)
            np.maximum(self._r, self._floor, out=self._r)
            np.copyto(self._r_gate, self._r)  # the gate judges with the noise as measured
            capped = np.full(self.n, np.inf)
            if not vel and self._wmin > 0.0 and ne.period_s > 0.0 and self.delay_s <= 0.0:
                # never smooth below the practice's band: cap at the noise whose filter
                # bandwidth (psd / (r^2 dt))^(1/6) is kalman_min_bandwidth_hz
                cap = math.sqrt(self.psd / (self._wmin**6 * ne.period_s))
                white = ne.white(self._tmp)
                white *= COLOURED_RATIO  # band level above this: coloured, capped
                capped[self._r > white] = cap
                np.minimum(capped, self._r, out=self._r)
                np.maximum(self._r, self._floor, out=self._r)
            self._innovation_std()  # not the groups' recursions: they are converged (still)
            self._armed = moved = True
            self._applied[0] = True
        elif (self._fixed_r is None and ne.white_evaluations >= WHITE_ARM_EVALUATIONS
              and 0.0 < ne.period_s <= WHITE_ARM_MAX_PERIOD_S):
            # no 10 Hz estimate yet (a stream whose timer stalls restarts it at every stall and
            # may never get one): the gate judges with the white level, measured in a few
            # samples, rather than stay unarmed and let every jump ring through the filter
            ne.white(self._r_gate)
            np.maximum(self._r_gate, self._floor, out=self._r_gate)
            self._innovation_std()  # the gate's stds with this level (the gains stand)
            self._armed = True
        if vel and self._fixed_rv is None and ne.velocity_ready:
            ne.velocity(self._rv)
            np.maximum(self._rv, self._floor, out=self._rv)
            moved = True
            self._applied[1] = True
        if moved:
            self._regroup(vel, dt)

    def _practice_lag_joints(self) -> None:
        """The joints whose delayed estimate blends in the practice's (practice_lag.py): noisy
        (white level above EXACT_WHITE x the floor: not exact or held input) and either
        filtered by the model wider than the practice's band, (psd / (r^2 dt))^(1/6) >
        2 pi delay_practice_hz, or with coloured noise (band level > COLOURED_RATIO x white
        level; once in, down to KEEP_RATIO). A white joint filtered narrower passes nothing
        the practice removes, and the model, right for white noise, is kept."""
        use = self._plag_use
        if not self.noise_known(False):  # the band level is the default belief, not measured:
            use.fill(False)  # no joint is known to be coloured or wide yet (a short exact movement)
            return
        self._passes_what_the_practice_removes(use, self._plag_use_was, self._plag_against,
                                               self._plag.cutoff_hz,
                                               self.noise_estimator.period_s or self._dt)

    def _passes_what_the_practice_removes(self, use: np.ndarray, was: np.ndarray,
                                          against: np.ndarray, band_hz: float, dt: float) -> None:
        """Into `use`: the joints the model lets content above band_hz through on (the rule
        of _practice_lag_joints, also the practice filter's: practice_output.py); a joint
        enters at once and leaves once the rule has said so HOLD_UPDATES times in a row.
        `was`: the joints in use (also the coloured test's hysteresis) and `against` the
        count of answers against, updated."""
        white = self.noise_estimator.white(self._tmp)
        np.greater(white, EXACT_WHITE * self._floor, out=use)
        wide = self.psd / (self._r**2 * dt) > (2.0 * math.pi * band_hz) ** 6
        coloured = self._r > np.where(was, practice_lag.KEEP_RATIO, COLOURED_RATIO) * white
        use &= wide | coloured
        leave = was & ~use  # the rule says "the model" for a joint in use
        against[leave] += 1
        against[~leave] = 0
        use |= was & (against < HOLD_UPDATES)  # entering at once, leaving once held
        against[~use] = 0
        np.copyto(was, use)
