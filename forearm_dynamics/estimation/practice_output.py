"""The Kalman filter's causal q̈ with the practice filter (issue 29), apart from the filter.

Which joints (`_practice_filter_joints`, at every noise update, every 0.25 s): positions
only, causal, at 25 Hz or faster, the noise measured, and per joint noisy (white level above EXACT_WHITE x the
floor: not exact or held input) and either filtered by the model wider than the practice's
6 Hz, (psd / (r^2 dt))^(1/6) > 2 pi 6 Hz, or with coloured noise (band level above
COLOURED_RATIO x the white level; once in, down to practice_lag.KEEP_RATIO): such a joint
passes content the practice removes. A joint enters at once and leaves once the rule has
said so for 1 s (noise_belief.HOLD_UPDATES): a fast movement reads as white noise for a
moment. The same rule as the delayed estimate's blend (practice_lag.py).
A joint the model filters narrower with white noise (a 1.5 deg glove at 90 Hz, a 3 deg
camera at 30 Hz) keeps the model: nothing above the band is passed, and the
model, right for white noise, is the better estimate (real corpus's tuning half with 1 deg
of added white noise: model 0.62 x the Butterworth, the practice filter 0.83 x; 3 deg:
0.40 x against 0.83 x; /tmp study).

Output (`_practice_filter_output`): q and q̇ stay the model's (a torque's error on real
recordings is almost all q̈'s; a q̇ of the filter's kernel made the simulated mocap sensor's
finger torques 2 x worse through the arm's velocities); q̈ of the rule's joints is the
blend of the model's and the practice filter's (practice_blend.py: the weight measured per
joint against the practice), with the share estimator.practice_filter (1 by default) of it
beside the model's own, once the filter's ring holds the kernel's span, faded in (and out,
when a joint leaves the rule) linearly over FADE_S so that q̈ does not jump; a restart (a
reset, a discontinuity) drops them at once, as the model restarts there too.

Per sample it is two compiled calls where the extension is built (practice_step.py: the
filter's ring, and the filter's q̈, the blend's sums, the fade and the output); the numpy
code here and in practice_fir.py / practice_blend.py is their reference.

`PracticeOutput` is a mixin of KalmanCA: it reads _pfir, _pblend, _pf_use, _pf_w, _out,
_dt, psd, _r, _floor, noise_estimator, writes the output's q̈ row and keeps the compiled
step in _pstep (bound to the arrays of _pstep_key).
"""

from __future__ import annotations

import numpy as np

from . import practice_step

#: seconds over which a joint's q̈ moves between the model's and the blend's
FADE_S = 0.1
#: the practice's band (Hz) the filter's kernel estimates (benchmarks/practice_fir_design.py)
BAND_HZ = 6.0
#: the slowest stream (s per sample) the filter serves: it was designed on 33-100 Hz (and
#: checked on noise to 1 kHz); below 25 Hz the practice's 6 Hz band nears the Nyquist
#: frequency and the model alone estimates
MAX_PERIOD_S = 0.04


class PracticeOutput:
    """Mixin of KalmanCA: the practice filter's joints and their q̈; see above."""

    def practice_filter_weight(self) -> np.ndarray:
        """(n,) each joint's share of the practice filter's blend in the q̈ output (0: the
        model's q̈; 1: the blend of practice_blend.py), copy; zeros without the filter."""
        return np.zeros(self.n) if self._pfir is None else self._pf_w.copy()

    def practice_filter_variance(self) -> np.ndarray | None:
        """(n,) the blended q̈'s error variance now ((rad/s²)², practice_blend.error_variance:
        the σ's q̈ variance on the filter's joints); None without the filter."""
        if self._pfir is None:
            return None
        return self._pblend.error_variance()

    def _practice_filter_joints(self) -> None:
        ne = self.noise_estimator
        use = self._pf_use
        dt = ne.period_s or self._dt
        if not self.noise_known(False) or not ne.white_evaluations or dt > MAX_PERIOD_S:
            use.fill(False)
            return
        self._pfir.configure(dt)
        self._pblend.configure(dt)
        self._pblend.update()
        self._passes_what_the_practice_removes(use, self._pf_was, self._pf_against, BAND_HZ, dt)
        np.multiply(use, self._pf_share, out=self._pf_target)

    def python_practice(self):
        """Run the practice filter numpy's way from now on, after a new rate too (the compiled
        step's reference: test_practice_step.py, benchmarks/compiled_cost.py); returns self."""
        self._pcompiled = False
        self._pstep = None
        return self

    def _practice_compiled(self):
        """The compiled step bound to the filter's and the blend's arrays of now (practice_step.py),
        bound again after either's configure(); None: numpy's way."""
        key = (self._pfir._ring, self._pblend._win)
        old = self._pstep_key
        if self._pcompiled and (old is None or key[0] is not old[0] or key[1] is not old[1]):
            self._pstep_key = key
            self._pstep = None if key[1] is None or not self._pfir.K else practice_step.bind(
                self._pfir, self._pblend, self._pf_w, self._pf_target, self._pf_use, self._out[2],
                self._pf_share, FADE_S)
        return self._pstep

    def _practice_push(self, t_ns: int, q: np.ndarray) -> None:
        """The sample's positions (the gate's prediction for a held joint) into the filter's ring."""
        fast = self._practice_compiled()
        if fast is not None:
            try:
                fast.push(t_ns, q)
            except (TypeError, ValueError, BufferError):  # not contiguous float64: numpy's way
                pass
            else:
                return
        self._pfir.push(t_ns, q)

    def _practice_filter_output(self, q: np.ndarray) -> None:
        """q̈ of the rule's joints: the blend of the model's and the practice filter's; every
        sample's two q̈ estimates into the blend's window. q: the sample's positions (the
        gate's prediction for a held joint). One compiled call where it is built."""
        fast = self._practice_compiled()
        if fast is not None:
            try:
                fast.output(self._dt, q)
            except (TypeError, ValueError, BufferError):  # not contiguous float64: numpy's way
                pass
            else:
                return
        pf = self._pfir
        w = self._pf_w
        qdd = self._out[2]
        if not pf.ready:  # restarted: the model restarts too, its output is the one there is
            w.fill(0.0)
            return
        f = pf.estimate()
        self._pblend.add(q, qdd, f)
        target = self._pf_target
        done = np.array_equal(w, target)
        if not done:  # fading: towards the share on the rule's joints, 0 elsewhere
            d = self._pf_d
            np.subtract(target, w, out=d)
            step = self._dt / FADE_S
            arrive = np.abs(d) <= step
            np.clip(d, -step, step, out=d)  # at most a step, never past the target
            w += d
            np.copyto(w, target, where=arrive)  # exactly there (w + (t - w) may miss by an ulp)
        if not w.any():
            return
        # the blend f + beta (k - f) = k + (1 - beta)(f - k), then faded: k + w (blend - k)
        f -= qdd
        f *= self._pblend.share
        if done and self._pf_share == 1.0:  # every weight 0 or 1
            np.add(qdd, f, out=qdd, where=self._pf_use)
        else:
            f *= w
            qdd += f
