"""Per-joint sensor noise, measured where it matters: just above the movement's band.

Why not the third difference of consecutive samples (the first version): it measures the
noise near the Nyquist frequency. Real sensors' noise is coloured: inverse kinematics and
soft-tissue artefact are low-pass (correlation times of 20-50 ms), so near Nyquist there is
little of it, and a filter told that little trusts the data and tracks content that the
offline 6 Hz practice removes. The third difference of an OpenSim IK result said 0.076 deg
for an elbow whose noise around 10 Hz is several times that (issue 16). What decides how a
filter should smooth is the noise level where the movement's spectrum ends, white or not.

Measure: per joint, the 5th divided difference of block means SPACING_S (50 ms) apart, on
the real stamps: the means m_0 .. m_5 of six consecutive blocks of s = SPACING_S / dt samples
(summed from a ring of the raw samples at each evaluation: any sample can end a block)
at their mean times t_i, z = sum_i w_i m_i with
w_i = 1 / prod_{j != i} (t_i - t_j). It is zero on any polynomial of order <= 4 (the
movement, over the 0.3 s it spans), and its response |2 sin(pi f SPACING)|^10 x |boxcar|^2
peaks at 1 / (2 SPACING) = 10 Hz, just above the 6 Hz band of the offline practice (the
boxcar suppresses the comb's aliases at 30, 50 Hz ..., which decimated samples would fold
in). For white noise of std r, var(z) = r^2 sum w^2 / s, so s z^2 / sum w^2 is an unbiased
estimate of r^2 (the level a white-noise filter should assume); for coloured noise it is
the white level with the same spectral density around 10 Hz. The movement leaks in where
it has content there (jerk steps at its start and end): the exact library movements read as up to
0.23 deg at 100 Hz and 0.72 deg at 1 kHz (the block mean divides noise, not signal, by its
length), which the filter then treats as noise: exact input at 1 kHz stays within 0.15 %
(with velocities; benchmarks/estimation.py).
Every EVERY_S (20 ms, at most every sample) one evaluation per joint, an exponentially
weighted mean (time constant TAU_S = 2 s; a running mean over the first ones) of the
evaluations, each winsorised at CLIP_SIGMAS of the current estimate once it has one (unless
CLIP_RUN evaluations in a row were: then the noise rose and is followed), so a single wild
sample cannot move it far; the filter's jump gate (gate.py) also hands over its
prediction instead of a sample it withholds (a marker swap).

Robust to: joints that never move or are exact (their estimate is ~0: they get the floor and
are passed through; every joint's estimate is its own, so a still joint never lowers
another's); levels 10-100 x apart (per joint); gaps (a step longer than GAP_PERIODS x the
previous one, and at least GAP_MIN_S = 40 ms, restarts the difference window: no difference
spans a gap; a shorter stall is jitter, which the real-time weights take: a 1 kHz stream
through a loaded ROS pipeline stalls for 3-20 ms every ~15 samples, and a 3-period rule
restarted the window so often that the estimate was never ready and the filter kept its
0.5 deg prior: `make demo` then failed every movement after the first); quantisation (a
12-bit encoder's 0.09 deg steps on a moving joint read as their 0.026 deg std; a still one
as 0); jittered stamps (the weights use the real times; uniform stamps reuse one set);
samples lost in bursts shorter than a gap. A starved node's best-effort input keeps what its
queue held: holes of up to 35 samples at 1 kHz, 40-60 % of a movement, among the
publisher's own catch-up bursts. The six blocks then cover unlike stretches of time, their
means are not the movement at their mean times, and the movement leaked in as noise: 0.003 ->
0.11 rad on an exact pro/sup in 0.6 s. The filter, given velocities, then ignored positions,
and a real 0.63 rad step went uncorrected for a second (stop 39, a two-host run at load 9;
test_noise_bursty_loss.py replays that input). So a jittered window is skipped (counted in
`irregular_windows`) when it spans more than WINDOW_STRETCH x its nominal time or its blocks'
stamp variances differ more than BLOCK_SPREAD_RATIO. Uniform stamps never are: past a
window of equal steps they take the other branch, and the windows just after a restart (still
here) have one span and equal variances; of 20 000 samples, none of a loaded publisher's
stalls (test_estimation_parts' stalled_grid) nor of ±0.3 ms jitter with 5 % random loss; 39
of 625 of that run's input.

Velocities (when the message has them): v0 - v1 - rho (v1 - v2), rho = dt0 / dt1, zero for
any constant acceleration at any stamp spacing, variance (1 + (1 + rho)^2 + rho^2) r_v^2 for
white noise; per joint, every sample (every 8th above ~400 Hz), same weighting.
"""

