"""The Kalman filter's per-sample arithmetic as two compiled calls (_kalman_step.c), and its
noise groups' covariance step as a third (Gains: noise_groups.py says why).

Why: issue 29 item 5 gives the default estimator +20 µs of a torque node's callback over the
backward difference. In a node at 1 kHz each numpy call costs a few µs, not the ~0.5 µs of a
loop (the process sleeps between samples and its caches go cold), and the filter's predict,
innovations, gate maximum, correction and the copies after it were 14 of them. The 11
arithmetic ones took 22-25 µs paced at 1 kHz offline (a 0.9 ms sleep before each call),
3 µs as two C calls (/tmp timing, load ~1; in the node: docs/performance.md). The numbers
are numpy's to rounding: the same products and sums in the same order, built without fused
multiply-add; only the prediction's sum of three products may round differently from
BLAS's (test_kalman_step.py bounds the two paths' difference over whole streams).

The extension is optional: setup.py builds it where a C compiler is (`pip install`,
`colcon build`); without it, or for arrays it cannot take (not contiguous float64), the
filter runs numpy's way, the reference the tests compare it with.
"""

from __future__ import annotations

import numpy as np

try:
    from . import _kalman_step
    from ._kalman_step import Gains, Step
except ImportError:  # pragma: no cover - built without a C compiler: numpy's way
    _kalman_step = Gains = Step = None


def bind(x: np.ndarray, t3: np.ndarray, e: np.ndarray, kp: np.ndarray, kv: np.ndarray,
         out: np.ndarray, keep_q: np.ndarray, keep_qd: np.ndarray):
    """A Step on the filter's own arrays (written in place), or None without the extension.

    Step.predict_innovate(q, qd_or_None, dt) -> max |e[0]|: t3 = F(dt) x, e = (q, qd) - t3[:2];
    Step.correct(vel, q_or_None, qd_or_None, copy_out): x = kp * e[0] (+ kv * e[1]) + t3,
    then keep_q = q and keep_qd = qd where given (the sample the noise statistics take after
    the output), out = x if copy_out (the causal output)."""
    return None if Step is None else Step(x, t3, e, kp, kv, out, keep_q, keep_qd)


def bind_gains(state: np.ndarray, layout: dict[str, int], gidx: np.ndarray, r_gate: np.ndarray,
               kp: np.ndarray, kv: np.ndarray, sig: np.ndarray):
    """A Gains on the noise groups' state (G, WIDTH) and the filter's per-joint arrays, or None
    without the extension or without a group.

    Gains.step(dt, period, psd, vel, jitter) -> 1, 0 or -1: the covariance step of groups
    seated at their steady state (noise_groups.py), the gains written into kp, kv and the
    innovation stds into sig (1), nothing to do (0), or a group that is not seated (-1:
    nothing written, Python's loop runs). `layout` (column name -> index) must be the
    extension's: a layout that is not raises RuntimeError (a stale build)."""
    if Gains is None or not len(state):
        return None
    for name, at in layout.items():
        if getattr(_kalman_step, name, None) != at:
            raise RuntimeError(f"_kalman_step's group column {name} is not {at}: rebuild the "
                               "extension (pip install / colcon build)")
    return Gains(state, gidx, r_gate, kp, kv, sig)


def available() -> bool:
    """Whether the compiled step was built (the filter uses it)."""
    return Step is not None
