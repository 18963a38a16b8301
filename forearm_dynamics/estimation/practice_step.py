"""The practice filter's per-sample arithmetic as two compiled calls (_practice_step.c).

Why: issue 29 item 5 gives the default estimator +20 µs of a torque node's callback over the
backward difference. With velocities (an encoder, the node benchmark) the budget was met in
stop 43; with positions only the practice filter runs on its noisy joints (practice_output.py)
and the callback was +40 µs over `backward`: the filter's ring and taps, the blend's window,
sums and fade were ~25 numpy calls per sample (update() at 1 kHz positions only: 50 µs
against 21 for the model alone, offline), each a few µs on a node's cold caches. Here they
are two calls: `push` (PracticeFIR.push) and `output` (_practice_filter_output).

The numbers are numpy's to rounding: the same products and sums in the same order, built
without fused multiply-add; the two sums numpy hands to BLAS (the FIR's taps over its window,
the practice's kernel over the blend's), whose order depends on the CPU, are summed in order
here, so those round differently (test_practice_step.py bounds the difference over whole
streams). The counters the two sides share live in int64 arrays (PracticeFIR._c,
PracticeWindow._c, PracticeBlend._c), so a sample may go either way.

The extension is optional (setup.py: the Kalman step's extension); without it, or for
arrays it cannot take (not contiguous float64), the filter runs numpy's way, the reference.
"""

from __future__ import annotations

import numpy as np

try:
    from ._kalman_step import Practice
except ImportError:  # pragma: no cover - built without a C compiler: numpy's way
    Practice = None


def bind(fir, blend, pf_w: np.ndarray, target: np.ndarray, use: np.ndarray, qdd: np.ndarray,
         share: float, fade_s: float):
    """A Practice on a configured PracticeFIR's and PracticeBlend's arrays and the output's
    (pf_w, target, use: practice_output.py; qdd: the output's q̈ row), written in place; None
    without the extension. Bind again after either's configure() (new rings)."""
    if Practice is None:
        return None
    win = blend._win
    return Practice(fir._ring, fir._w, fir._last, fir.out, fir._c, blend.disagreement,
                    win._q, win._x, win.k, win.ref, blend._s, blend.share, win._c, blend._c,
                    pf_w, target, use, qdd,
                    (fir.K, win.h, win.every, fir.dt, fir._sum, blend._fast, blend._alpha,
                     float(share), float(fade_s)))


def available() -> bool:
    """Whether the compiled step was built (the filter uses it)."""
    return Practice is not None
