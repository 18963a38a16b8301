"""Where the noise estimator (noise.py) keeps its samples: the rings, the rate, the counters.

Why a module of its own: storing a sample is the per-sample half of the estimator and the
half that is compiled (noise_step.py: one C call, the same arrays); the evaluations, one
sample in ~4 at 1 kHz, read what is stored here and are noise.py's (the compiled call makes
them too, on noise.py's arrays: `_evaluated`). The counters and the rate live in two small
arrays (`_ctr`: Ctr, `_rate`: Rate) so that the compiled store and `_store`, its Python
reference, move the same state. They are array.array, not numpy: the
filter reads period_s on every sample, and an array.array's element is a Python float at a
list's cost, where a numpy element is a scalar conversion (µs on a node's cold caches: the
filter's update() p50 went 20 -> 25 µs in the node with numpy's). `_store` also does what the
compiled store leaves to it (NOT_STORED): the first steps, a new rate (a new stride and
ring).

The rate: the first step sets the nominal period and the stride. A step longer than
GAP_PERIODS x the nominal, and at least GAP_MIN_S, is a gap (no difference spans it); a
shorter stall is jitter. A slow mean of the steps (RATE_ALPHA) tells a new rate from
jitter: past NOMINAL_TOL off the nominal, the nominal follows it and the stride stays; past
NEW_RATE off the period the stride was set for, a new stride. (Measured against the nominal,
which follows the mean, the second never happened: a stream that went from 1 kHz to 500 Hz
kept blocks of 50 samples, 100 ms, and measured its noise at 5 Hz, inside the movement's
band.)
"""

from __future__ import annotations

from array import array

import numpy as np

from . import noise_step
from .compiled import BindsCompiled

GAP_PERIODS = 3.0
RATE_ALPHA = 0.005  # weight of one step in the mean period that tells a new rate from jitter
#: the nominal period (period_s) follows the mean once they differ by more than this; the
#: stride stays (a new stride only past NEW_RATE). The first step sets both, and a stream
#: stamped by a publisher's clock can start 17 % off its rate (a node benchmark's 1.168 ms at
#: 1 kHz): the filter's groups, seated at the nominal period, then ran their covariance
#: recursion on every sample (2 of them: 34-57 µs of the update in the node)
NOMINAL_TOL = 0.02
NEW_RATE = 0.25  # the mean step this far from the nominal: a new rate, a new stride
SAME_NS = 1000  # steps within this (ns) are the same length: uniform stamps
GAP_MIN_S = 0.04  # a step shorter than this is never a gap: a late publisher, not a lost sensor
#: above ~400 Hz (a period under DENSE_PERIOD_S) the white and velocity differences take every
#: DENSE_STRIDE-th window of consecutive samples, not every one
DENSE_PERIOD_S = 2.5e-3
DENSE_STRIDE = 8


def dense_stride(dt: float) -> int:
    """Every how many windows the white and velocity differences take one at period dt
    (s; 0 before the first step): DENSE_STRIDE above ~400 Hz, else every one. The stores and
    the evaluations that weight their steps use this one rule."""
    return DENSE_STRIDE if 0.0 < dt < DENSE_PERIOD_S else 1


#: what a stored sample makes due (SampleRings.store; the compiled store returns the same)
WHITE_DUE, POSITION_DUE, VELOCITY_DUE = 1, 2, 4
NOT_STORED = -1  # the compiled store left the sample to _store (a first step, a new rate)


class Ctr:
    """Indices into SampleRings._ctr (int64): what a stored sample moves, shared with the
    compiled store (_noise_step.c reads and writes the same array). Plain ints, not an
    IntEnum: an enum member's lookup costs µs on a node's cold caches, and these are read on
    every sample."""

    STARTED = 0  # ORIGIN is set (the first sample's stamp: times are relative to it)
    ORIGIN = 1
    HAS_LAST = 2  # LAST_NS is the previous sample's stamp (none after a restart)
    LAST_NS = 3
    LAST_D = 4  # the last step (ns)
    SAME = 5  # consecutive steps of the same length (to 1 us): uniform weights
    COUNT = 6  # samples in the position ring since its last restart
    WCOUNT = 7  # ... in the white window
    VCOUNT = 8  # ... in the velocity window
    CAP = 9  # the position ring's samples (blocks x STRIDE; 0 before the first step)
    STRIDE = 10  # samples per block
    EVERY = 11  # samples between position evaluations
    WEVALS = 12  # white evaluations made (noise.py's; the compiled store makes them too)
    VEVALS = 13  # velocity evaluations made
    PEVALS = 14  # position evaluations made
    IRREGULAR = 15  # position evaluations skipped: a jittered window's blocks do not compare


