"""The muscle node's per-sample arithmetic around the QP as two compiled calls (_muscle_step.c).

Why: issue 31 gives muscle_node's callback 250 µs at 1 kHz. In a node that sleeps between
samples each numpy call costs several µs, not the ~1 µs of a loop (caches and the CPU's state
cool while it sleeps), and the callback's arithmetic outside daqp was ~45 numpy calls: the
surrogate's clip, monomial steps and sparse product, V = -R q̇, the curves (17 calls), the QP's
matrix, and the result's clip, product, reserves and forces. Paced at 1 kHz in process
(`python -m benchmarks.muscle_callback`, quiet machine) geometry + set-up + result took
~190 µs of the callback's ~350 µs; the compiled calls: docs/muscles.md.

The numbers are numpy's to rounding: the same operations in the same order without fused
multiply-add; exp and asinh (libm's, not numpy's) and the sums numpy gives to BLAS (V, A·a)
may round differently (test_muscle_step.py bounds the two paths over whole movements).

The extension is optional, like the Kalman filter's (estimation/kalman_step.py): setup.py
builds it where a C compiler is; without it, or for a model it does not cover (pennate
muscles, passive forces), StaticOptimizer.solve_sample_into runs numpy's way, the reference.
"""

from __future__ import annotations

import numpy as np

try:
    from ._muscle_step import Step
except ImportError:  # pragma: no cover - built without a C compiler: numpy's way
    Step = None


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, np.int64)


def bind(surrogate, unit, geo_buffer: np.ndarray, V: np.ndarray, A: np.ndarray,
         rhs_u: np.ndarray, rhs_l: np.ndarray, rows: np.ndarray | None = None):
    """A Step on these arrays, or None (no extension, or curves it does not compute).

    surrogate: the model's Surrogate (its tables and scratch); unit: the optimizer's
    UnitForces (its constants); geo_buffer: the one buffer a geometry_outputs() pair (R, L)
    views ([L (n); R (n, 20) flat]); V (n,), A (20, n), rhs_u, rhs_l (20,): written each
    sample, as numpy's path writes them. rows: the order the sparse product takes the
    non-empty rows in, longest first (the default; the kernel refuses any other order)."""
    if Step is None or unit.pennate or unit.passive:
        return None
    s = surrogate
    first, steps = s.plan_tables()
    _, _, indptr, indices, data = s._full
    if rows is None:
        length = np.diff(indptr)
        rows = np.argsort(-length, kind="stable")[: np.count_nonzero(length)]
    return Step(s.center, s.inv_half, _i64(first), *(_i64(t) for t in steps), _i64(indptr),
                np.ascontiguousarray(indices, np.int32), np.ascontiguousarray(data), _i64(rows),
                unit.lts, unit.inv_l0,
                np.broadcast_to(unit.v_scale, unit.lts.shape).copy(), unit.f0_d1, unit.f0_d4,
                unit.f0, s._xe, s._mono, geo_buffer, V, unit._unit, A, rhs_u, rhs_l,
                bool(unit.use_velocity))


def available() -> bool:
    """Whether the compiled step was built (muscle_node uses it)."""
    return Step is not None
