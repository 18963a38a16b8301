"""Moment arms and muscle-tendon lengths as polynomials of the posture (the fast path).

Why polynomials: the exact path geometry (wrapping surfaces) costs ~200 µs per posture in
MuJoCo and ~66 ms in OpenSim; a polynomial of the joints a muscle crosses costs a few µs and
is fitted offline to the source's own moment arms (fit.py). Each muscle's polynomials use the
normalised joint angles x = (q − centre) / half_range of the fit box (the README ranges);
a posture outside the box is held at its edge (x clipped to [−1, 1]): polynomials do not
extrapolate, and the geometry there was not fitted.

Evaluation: every distinct monomial of every muscle is evaluated once (products of at most
`degree` factors of [1, x0..x19], gathered by index), then one sparse matrix maps the
monomials to the n lengths and the spanned (muscle, joint) moment arms.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse

from ..description import JOINT_NAMES

_CHUNK = 2048  # samples per block in the batch path (memory: chunk × monomials)


class Surrogate:
    """Lengths (n,) and moment arms (n, 20) of a posture, from fitted polynomials."""

    def __init__(self, center: np.ndarray, half: np.ndarray, factors: np.ndarray,
                 coef: sparse.csr_matrix, pair_rows: np.ndarray, pair_cols: np.ndarray,
                 n: int):
        self.center = center
        self.inv_half = 1.0 / half
        self.factors = factors  # (degree, K) indices into [1, x0..x19]
        self.coef = coef  # (n + n_pairs, K)
        self.pair_rows, self.pair_cols = pair_rows, pair_cols
        self.pair_flat = pair_rows * len(JOINT_NAMES) + pair_cols
        self.n = n
        self._xe = np.ones(len(JOINT_NAMES) + 1)

    @classmethod
    def from_doc(cls, joints: dict, spans: Sequence[Sequence[str]], rows: Sequence[dict], *,
                 length_scale: np.ndarray, joint_scale: np.ndarray) -> Surrogate:
        """Build from the file's `joints` and each muscle's `surrogate` (see fit.py)."""
        nj = len(JOINT_NAMES)
        center = np.asarray(joints["center"], float)
        half = np.asarray(joints["half_range"], float)
        if center.shape != (nj,) or half.shape != (nj,) or np.any(half <= 0):
            raise ValueError("joints.center / half_range must be 20 numbers (half_range > 0)")
        index: dict[tuple[int, ...], int] = {}
        data, ri, ci = [], [], []
        pair_rows, pair_cols = [], []
        n = len(rows)
        n_pairs = sum(len(s) for s in spans)
        pair_base = n
        for m, (span, row) in enumerate(zip(spans, rows)):
            cols = [JOINT_NAMES.index(j) for j in span]
            exps = np.asarray(row["exponents"], int)
            if exps.ndim != 2 or exps.shape[1] != len(cols) or np.any(exps < 0):
                raise ValueError(f"muscle #{m}: exponents must be (K, {len(cols)}) non-negative")
            length = np.asarray(row["length"], float)
            arms = row["moment_arms"]
            if length.shape != (len(exps),) or set(arms) != set(span):
                raise ValueError(f"muscle #{m}: length / moment_arms do not match exponents")
            keys = []
            for e in exps:
                g = np.zeros(nj, int)
                g[cols] = e
                key = tuple(g)
                if key not in index:
                    index[key] = len(index)
                keys.append(index[key])
            keys = np.asarray(keys)
            ri += [m] * len(keys)
            ci += keys.tolist()
            data += (length * length_scale[m]).tolist()
            for j, c in zip(span, cols):
                a = np.asarray(arms[j], float)
                if a.shape != (len(exps),):
                    raise ValueError(f"muscle #{m}: moment arm about {j} has the wrong length")
                ri += [pair_base] * len(keys)
                ci += keys.tolist()
                data += (a * joint_scale[c]).tolist()
                pair_rows.append(m)
                pair_cols.append(c)
                pair_base += 1
        if not np.all(np.isfinite(data)):
            raise ValueError("coefficients must be finite")
        degree = max(sum(k) for k in index)
        factors = np.zeros((max(degree, 1), len(index)), int)
        for key, k in index.items():
            idx = [j + 1 for j, e in enumerate(key) for _ in range(e)]
            factors[: len(idx), k] = idx
        coef = sparse.csr_matrix((data, (ri, ci)), shape=(n + n_pairs, len(index)))
        coef.sum_duplicates()
        return cls(center, half, factors, coef, np.asarray(pair_rows), np.asarray(pair_cols), n)

    @property
    def n_monomials(self) -> int:
        return self.factors.shape[1]

    def _x(self, q: np.ndarray) -> np.ndarray:
        return np.clip((q - self.center) * self.inv_half, -1.0, 1.0)

    def evaluate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One posture (20,) -> (moment arms (n, 20), lengths (n,))."""
        xe = self._xe
        xe[1:] = self._x(q)
        f = self.factors
        mono = xe[f[0]]
        for k in range(1, f.shape[0]):
            mono = mono * xe[f[k]]
        vals = self.coef @ mono
        R = np.zeros(self.n * len(JOINT_NAMES))
        R[self.pair_flat] = vals[self.n:]
        return R.reshape(self.n, len(JOINT_NAMES)), vals[: self.n]

    def _batch(self, q: np.ndarray) -> np.ndarray:
        out = np.empty((len(q), self.coef.shape[0]))
        for s in range(0, len(q), _CHUNK):
            x = self._x(q[s:s + _CHUNK])
            xe = np.concatenate([np.ones((len(x), 1)), x], axis=1)
            mono = xe[:, self.factors[0]]
            for k in range(1, self.factors.shape[0]):
                mono *= xe[:, self.factors[k]]
            out[s:s + _CHUNK] = (self.coef @ mono.T).T
        return out

    def moment_arms(self, q: np.ndarray) -> np.ndarray:
        if q.ndim == 1:
            return self.evaluate(q)[0]
        vals = self._batch(q)
        R = np.zeros((len(q), self.n * len(JOINT_NAMES)))
        R[:, self.pair_flat] = vals[:, self.n:]
        return R.reshape(len(q), self.n, len(JOINT_NAMES))

    def lengths(self, q: np.ndarray) -> np.ndarray:
        if q.ndim == 1:
            return self.evaluate(q)[1]
        return self._batch(q)[:, : self.n]
