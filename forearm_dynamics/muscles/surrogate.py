"""Moment arms and muscle-tendon lengths as polynomials of the posture (the fast path).

Why polynomials: the exact path geometry (wrapping surfaces) costs ~200 µs per posture in
MuJoCo and ~66 ms in OpenSim; a polynomial of the joints a muscle crosses costs a few µs and
is fitted offline to the source's own moment arms (fit.py). Each muscle's polynomials use the
normalised joint angles x = (q − centre) / half_range of the fit box (the README ranges);
a posture outside the box is held at its edge (x clipped to [−1, 1]): polynomials do not
extrapolate, and the geometry there was not fitted.

Evaluation: every distinct monomial of every muscle is evaluated once, then one sparse matrix
maps the monomials to the n lengths and the spanned (muscle, joint) moment arms. A monomial
of degree d >= 2 is the product of two of degree ⌊d/2⌋ and ⌈d/2⌉ (its divisors: each
muscle's set of monomials holds every divisor of its members, fit_core.refine_pairs), so the
monomials come in ⌈log2 D⌉ + 1 vectorised steps (degree 1, 2, 3-4, 5-8, 9-16, 17-32), not D:
a pair fitted to degree 20 (FCU about the wrist) costs 6 steps, not 20 (each ~1-2 µs of
NumPy call overhead per sample).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse

from ..description import JOINT_NAMES

try:  # what `csr_matrix @ vector` runs, without its Python-level checks (~6 µs a sample)
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec
except ImportError:  # pragma: no cover - a scipy that moved it: the public product
    _csr_matvec = None
try:  # np.clip's ufunc without np.clip's Python wrapper (~5 µs): max then min in one call
    from numpy._core.umath import clip as clip_ufunc
except ImportError:  # pragma: no cover - a numpy that moved it: the two ufuncs it replaces
    def clip_ufunc(x, lo, hi, out):
        np.maximum(x, lo, out=out)
        return np.minimum(out, hi, out=out)

_CHUNK = 2048  # samples per block in the batch path (memory: chunk × monomials)
#: Coefficients dropped per row while the sum of their magnitudes stays below this (m): on
#: the clipped box every |monomial| <= 1, so a row moves by at most PRUNE_M (0.02 mm) and the
#: sparse product, most of the cost, shrinks by ~28 % (36 128 -> 26 174 terms, shipped file).
PRUNE_M = 2e-5


def _prune(coef: sparse.csr_matrix, budget: float) -> sparse.csr_matrix:
    """Drop each row's smallest coefficients while their |sum| bound stays <= budget."""
    keep = np.ones(coef.nnz, bool)
    for r in range(coef.shape[0]):
        a, b = coef.indptr[r], coef.indptr[r + 1]
        order = np.argsort(np.abs(coef.data[a:b]))
        n_drop = int(np.searchsorted(np.cumsum(np.abs(coef.data[a:b])[order]), budget,
                                     side="right"))
        keep[a + order[:n_drop]] = False
    out = coef.copy()
    out.data[~keep] = 0.0
    out.eliminate_zeros()
    return out


