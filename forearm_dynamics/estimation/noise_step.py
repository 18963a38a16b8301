"""The noise estimator's per-sample store and its evaluations as one compiled call (_noise_step.c).

Why: issue 29 item 5 gives the default estimator +20 µs of a torque node's callback over the
backward difference, and after the Kalman's compiled step (kalman_step.py) the noise
statistics' bookkeeping was most of what was left: NoiseEstimator.add took 22-27 µs p50
paced at 1 kHz offline (a 0.9 ms sleep before each call, jittered stamps), 4-7 µs back to
back; with the compiled store 3-4 µs paced (benchmarks/compiled_cost.py --part noise,
docs/performance.md).
In a node each numpy call and each Python line costs several times what it does in a loop
(the process sleeps between samples and its caches go cold), and storing a sample was ~40
lines and 4-6 numpy calls: the rate, the counters, three rings. The compiled store
does all of it in one call (noise_store.SampleRings.store). What it makes due, an
evaluation, comes on one sample in ~4 at 1 kHz: the white and the velocity differences on
every 8th window each, the position one every 20th sample. In Python they were 10-25 numpy
calls each, 40-300 µs on the node's cold caches (the probe's learn(): p50 5 µs, p90 88-101,
p99 250-290), so the store makes them too, in the same call (noise.py's evaluations are
the reference, and run where the store leaves a sample to Python). The C code does
Python's operations in Python's order, built without fused multiply-add: numpy's pairwise
sum where noise.py sums a block's stamps, and the weighted sums that np.dot handed to BLAS
(whose order depends on the CPU) summed in order on both sides (noise._weighted_rows). So
the estimates are the same numbers with and without it (test_noise_step.py); against the
np.dot of before they moved by at most 2e-13 (relative).

The extension is optional: setup.py builds it where a C compiler is (`pip install`,
`colcon build`); without it, or for arrays it cannot take (not contiguous float64), the
estimator stores in Python (SampleRings._store), the reference the tests compare it with.
"""

from __future__ import annotations

import numpy as np

try:
    from ._noise_step import FIELDS, Store
except ImportError:  # pragma: no cover - built without a C compiler: Python's way
    FIELDS, Store = "", None


def bind(ctr: np.ndarray, rate: np.ndarray, raw: np.ndarray, rawt: np.ndarray,
         wring: np.ndarray, wt: np.ndarray, vring: np.ndarray, vt: np.ndarray,
         ms_w: np.ndarray, ms_v: np.ndarray, nclip_v: np.ndarray, ms: np.ndarray,
         nclip: np.ndarray, fields: list[str], params: tuple):
    """A Store on the estimator's own arrays (written in place), or None without the
    extension. `fields`: noise_store.Ctr's names, then Rate's, in order, which must be the
    extension's (a RuntimeError otherwise: the two would read each other's counters); `params`: the
    constants _noise_step.c's header lists, from noise_store.py and noise.py."""
    if Store is None:
        return None
    if fields != FIELDS.split():
        raise RuntimeError(f"noise_store's fields {fields} are not _noise_step.c's "
                           f"{FIELDS.split()}: rebuild the extension (pip install / colcon build)")
    return Store(ctr, rate, raw, rawt, wring, wt, vring, vt, ms_w, ms_v, nclip_v, ms, nclip,
                 params)


def available() -> bool:
    """Whether the compiled store was built (the estimator uses it)."""
    return Store is not None