from __future__ import annotations

import math

import numpy as np

from .noise_store import (  # noqa: F401 - the rate's constants are noise's public ones
    GAP_MIN_S,
    GAP_PERIODS,
    NOMINAL_TOL,
    POSITION_DUE,
    VELOCITY_DUE,
    WHITE_DUE,
    Ctr,
    SampleRings,
    dense_stride,
)

SPACING_S = 0.05
ORDER = 5
EVERY_S = 0.02
TAU_S = 2.0
CLIP_SIGMAS = 4.0
CLIP_RUN = 3  # evaluations clipped in a row: the noise rose, stop clipping that joint
MIN_EVALUATIONS = 5  # before this many, the estimate is not ready
#: A jittered window is skipped (module docstring, "samples lost in bursts") when it spans
#: more than WINDOW_STRETCH x its nominal time (a quarter of its samples lost), or when its
#: blocks' stamp variances differ more than BLOCK_SPREAD_RATIO (holes and bursts).
WINDOW_STRETCH = 1.25
BLOCK_SPREAD_RATIO = 3.0
MIN_BLOCK = 4  # samples per block below which a window is not judged (_comparable)


def divided_difference_weights(t: list[float]) -> tuple[list[float], float]:
    """Weights of the divided difference on times t (any order), and the sum of their squares."""
    w = []
    for i, ti in enumerate(t):
        p = 1.0
        for j, tj in enumerate(t):
            if j != i:
                p *= ti - tj
        w.append(1.0 / p)
    return w, sum(x * x for x in w)