class Surrogate:
    """Lengths (n,) and moment arms (n, 20) of a posture, from fitted polynomials."""

    def __init__(self, center: np.ndarray, half: np.ndarray, keys: list[tuple[int, ...]],
                 coef: sparse.csr_matrix, pair_rows: np.ndarray, pair_cols: np.ndarray,
                 n: int):
        """keys: the monomials' exponent tuples (20 ints), sorted by degree, the constant
        first; coef's columns in that order."""
        self.center = center
        self.half = half
        self.inv_half = 1.0 / half
        self.keys = np.asarray(keys, int).reshape(-1, len(JOINT_NAMES))  # (K, 20) exponents
        self.coef = coef  # (n + n_pairs, K): pruned and scaled, the only coefficients used
        self.pair_rows, self.pair_cols = pair_rows, pair_cols
        self.pair_flat = pair_rows * len(JOINT_NAMES) + pair_cols
        self.n = n
        self._xe = np.ones(len(JOINT_NAMES) + 1)
        self._mono = np.ones(len(keys))
        self._vals = np.zeros(coef.shape[0])
        pos = {k: i for i, k in enumerate(keys)}
        degree = np.array([sum(k) for k in keys])
        if len(keys) == 0 or degree[0] != 0 or np.any(np.diff(degree) < 0):
            raise ValueError("monomials must be sorted by degree, the constant first")
        self.levels = []  # (slice, first parents, second parents) per step
        top = int(degree.max())
        bounds = [1] + [2 ** s for s in range(1, max(1, (top - 1).bit_length()) + 1)]
        variables = np.zeros(len(keys), int)  # degree 1: the variable (index into [1, x...])
        for lo_d, hi_d in zip([1] + [b + 1 for b in bounds[:-1]], bounds):
            at = np.nonzero((degree >= lo_d) & (degree <= hi_d))[0]
            if len(at) == 0:
                continue
            pa, pb = [], []
            for i in at:
                k = np.array(keys[i])
                if lo_d == 1:  # x_j = 1 · x_j: the constant times the variable
                    variables[i] = int(np.nonzero(k)[0][0]) + 1
                    pa.append(0)
                    continue
                half_d, a = sum(keys[i]) // 2, np.zeros_like(k)
                for j in np.nonzero(k)[0]:  # the first ⌊d/2⌋ exponents, in joint order
                    a[j] = min(k[j], half_d - a.sum())
                pa.append(pos[tuple(a)])
                pb.append(pos[tuple(k - a)])
            self.levels.append((slice(int(at[0]), int(at[-1]) + 1), np.array(pa),
                                np.array(pb) if pb else None))
        self.variables = variables[: len(self.levels[0][1]) + 1] if self.levels else variables[:1]
        self._one_sample_plan()

    def _one_sample_plan(self) -> None:
        """evaluate()'s per-sample steps with every view made here, once: the degree-1
        monomials taken straight from [1, x] (x_j, what 1 · x_j gives to the bit), then per
        step one gather of both its parents into scratch (first parents, then second: one
        call, not two) and one product of the two halves into the step's slice.
        Gathers use take(mode='clip'): the indices are built here and always in range, and
        numpy's bounds check costs ~40 % of a gather (7.3 vs 4.1 µs for 2 577 of them)."""
        mono = self._mono
        width = max((len(p) for _, p, _ in self.levels), default=0)
        self._parents = np.empty(2 * width)
        self._x_part = self._xe[1:]
        self._first = None
        self._steps = []
        for sl, pa, pb in self.levels:
            if pb is None:
                self._first = (self.variables[sl], mono[sl])
            else:  # both parents in one gather: [first parents | second parents]
                w = len(pa)
                self._steps.append((np.concatenate([pa, pb]), self._parents[: 2 * w],
                                    self._parents[:w], self._parents[w: 2 * w], mono[sl]))
        n = self.n
        self._vals_l, self._vals_r = self._vals[:n], self._vals[n:]
        # the same rows, laid out as [L (n); R (n, 20) flat] with empty rows for the joints a
        # muscle does not cross: the product then writes new_outputs()' arrays directly
        # (no scatter, no copy; each row's terms in the same order: the same sums to the bit)
        c = self.coef
        target = np.r_[np.arange(n), n + self.pair_flat]  # coef row -> full row
        lengths = np.zeros(n + n * len(JOINT_NAMES), np.int64)
        lengths[target] = np.diff(c.indptr)
        order = np.argsort(target)  # coef rows in full-row order
        take = np.concatenate([np.arange(c.indptr[r], c.indptr[r + 1]) for r in order]) \
            if c.nnz else np.zeros(0, np.int64)
        self._full = (len(lengths), c.shape[1], np.r_[0, np.cumsum(lengths)].astype(c.indptr.dtype),
                      c.indices[take], c.data[take])
        self._direct: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

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
        row_scale, pair_scale = [], []  # body size, applied after pruning (size-independent)
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
            data += length.tolist()
            row_scale.append(length_scale[m])
            for j, c in zip(span, cols):
                a = np.asarray(arms[j], float)
                if a.shape != (len(exps),):
                    raise ValueError(f"muscle #{m}: moment arm about {j} has the wrong length")
                ri += [pair_base] * len(keys)
                ci += keys.tolist()
                data += a.tolist()
                pair_scale.append(joint_scale[c])
                pair_rows.append(m)
                pair_cols.append(c)
                pair_base += 1
        if not np.all(np.isfinite(data)):
            raise ValueError("coefficients must be finite")
        keys = sorted(index, key=lambda k: (sum(k), index[k]))
        order = np.array([index[k] for k in keys])
        new_col = np.empty(len(keys), int)
        new_col[order] = np.arange(len(keys))
        coef = sparse.csr_matrix((data, (ri, new_col[np.asarray(ci, int)])),
                                 shape=(n + n_pairs, len(keys)))
        coef.sum_duplicates()
        coef = sparse.diags(np.asarray(row_scale + pair_scale, float)) @ _prune(coef, PRUNE_M)
        coef = sparse.csr_matrix(coef)
        return cls(center, half, keys, coef, np.asarray(pair_rows), np.asarray(pair_cols), n)

    @property
    def n_monomials(self) -> int:
        return len(self._mono)

    def polynomial(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """Row `row` of the coefficient matrix (0..n-1: a muscle's length, then its moment
        arms in pair order) as (exponents (K_r, 20), coefficients (K_r,)) of x, after
        pruning and body-size scaling: exactly what `evaluate` sums. Anything that must
        agree with the node (the OpenSim reference's FunctionBasedPath) reads it here, never
        the file, so the two cannot differ."""
        a, b = self.coef.indptr[row], self.coef.indptr[row + 1]
        return self.keys[self.coef.indices[a:b]], self.coef.data[a:b].copy()

    def moment_arm_row(self, muscle: int, joint: int) -> int:
        """The coefficient row of (muscle, joint)'s moment arm (KeyError if not spanned)."""
        hit = np.nonzero((self.pair_rows == muscle) & (self.pair_cols == joint))[0]
        if len(hit) != 1:
            raise KeyError((muscle, joint))
        return self.n + int(hit[0])

    def in_box(self, q: np.ndarray) -> np.ndarray:
        """(N,) True where no spanned joint of q (N, 20) lies outside the fit box, i.e. where
        the clip in `evaluate` changes nothing (the box test is the clip's own, |x| <= 1, up
        to 1e-12: a movement ending exactly on a range edge rounds to 1 + 2e-16)."""
        x = (np.atleast_2d(q) - self.center) * self.inv_half
        spanned = np.unique(self.pair_cols)
        return (np.abs(x[:, spanned]) <= 1.0 + 1e-12).all(axis=1)

    def _x(self, q: np.ndarray) -> np.ndarray:
        return np.clip((q - self.center) * self.inv_half, -1.0, 1.0)

    def _monomials(self, xe: np.ndarray, mono: np.ndarray) -> np.ndarray:
        """Fill mono (..., K) from xe (..., 21) = [1, x], step by step (see the module)."""
        xv = xe[..., self.variables]  # the degree-1 monomials: [1, x_j...]
        for sl, pa, pb in self.levels:
            np.multiply(mono[..., pa], xv[..., sl] if pb is None else mono[..., pb],
                        out=mono[..., sl])
        return mono

    def _monomials_one(self, xe: np.ndarray) -> np.ndarray:
        """_monomials for one posture, into arrays made once (same products, same order;
        see _one_sample_plan)."""
        if self._first is not None:
            variables, first = self._first
            xe.take(variables, out=first, mode="clip")
        multiply, take = np.multiply, self._mono.take
        for both, pq, p, q, out in self._steps:
            take(both, out=pq, mode="clip")
            multiply(p, q, out=out)
        return self._mono

    def plan_tables(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """evaluate()'s plan as flat tables, for the compiled step (muscle_step.py): the
        degree-1 monomials' variables (indices into [1, x]; they are monomials 1..k), then
        every product as (monomial, first parent, second parent), in evaluation order (each
        parent is of lower degree, so one pass in this order is the steps' result)."""
        first = np.zeros(0, int)
        outs, pas, pbs = [], [], []
        for sl, pa, pb in self.levels:
            if pb is None:
                if sl.start != 1:
                    raise ValueError("the degree-1 monomials must follow the constant")
                first = self.variables[sl]
                continue
            outs.append(np.arange(sl.start, sl.stop))
            pas.append(pa)
            pbs.append(pb)
        flat = [np.concatenate(t) if t else np.zeros(0, int) for t in (outs, pas, pbs)]
        return first, (flat[0], flat[1], flat[2])

    def output_buffer(self, R: np.ndarray, L: np.ndarray) -> np.ndarray | None:
        """The one buffer a new_outputs() pair (R, L) views, or None for other arrays."""
        direct = self._direct.get(id(R))
        return direct[2] if direct is not None and direct[0] is R and direct[1] is L else None

    def new_outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """(R (n, 20), L (n,)) for evaluate(q, out=...): R's unspanned entries stay 0. Both
        are views of one buffer the sparse product writes in place (the last 8 pairs made
        are known to evaluate; any other arrays are filled by a scatter and a copy)."""
        buf = np.zeros(self._full[0])
        R, L = buf[self.n:].reshape(self.n, len(JOINT_NAMES)), buf[: self.n]
        if len(self._direct) >= 8:
            self._direct.pop(next(iter(self._direct)))
        self._direct[id(R)] = (R, L, buf)
        return R, L

    def evaluate(self, q: np.ndarray, out: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """One posture (20,) -> (moment arms (n, 20), lengths (n,)): new arrays, or written
        into out = new_outputs() (the per-sample path: no allocation)."""
        xe, x = self._xe, self._x_part
        np.subtract(q, self.center, out=x)
        np.multiply(x, self.inv_half, out=x)
        clip_ufunc(xe, -1.0, 1.0, out=xe)  # xe[0] = 1 stays
        mono = self._monomials_one(xe)
        direct = self._direct.get(id(out[0])) if out is not None and _csr_matvec is not None \
            else None
        if direct is not None and direct[0] is out[0] and direct[1] is out[1]:
            buf = direct[2]
            buf.fill(0.0)  # csr_matvec adds to it, as scipy's own product starts from zeros
            _csr_matvec(*self._full, mono, buf)
            return out
        c = self.coef
        if _csr_matvec is None:
            vals = c @ mono
        else:
            vals = self._vals
            vals.fill(0.0)  # csr_matvec adds to it, as scipy's own product starts from zeros
            _csr_matvec(c.shape[0], c.shape[1], c.indptr, c.indices, c.data, mono, vals)
        n = self.n
        if out is None:
            R = np.zeros(n * len(JOINT_NAMES))
            R[self.pair_flat] = vals[n:]
            return R.reshape(n, len(JOINT_NAMES)), vals[:n].copy()
        R, L = out
        R.put(self.pair_flat, self._vals_r if _csr_matvec is not None else vals[n:], mode="clip")
        np.copyto(L, self._vals_l if _csr_matvec is not None else vals[:n])
        return R, L

    def _batch(self, q: np.ndarray) -> np.ndarray:
        out = np.empty((len(q), self.coef.shape[0]))
        for s in range(0, len(q), _CHUNK):
            x = self._x(q[s:s + _CHUNK])
            xe = np.concatenate([np.ones((len(x), 1)), x], axis=1)
            mono = self._monomials(xe, np.ones((len(x), self.n_monomials)))
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