class Rate:
    """Indices into SampleRings._rate (float64, s), shared with the compiled store."""

    DT = 0  # the nominal period (period_s): follows the mean within NOMINAL_TOL
    DT_AVG = 1  # the mean step, slow (RATE_ALPHA): tells a new rate from jitter
    STRIDE_DT = 2  # the period the stride was set for: past NEW_RATE off it, a new stride



def fields(layout: type) -> list[str]:
    """A layout's (Ctr's, Rate's) field names in index order: what _noise_step.c's FIELDS
    lists, and how long the array is."""
    return sorted((k for k, v in vars(layout).items() if k.isupper() and isinstance(v, int)),
                  key=lambda k: getattr(layout, k))


class SampleRings(BindsCompiled):
    """A noise estimator's stored samples: the position ring (each sample twice, so that a
    window is a view), the white and velocity windows, the rate and the counters."""

    def __init__(self, n: int, spacing_s: float, every_s: float, blocks: int):
        """n joints; the position ring holds `blocks` blocks of samples spacing_s apart, an
        evaluation every every_s (noise.py's SPACING_S, EVERY_S, ORDER + 1)."""
        self.n = n
        self._spacing_s, self._every_s, self._blocks = spacing_s, every_s, blocks
        self._ctr = array("q", bytes(8 * len(fields(Ctr))))  # counters, stamps (Ctr): shared
        self._rate = array("d", bytes(8 * len(fields(Rate))))  # the periods (Rate, s): shared
        self._raw = np.zeros((0, n))  # the last blocks x stride samples, a ring (twice)
        self._rawt = np.zeros(0)  # their times (s)
        self._wring = np.zeros((4, n))  # the white difference's four samples
        self._wt = np.zeros(4)  # their times (s)
        self._vring = np.zeros((3, n))  # the velocity difference's three samples
        self._vt = np.zeros(3)
        self._fast = None
        self._compiled = True  # python_store() turns it off: the reference the tests compare
        self._bind()

    def python_store(self) -> SampleRings:
        """Store in Python from now on, after a new rate too (the compiled store's reference:
        test_noise_step.py, benchmarks/compiled_cost.py); returns self."""
        self._compiled = False
        self._fast = None
        return self

    def _bind(self) -> None:
        """The compiled store on this estimator's arrays (noise_step.py; None: Python's way)."""
        if not self._compiled:
            return
        arrays, constants = self._evaluated()
        self._fast = noise_step.bind(self._ctr, self._rate, self._raw, self._rawt, self._wring,
                                     self._wt, self._vring, self._vt, *arrays,
                                     fields(Ctr) + fields(Rate),
                                     (GAP_PERIODS, GAP_MIN_S, RATE_ALPHA, NOMINAL_TOL, NEW_RATE,
                                      DENSE_PERIOD_S, DENSE_STRIDE, SAME_NS, *constants))

    def _evaluated(self) -> tuple[tuple[np.ndarray, ...], tuple]:
        """What the compiled store's evaluations write, and their constants: the estimator's
        (noise.NoiseEstimator: the white, velocity and position mean squares and the clip
        runs; TAU_S, CLIP_SIGMAS, CLIP_RUN, MIN_EVALUATIONS, WINDOW_STRETCH,
        BLOCK_SPREAD_RATIO, MIN_BLOCK)."""
        raise NotImplementedError

    # -- configuration -------------------------------------------------------------------
    def _configure(self, dt: float) -> None:
        """Stride and ring for sample period dt (on the first step and when the rate changes)."""
        ctr = self._ctr
        self._rate[Rate.DT] = self._rate[Rate.STRIDE_DT] = dt
        stride = ctr[Ctr.STRIDE] = max(1, round(self._spacing_s / dt))
        ctr[Ctr.EVERY] = max(1, round(self._every_s / dt))
        cap = self._blocks * stride  # the samples one evaluation spans
        if cap != ctr[Ctr.CAP]:
            ctr[Ctr.CAP] = cap
            self._raw = np.zeros((2 * cap, self.n))  # each sample twice: a window is a view
            self._rawt = np.zeros(2 * cap)
            self._bind()
        ctr[Ctr.COUNT] = 0

    def shift(self, offset: np.ndarray) -> None:
        """A discontinuity of `offset` (n,) at the newest sample: the stored samples are moved
        by it, so the difference window continues across the jump without seeing it."""
        self._ctr[Ctr.WCOUNT] = 0
        if self._ctr[Ctr.CAP]:
            self._raw += offset
        self._ctr[Ctr.VCOUNT] = 0

    def restart(self) -> None:
        """No difference across this point (a gap, a re-initialised filter); estimates stay."""
        for i in (Ctr.COUNT, Ctr.VCOUNT, Ctr.WCOUNT, Ctr.HAS_LAST, Ctr.SAME):
            self._ctr[i] = 0

    # -- samples -------------------------------------------------------------------------
    def store(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> int:
        """The sample at t_ns (positions, and velocities or None) into the rings; returns
        the evaluations it makes due (WHITE_DUE | POSITION_DUE | VELOCITY_DUE)."""
        if self._fast is not None:
            try:
                due = self._fast.store(t_ns, q, qd)
                if due != NOT_STORED:
                    return due
            except (TypeError, ValueError, BufferError):  # not contiguous float64: Python's way
                pass
        return self._store(t_ns, q, qd)

    def _store(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> int:
        """The sample into the rings (and the rate, the counters); returns the evaluations it
        makes due (WHITE_DUE | POSITION_DUE | VELOCITY_DUE). _noise_step.c does the same for
        every sample after the first steps, and leaves a new rate (NOT_STORED) to this."""
        ctr, rate = self._ctr, self._rate
        if not ctr[Ctr.STARTED]:
            ctr[Ctr.STARTED] = 1
            ctr[Ctr.ORIGIN] = t_ns
        t_s = (t_ns - ctr[Ctr.ORIGIN]) * 1e-9  # relative: full float precision
        had_last = ctr[Ctr.HAS_LAST]
        last = ctr[Ctr.LAST_NS]
        ctr[Ctr.LAST_NS] = t_ns
        ctr[Ctr.HAS_LAST] = 1
        if had_last:
            d = t_ns - last
            dt = d * 1e-9
            nominal = rate[Rate.DT]
            if not nominal:  # the first step sets the stride
                self._configure(dt)
                rate[Rate.DT_AVG] = dt
            elif dt > max(GAP_PERIODS * nominal, GAP_MIN_S):  # a gap: no difference spans it
                ctr[Ctr.COUNT] = ctr[Ctr.VCOUNT] = ctr[Ctr.WCOUNT] = 0
            else:  # a new rate (not jitter: the mean moves) reconfigures the stride
                # a slow mean (~200 samples): a stall and its catch-up burst average out
                # (with 0.05 one 20 ms stall moved it 100 %: 241 restarts in 4 s of make
                # demo's stamps, the estimate never ready)
                avg = rate[Rate.DT_AVG]
                avg += RATE_ALPHA * (dt - avg)
                rate[Rate.DT_AVG] = avg
                strided = rate[Rate.STRIDE_DT]
                if abs(avg - strided) > NEW_RATE * strided:
                    self._configure(avg)
                elif abs(avg - nominal) > NOMINAL_TOL * nominal:  # the nominal follows the mean
                    rate[Rate.DT] = avg
            same = abs(d - ctr[Ctr.LAST_D]) <= SAME_NS
            ctr[Ctr.SAME] = ctr[Ctr.SAME] + 1 if same else 0
            ctr[Ctr.LAST_D] = d
        due = 0
        dt = rate[Rate.DT]
        if ctr[Ctr.STRIDE]:
            due |= self._store_white(t_s, q, dt) | self._store_position(t_s, q)
        if qd is not None:
            due |= self._store_velocity(t_s, qd, dt)
        return due

    def _store_white(self, t_s: float, q: np.ndarray, dt: float) -> int:
        """Every 8th window of four consecutive samples above ~400 Hz (every one below)."""
        ctr = self._ctr
        c = ctr[Ctr.WCOUNT]
        h = c % 4
        wstride = dense_stride(dt)
        ctr[Ctr.WCOUNT] = c = c + 1
        if (-c) % wstride >= 4:
            return 0
        np.copyto(self._wring[h], q)
        self._wt[h] = t_s
        return 0 if c % wstride or c < 4 else WHITE_DUE

    def _store_position(self, t_s: float, q: np.ndarray) -> int:
        """Keep the sample; every EVERY samples, an evaluation is due. The block sums are
        taken at the evaluation from the raw ring, not kept as a moving sum updated per
        sample: that was 4 numpy calls on every sample for an evaluation every 20 at 1 kHz."""
        ctr = self._ctr
        cap = ctr[Ctr.CAP]
        c = ctr[Ctr.COUNT]
        h = c % cap
        self._raw[h] = self._raw[h + cap] = q
        self._rawt[h] = self._rawt[h + cap] = t_s
        ctr[Ctr.COUNT] = c = c + 1
        return 0 if c < cap or c % ctr[Ctr.EVERY] else POSITION_DUE

    def _store_velocity(self, t_s: float, qd: np.ndarray, dt: float) -> int:
        """The three samples each velocity evaluation uses (every 8th above ~400 Hz)."""
        ctr = self._ctr
        c = ctr[Ctr.VCOUNT] + 1
        ctr[Ctr.VCOUNT] = c
        vstride = dense_stride(dt)
        if (-c) % vstride >= 3:  # not one of the three samples the next evaluation uses
            return 0
        h = c % 3
        self._vring[h] = qd
        self._vt[h] = t_s
        return 0 if c < 3 or c % vstride else VELOCITY_DUE

    @property
    def period_s(self) -> float:
        """The nominal sample period (s) the stride was set for (0 before the first step)."""
        return self._rate[Rate.DT]
