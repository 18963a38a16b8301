"""Wrapping artefacts past the source's own joint limits: detected per posture, repaired.

Why: a source model is built for its own joint ranges (MyoArm's wrist flexes ±45°, ours
−70…80°). Past them its wrapped paths may jump across a wrap surface: at wrist extension
beyond ~−66° MyoArm's FDS2 path steps 6.5 mm longer in 1° and its moment arm about the wrist
goes from +8.0 mm (a flexor, as FDS is at every posture) to −14.6 mm (an extensor). That is
not the muscle's geometry but the wrapping's, extrapolated where it was never built to go,
and no polynomial follows a step (the fit's three pairs above 1 mm RMS were exactly these).

The rule, the same for every muscle and joint (`repair`):

1. A posture q outside the source's joint-limit box is joined to its nearest posture inside
   the box, p = clip(q, lo, hi), by the straight segment p -> q (only the joints past their
   limits move along it).
2. Along that segment, in steps of at most STEP_DEG, a step whose length change the moment
   arms do not explain (|ΔL + ½(r_a + r_b)·Δq| > tolerance: fit.find_jumps' test) is bisected
   down to REFINE_DEG; if it is still unexplained there, the path jumps there (a steep but
   continuous moment arm, FCU's past 45° of flexion, is explained at a finer step and is not
   a jump).
3. From the first jump on (for that muscle), the source's geometry is the artefact's: the
   target becomes the geometry at the last clean point a of the segment, continued: moment
   arms R(a) (every joint), length L(a) − R(a)·(q − a) (so −dL/dq = R still holds).

Postures inside the source's limits are never changed (what the source does there is its
geometry, including RI2's sign flip at 9° of index MCP flexion), nor are paths past the
limits that do not jump (FCU's moment arm turning sign past 45° of flexion is continuous:
followed). `repair` returns the repaired copy and a mask of what it changed; fit.py fits the
repaired targets and reports each pair's error both against them and against the raw source
on the postures the rule left alone.
"""

from __future__ import annotations

import math

import numpy as np

STEP_DEG = 5.0  # coarse sweep step (the trapezoid rule's error there is < 0.05 mm)
REFINE_DEG = 0.1  # a jump still unexplained over this step is a discontinuity
#: The rule as the fit file records it (`fit.wrap_repair.rule`).
WRAP_REPAIR_RULE = (
    "a posture past the source's own joint limits is joined to its nearest posture inside "
    f"them by a straight segment; where the muscle's path length along it steps by more "
    f"than its moment arms explain (checked every {STEP_DEG:g} deg, confirmed over "
    f"{REFINE_DEG:g} deg), the target from there on is the geometry at the last clean point, "
    "continued: moment arms held, length linear in them")


def _unexplained(La, Ra, Lb, Rb, dq) -> np.ndarray:
    """|ΔL + ½(r_a + r_b)·Δq| per muscle: (..., n) m."""
    return np.abs((Lb - La) + 0.5 * np.einsum("...ij,...j->...i", Ra + Rb, dq))


def repair(src, q: np.ndarray, L: np.ndarray, R: np.ndarray, lo, hi, tol: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """q (N, 20) with the source's L (N, n) and R (N, n, 20) there; lo, hi: the source's
    joint limits (our joints and signs). Returns L', R' (repaired copies), the mask (N, n)
    of (posture, muscle) repaired, and counts {'evaluated': postures asked of src}."""
    q = np.atleast_2d(q)
    p = np.clip(q, lo, hi)
    L2, R2 = L.copy(), R.copy()
    mask = np.zeros(L.shape, bool)
    evaluated = 0
    out = np.nonzero((q != p).any(axis=1))[0]
    for k in out:
        d = q[k] - p[k]
        n = max(1, math.ceil(math.degrees(float(np.abs(d).max())) / STEP_DEG))
        t = np.arange(n + 1) / n
        Ls, Rs = src.evaluate(p[k] + t[:n, None] * d)
        evaluated += n
        Ls, Rs = np.concatenate([Ls, L[k][None]]), np.concatenate([Rs, R[k][None]])
        bad = _unexplained(Ls[:-1], Rs[:-1], Ls[1:], Rs[1:], d / n) > tol  # (n, muscles)
        for i in np.nonzero(bad.any(axis=0))[0]:
            for s in np.nonzero(bad[:, i])[0]:  # first confirmed jump of muscle i
                hit, ev = _bisect(src, p[k], d, t[s], t[s + 1], Ls[s], Rs[s], Ls[s + 1],
                                  Rs[s + 1], i, tol)
                evaluated += ev
                if hit is None:
                    continue
                ta, La, Ra = hit
                R2[k, i] = Ra
                L2[k, i] = La - Ra @ ((1.0 - ta) * d)
                mask[k, i] = True
                break
    return L2, R2, mask, {"evaluated": evaluated}


def _bisect(src, p, d, ta, tb, La, Ra, Lb, Rb, i, tol):
    """Narrow the unexplained step [ta, tb] of muscle i to REFINE_DEG. Returns (t, L_i, R_i)
    at the clean end of the jump, or None when no half stays unexplained (continuous);
    and the number of postures evaluated."""
    span = math.degrees(float(np.abs(d).max()))
    ev = 0
    La, Ra, Lb, Rb = La[i], Ra[i], Lb[i], Rb[i]
    while (tb - ta) * span > REFINE_DEG:
        tm = 0.5 * (ta + tb)
        Lm, Rm = src.evaluate((p + tm * d)[None])
        ev += 1
        Lm, Rm = Lm[0, i], Rm[0, i]
        left = abs((Lm - La) + 0.5 * (Ra + Rm) @ ((tm - ta) * d)) > tol
        right = abs((Lb - Lm) + 0.5 * (Rm + Rb) @ ((tb - tm) * d)) > tol
        if left:
            tb, Lb, Rb = tm, Lm, Rm
        elif right:
            ta, La, Ra = tm, Lm, Rm
        else:
            return None, ev
    return (ta, La, Ra), ev


class Repairer:
    """`repair` with the source's own limits, counting what it asked of the source. A source
    without `joint_limits()` (source_osim's OpenSim models, whose fit box is already cut to
    the model's own ranges) is passed through unchanged."""

    def __init__(self, src, tol: float):
        self.src, self.tol = src, tol
        self.limits = src.joint_limits() if hasattr(src, "joint_limits") else None
        self.evaluated = 0

    def __call__(self, q, L, R):
        if self.limits is None:
            return L, R, np.zeros(L.shape, bool)
        L2, R2, mask, info = repair(self.src, q, L, R, *self.limits, self.tol)
        self.evaluated += info["evaluated"]
        return L2, R2, mask