def _weighted_rows(w: list[float], rows: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> None:
    """out = sum_i w[i] rows[i], summed in order: the compiled store's arithmetic to the bit
    (np.dot hands it to BLAS, whose order and fused multiply-adds depend on the CPU)."""
    np.multiply(rows[0], w[0], out=out)
    for i in range(1, len(w)):
        np.multiply(rows[i], w[i], out=tmp)
        out += tmp


class NoiseEstimator(SampleRings):
    """Per-joint position (and velocity) noise std, updated sample by sample.

    `add(t_s, q, qd)` takes a sample (t in s); `position()` / `velocity()` are (n,) arrays
    of the current estimates (rad, rad/s), `ready` / `velocity_ready` whether they have
    enough evaluations; `restart()` after a gap or a re-initialised filter.

    A sample is stored (the rings, the rate, the counters: noise_store.SampleRings), and
    the evaluations it makes due are made, by one compiled call where noise_step.py's
    extension is built; the evaluations here are its reference, and run for the samples it
    leaves to Python (the first steps, a new rate).
    """

    def __init__(self, n: int):
        # what the compiled store's evaluations write (bound by SampleRings.__init__)
        self.ms = np.zeros(n)  # mean square, position
        self.ms_v = np.zeros(n)  # mean square, velocity
        self.ms_w = np.zeros(n)  # mean square of the third difference / 20: the white level
        self._nclip = np.zeros(n, np.int64)  # evaluations clipped in a row, position
        self._nclip_v = np.zeros(n, np.int64)
        super().__init__(n, SPACING_S, EVERY_S, ORDER + 1)
        self._d3 = [np.roll([-1.0, 3.0, -3.0, 1.0], h + 1).tolist() for h in range(4)]  # newest at h
        self._over = np.zeros(n, bool)
        self._sums = np.zeros((ORDER + 1, n))  # the blocks' sums, oldest first
        self._z = np.zeros(n)
        self._tmp = np.zeros(n)
        # the uniform stamps' weights, for their (step ns, stride): ((last_d, s), w, sum w^2)
        self._uniform: tuple[tuple[int, int], list[float], float] | None = None

    def _evaluated(self) -> tuple[tuple[np.ndarray, ...], tuple]:
        return ((self.ms_w, self.ms_v, self._nclip_v, self.ms, self._nclip),
                (TAU_S, CLIP_SIGMAS, CLIP_RUN, MIN_EVALUATIONS, WINDOW_STRETCH,
                 BLOCK_SPREAD_RATIO, MIN_BLOCK))

    @property
    def evaluations(self) -> int:
        """Position evaluations made."""
        return self._ctr[Ctr.PEVALS]

    @property
    def irregular_windows(self) -> int:
        """Position evaluations skipped: a jittered window's blocks do not compare (bursty
        loss; module docstring)."""
        return self._ctr[Ctr.IRREGULAR]

    @property
    def white_evaluations(self) -> int:
        return self._ctr[Ctr.WEVALS]

    @property
    def velocity_evaluations(self) -> int:
        return self._ctr[Ctr.VEVALS]

    # -- samples -------------------------------------------------------------------------
    def add(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> None:
        """The sample at t_ns (positions, and velocities or None): stored (noise_store.py),
        then the evaluations it makes due (the compiled store makes them itself, the same
        arithmetic: _noise_evaluations.c, and returns none due)."""
        due = self.store(t_ns, q, qd)
        if due:
            if due & WHITE_DUE:
                self._white_evaluation()
            if due & POSITION_DUE:
                self._position_evaluation()
            if due & VELOCITY_DUE:
                self._velocity_evaluation()

    # -- evaluations ---------------------------------------------------------------------
    def _position_evaluation(self) -> None:
        """One evaluation from the six blocks that end at the newest sample (module
        docstring)."""
        ctr = self._ctr
        cap, s = ctr[Ctr.CAP], ctr[Ctr.STRIDE]
        h = (ctr[Ctr.COUNT] - 1) % cap
        window = slice(h + 1, h + 1 + cap)  # the last cap samples, oldest first
        last_d = ctr[Ctr.LAST_D]
        if ctr[Ctr.SAME] > cap:  # uniform stamps over the window: the weights of that spacing
            u = self._uniform
            if u is None or u[0] != (last_d, s):
                span = [(i - ORDER) * s * last_d * 1e-9 for i in range(ORDER + 1)]
                w, sw = divided_difference_weights(span)
                u = self._uniform = ((last_d, s), w, sw)
            _, w, sw = u
        else:  # jittered: the weights of the blocks' mean times, if the blocks compare
            tw = self._rawt[window].reshape(ORDER + 1, s)
            if not self._comparable(tw):
                ctr[Ctr.IRREGULAR] += 1
                return
            w, sw = divided_difference_weights(tw.mean(axis=1).tolist())
        sums = self._sums
        np.sum(self._raw[window].reshape(ORDER + 1, s, self.n), axis=1, out=sums)
        z = self._z
        _weighted_rows(w, sums, z, self._tmp)  # s x the divided difference of the block means
        z *= z
        z *= 1.0 / (s * sw)  # a block mean of s white samples has variance r^2 / s
        ctr[Ctr.PEVALS] += 1
        self._accumulate(self.ms, z, ctr[Ctr.PEVALS], ctr[Ctr.EVERY] * self.period_s)

    def _comparable(self, tw: np.ndarray) -> bool:
        """Whether a jittered window's six blocks (their stamps, (6, s)) measure what the
        difference is made for (module docstring, "samples lost in bursts"): the window no
        longer than WINDOW_STRETCH x its nominal span, and the blocks' stamp variances within
        BLOCK_SPREAD_RATIO of each other. Blocks of fewer than MIN_BLOCK samples (below
        ~70 Hz) always compare: there one missing sample would change a block's variance 4x
        and the gap rule takes a sensor's dropouts (a 30 Hz camera's: the sensor zoo)."""
        if tw.shape[1] < MIN_BLOCK:
            return True
        span = tw[-1, -1] - tw[0, 0]
        if span > WINDOW_STRETCH * (tw.size - 1) * self.period_s:
            return False
        spread = tw.var(axis=1)
        return bool(spread.max() <= BLOCK_SPREAD_RATIO * spread.min())

    def _white_evaluation(self) -> None:
        """Third difference of consecutive samples: the white level, near Nyquist, where no
        movement is. On uniform stamps the plain difference (-1, 3, -3, 1) / sqrt(20); on
        jittered ones the third divided difference on the real times, normalised the same
        way (z^2 / sum w^2): the plain difference of a moving joint sampled at irregular
        times is not zero (its velocity times the timing irregularity), and that leak read as
        noise (0.021 deg on an exact elbow through a loaded ROS pipeline, over the 2 x floor
        that tells exact input)."""
        ctr = self._ctr
        h = (ctr[Ctr.WCOUNT] - 1) % 4
        z = self._z
        if ctr[Ctr.SAME] >= 3:  # the last three steps equal (to 1 us): the plain difference
            _weighted_rows(self._d3[h], self._wring, z, self._tmp)
            z *= z
            z *= 1.0 / 20.0
        else:
            try:
                wl, sw = divided_difference_weights(self._wt.tolist())
            except ZeroDivisionError:  # a repeated stamp: no difference across it
                return
            _weighted_rows(wl, self._wring, z, self._tmp)
            z *= z
            z *= 1.0 / sw
        ctr[Ctr.WEVALS] += 1
        dt = self.period_s
        a = min(1.0, max(1.0 / ctr[Ctr.WEVALS], dense_stride(dt) * dt / TAU_S))
        z -= self.ms_w
        z *= a
        self.ms_w += z

    def _velocity_evaluation(self) -> None:
        """v0 - v1 - rho (v1 - v2) on the newest three stored velocities (module docstring)."""
        h = self._ctr[Ctr.VCOUNT] % 3
        t0, t1, t2 = self._vt[h], self._vt[(h - 1) % 3], self._vt[(h - 2) % 3]
        t0, t1, t2 = float(t0), float(t1), float(t2)
        if not (t0 > t1 > t2):
            return
        rho = (t0 - t1) / (t1 - t2)
        v0, v1, v2 = self._vring[h], self._vring[(h - 1) % 3], self._vring[(h - 2) % 3]
        z, tmp = self._z, self._tmp
        np.subtract(v1, v2, out=tmp)
        tmp *= rho
        np.subtract(v0, v1, out=z)
        z -= tmp
        z *= z
        u = 1.0 + rho
        z *= 1.0 / (1.0 + u * u + rho * rho)
        self._ctr[Ctr.VEVALS] += 1
        self._accumulate(self.ms_v, z, self._ctr[Ctr.VEVALS],
                         dense_stride(self.period_s) * (t0 - t1))

    def _accumulate(self, ms: np.ndarray, sq: np.ndarray, k: int, step_s: float) -> None:
        """Running mean over the first evaluations, then exponential (TAU_S); winsorised."""
        if k > MIN_EVALUATIONS:  # winsorise, unless clipped CLIP_RUN times in a row (a change)
            nclip = self._nclip_v if ms is self.ms_v else self._nclip
            lim, over = self._tmp, self._over
            np.multiply(ms, CLIP_SIGMAS * CLIP_SIGMAS, out=lim)
            np.greater(sq, lim, out=over)
            if over.any():
                nclip += 1
                nclip *= over
                lim[nclip >= CLIP_RUN] = np.inf
                np.minimum(sq, lim, out=sq)
            else:
                nclip.fill(0)
        a = min(1.0, max(1.0 / k, step_s / TAU_S))
        sq -= ms
        sq *= a
        ms += sq

    # -- estimates -----------------------------------------------------------------------
    @property
    def ready(self) -> bool:
        return self.evaluations >= MIN_EVALUATIONS

    @property
    def velocity_ready(self) -> bool:
        return self.velocity_evaluations >= MIN_EVALUATIONS

    def position(self, out: np.ndarray) -> np.ndarray:
        np.sqrt(np.maximum(self.ms, 0.0, out=out), out=out)
        return out

    def white(self, out: np.ndarray) -> np.ndarray:
        """The white level per joint (rad): third differences of consecutive samples."""
        np.sqrt(np.maximum(self.ms_w, 0.0, out=out), out=out)
        return out

    def velocity(self, out: np.ndarray) -> np.ndarray:
        np.sqrt(np.maximum(self.ms_v, 0.0, out=out), out=out)
        return out


def white_level_of_coloured(sigma: float, tau_s: float, f_hz: float, rate_hz: float) -> float:
    """The white-noise std with the same spectral density at f_hz as first-order low-pass
    (Ornstein-Uhlenbeck) noise of std sigma and correlation time tau_s, sampled at rate_hz
    (what this estimator reports for such noise, to first order; used by the tests)."""
    return sigma * math.sqrt(2.0 * tau_s * rate_hz / (1.0 + (2.0 * math.pi * f_hz * tau_s) ** 2))
