"""The per-muscle polynomial fit of fit.py: degree, outliers, and the sign of each moment arm.

Why: a surrogate whose moment arm has the wrong sign turns a flexor into an extensor in the
static optimisation (BRA at full elbow extension: MyoArm +0.68 mm, a degree-2 fit −0.51 mm,
so the QP could not use BRA there). Least squares minimises the RMS, not the sign; the edges
of the box, where a low degree bends over and uniform samples are rare, are where it fails.
So the fit also samples the faces and corners of the box (`edge_postures`), requires the
source's sign wherever the source's moment arm is clearly non-zero or one-signed
(`required_sign`), counts misses (`sign_violations`), and refits a moment arm that misses
with those postures as inequality constraints (`constrained_fit`, a QP solved by daqp).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

TARGET_M = 1e-3  # the target: RMS <= 1 mm per (muscle, DOF) pair
EDGE_TARGET_M = 1e-3  # the same on the faces and corners of the box
MAX_DEGREE = 8  # a 1-4 joint muscle may go past 5 (RI2, FCU, ECRL); MAX_TERMS bounds the rest
MAX_TERMS = 462
OUTLIER_K = 6.0
SIGN_MIN_M = 1e-3  # a moment arm this large has a sign the surrogate must keep
ONE_SIGNED_MIN_M = 1e-4  # a pair one-signed in the source keeps its sign down to this
SIGN_MARGIN_M = 2e-4  # constrained postures: s * r >= min(this, |r_source| / 2) (> PRUNE_M)
JUMP_WAIVE_DEG = 10.0  # no sign required this close to a wrapping jump of the same pair
N_EDGE = 300  # base postures per face (one joint at an edge)
N_CORNER = 100  # base postures per corner (two joints a muscle crosses together at edges)
#: A pair no total degree brings to the target: its own basis, the muscle's total-degree
#: monomials plus every monomial of degree <= one of these in the one or two joints its
#: error depends on (`dominant_joints`: the wrist's 2-D flexion-deviation for FCU, FPL, EPL).
PAIR_DEGREES = (10, 12, 14, 16, 20, 24)
#: Terms of the OpenSim reference's MultivariatePolynomialFunction (every monomial of the
#: muscle's dimension up to its highest degree: C(n + D, D)), bounded to keep its
#: StaticOptimization's cost (muscle_validation/opensim_so.py) near today's.
OPENSIM_MAX_TERMS = 20000


def edge_postures(base: np.ndarray, lo, hi, spans) -> tuple[np.ndarray, list[frozenset]]:
    """Postures on the faces and corners of the box: each base posture with one joint at
    either edge of its range, and (a corner, as BRD's full extension and supination) with
    two joints some muscle crosses together at edges. Returns the postures and, per
    posture, the joints moved (a muscle uses those whose moved joints it crosses)."""
    n, nc = min(N_EDGE, len(base)), min(N_CORNER, len(base))
    qs, moved = [], []
    for j in range(20):
        if not any(j in s for s in spans):
            continue
        for v in (lo[j], hi[j]):
            q = base[:n].copy()
            q[:, j] = v
            qs.append(q)
            moved += [frozenset((j,))] * n
    pairs = sorted({(a, b) for s in spans for a in s for b in s if a < b})
    for a, b in pairs:
        for va, vb in itertools.product((lo[a], hi[a]), (lo[b], hi[b])):
            q = base[:nc].copy()
            q[:, a], q[:, b] = va, vb
            qs.append(q)
            moved += [frozenset((a, b))] * nc
    return np.concatenate(qs), moved


def required_sign(R: np.ndarray, one_signed: np.ndarray) -> np.ndarray:
    """Per sample and spanned joint: the sign the surrogate must have (0: free)."""
    s = np.sign(R) * (np.abs(R) > SIGN_MIN_M)
    keep_one = one_signed[None, :] * (np.abs(R) > ONE_SIGNED_MIN_M) * (np.sign(R) == one_signed)
    return np.where(s != 0, s, keep_one)


def one_signed(*Rs: np.ndarray) -> np.ndarray:
    """+1 / -1 per spanned joint where the source's moment arm has that sign (or is within
    ONE_SIGNED_MIN_M of 0) on every sample given and exceeds it somewhere, else 0."""
    r = np.concatenate(Rs)
    lo, hi, tiny = r.min(axis=0), r.max(axis=0), ONE_SIGNED_MIN_M
    return np.select([(lo > -tiny) & (hi > tiny), (hi < tiny) & (lo < -tiny)], [1, -1], 0)


def sign_violations(coef_r: np.ndarray, B: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Per spanned joint: samples where the fitted moment arm (B @ coef_r) has not the
    required sign (strictly)."""
    return (((B @ coef_r) * sign <= 0) & (sign != 0)).sum(axis=0)


def constrained_fit(A: np.ndarray, y: np.ndarray, B: np.ndarray, s: np.ndarray,
                    r_src: np.ndarray, coef0: np.ndarray) -> tuple[np.ndarray, int]:
    """Least squares min |A c − y| with s·(B c) ≥ min(SIGN_MARGIN_M, |r|/2) on the postures
    B where the sign is required (s ≠ 0): a QP in the orthonormal basis of A (A = QR,
    c = R⁻¹ z, cost |z − Qᵀy|², identity Hessian), solved by daqp; constraints enter as
    they are violated (cutting planes). Returns c and the number of constraints used."""
    import daqp

    Q, Rq = np.linalg.qr(A)
    Rinv = np.linalg.solve(Rq, np.eye(len(Rq)))
    f = -(Q.T @ y)
    idx = np.nonzero(s)[0]
    m_all = np.minimum(SIGN_MARGIN_M, 0.5 * np.abs(r_src[idx]))
    active = np.zeros(len(idx), bool)
    coef = coef0
    for _ in range(10):
        slack = s[idx] * (B[idx] @ coef) - m_all
        new = (slack < -1e-9) & ~active
        if not new.any():
            break
        worst = np.argsort(slack)[: max(1, min(400, int(new.sum())))]
        active[worst[new[worst]]] = True
        G = np.ascontiguousarray(s[idx[active], None] * (B[idx[active]] @ Rinv))
        H = np.eye(len(f))
        z, _, flag, _ = daqp.solve(H, f, G, np.full(len(G), 1e30), m_all[active],
                                   np.zeros(len(G), np.int32))
        if flag < 1:
            break
        coef = Rinv @ z
    return coef, int(active.sum())


def waive_near_jumps(need: np.ndarray, x: np.ndarray, jumps_x: dict, width: dict) -> None:
    """No sign required within `width` (normalised) of a wrapping jump of the same pair:
    there the source's moment arm changes sign in a step (RI2 at index MCP 9°: −5.2 mm
    below, +4.5 mm above: its path switches sides of a wrap), which no polynomial follows
    and which is an artefact, not anatomy (fit.jumps lists them)."""
    for k, at in jumps_x.items():
        for a in at:
            need[np.abs(x[:, k] - a) < width[k], k] = 0


def exponents(n_vars: int, degree: int) -> np.ndarray:
    """All monomials of total degree <= degree in n_vars variables, (K, n_vars) ints,
    ordered by degree (built degree by degree: no enumeration of a (degree+1)^n grid)."""
    levels = [[(0,) * n_vars]]
    for _ in range(degree):
        nxt = {e[:k] + (e[k] + 1,) + e[k + 1:] for e in levels[-1] for k in range(n_vars)}
        levels.append(sorted(nxt))
    return np.array([e for lv in levels for e in lv], int).reshape(-1, n_vars)


def design(x: np.ndarray, exps: np.ndarray) -> np.ndarray:
    """(N, K) values of the monomials exps (K, n) at x (N, n): one power table per joint."""
    out = np.ones((len(x), len(exps)))
    for k in range(exps.shape[1]):
        e = exps[:, k]
        if len(e) and e.max() > 0:
            out *= (x[:, k:k + 1] ** np.arange(e.max() + 1))[:, e]
    return out


def dominant_joints(x: np.ndarray, e: np.ndarray, degree: int = 12) -> list[int]:
    """Spanned-joint positions ranked by how much of the residual e (N,) a polynomial of
    that joint alone explains (Legendre, degree 12): where a pair's error sits."""
    score = []
    for k in range(x.shape[1]):
        V = np.polynomial.legendre.legvander(x[:, k], degree)
        c, *_ = np.linalg.lstsq(V, e, rcond=None)
        score.append(float(np.sum((V @ c) ** 2)))
    return [int(k) for k in np.argsort(score)[::-1]]


def _pair_fit(ex, data, k, constrain: bool):
    """Fit pair k (its moment arm) on the basis ex: least squares on the fit's kept
    postures (sign-constrained where it misses, if constrain); held-out RMS, max,
    face/corner RMS, sign errors."""
    xs, Y, keep, need_f, Rf_s, xt, Yt, xc, need_c, xe, Ye = data
    A = design(xs, ex)
    y = Y[:, 1 + k]
    c, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)
    n_con = 0
    if constrain and sign_violations(c[:, None], A, need_f[:, k:k + 1]).sum():
        c, n_con = constrained_fit(A[keep], y[keep], A, need_f[:, k], Rf_s[:, k], c)
    err = design(xt, ex) @ c - Yt[:, 1 + k]
    edge = float(np.sqrt(np.mean((design(xe, ex) @ c - Ye[:, 1 + k]) ** 2))) if len(xe) else 0.0
    viol = int(sign_violations(c[:, None], design(xc, ex), need_c[:, k:k + 1]).sum())
    return {"exps": ex, "coef": c, "rms": float(np.sqrt(np.mean(err ** 2))),
            "max": float(np.abs(err).max()), "edge_rms": edge, "viol": viol, "n_con": n_con}


def _passes(f) -> bool:
    return f["rms"] <= TARGET_M and f["edge_rms"] <= EDGE_TARGET_M and f["viol"] == 0


def refine_pairs(fit: dict, data) -> dict:
    """Each moment-arm pair of fit that misses the target (held-out RMS, face/corner RMS or a
    sign error) gets its own basis: the muscle's total-degree monomials plus those of degree
    <= D (PAIR_DEGREES) in its dominant joint, or two: the first candidate that meets the
    target with the fewest terms; if none does, the lowest held-out RMS if it is 5 % below
    the pair's and adds no sign error. A sharp change in one joint (FCU's wrist-flexion moment
    arm falls from +17 to −18 mm between 45° and 68°, past MyoArm's own limit) needs a high
    degree in that joint, not in the joints it hardly depends on. The muscle's exponents
    become the union (still closed under division, as surrogate.Surrogate requires); a
    pair's coefficients are zero outside its own basis (pruned on loading)."""
    xs, Y, keep = data[:3]
    n, base = xs.shape[1], fit["exps"]
    base_set = {tuple(e) for e in base}
    A = design(xs, base)
    chosen = {}
    for k in range(n):
        cur = {"rms": float(fit["rms"][1 + k]), "edge_rms": float(fit["edge_rms"][1 + k]),
               "viol": int(fit["sign_violations"][k])}
        if _passes(cur):
            continue
        order = dominant_joints(xs[keep], A[keep] @ fit["coef"][:, 1 + k] - Y[keep, 1 + k])
        subsets = [order[:1]] + ([sorted(order[:2])] if n > 1 else [])
        cands = []
        for S in subsets:
            for D in PAIR_DEGREES:
                if D <= fit["degree"] or math.comb(n + D, D) > OPENSIM_MAX_TERMS:
                    continue
                hi = exponents(len(S), D)
                sub = np.zeros((len(hi), n), int)
                sub[:, S] = hi
                extra = [tuple(e) for e in sub if tuple(e) not in base_set]
                cands.append((len(extra), D, S, np.array(extra, int).reshape(-1, n)))
        tried = []
        for _, D, S, extra in sorted(cands, key=lambda c: c[:2]):  # fewest terms first
            ex = np.concatenate([base, extra])
            f = _pair_fit(ex, data, k, constrain=False)
            if f["rms"] <= TARGET_M and f["edge_rms"] <= EDGE_TARGET_M and f["viol"]:
                f = _pair_fit(ex, data, k, constrain=True)  # the sign, only where it matters
            f.update(joints=[int(j) for j in S], pair_degree=D)
            tried.append(f)
            if _passes(f):
                chosen[k] = f
                break
        if k not in chosen and tried:
            best = min((f for f in tried if f["viol"] <= cur["viol"]), default=None,
                       key=lambda f: f["rms"])
            if best is not None and best["rms"] < 0.95 * cur["rms"]:
                chosen[k] = best
    if not chosen:
        return fit
    union = {tuple(e) for f in chosen.values() for e in f["exps"]} | base_set
    exps = np.array(sorted(union, key=lambda e: (sum(e), e)), int)
    col = {tuple(e): i for i, e in enumerate(exps)}
    coef = np.zeros((len(exps), fit["coef"].shape[1]))
    coef[[col[tuple(e)] for e in base]] = fit["coef"]
    out = dict(fit, exps=exps, coef=coef, rms=fit["rms"].copy(), max=fit["max"].copy(),
               edge_rms=fit["edge_rms"].copy(), sign_violations=fit["sign_violations"].copy(),
               pair_bases={})
    for k, f in chosen.items():
        coef[:, 1 + k] = 0.0
        coef[[col[tuple(e)] for e in f["exps"]], 1 + k] = f["coef"]
        out["rms"][1 + k], out["max"][1 + k] = f["rms"], f["max"]
        out["edge_rms"][1 + k], out["sign_violations"][k] = f["edge_rms"], f["viol"]
        out["sign_constraints"] += f["n_con"]
        out["pair_bases"][k] = (f["joints"], f["pair_degree"])
    return out


def fit_muscle(xf, Lf, Rf, xt, Lt, Rt, span, edge_fit=None, edge_test=None,
               jumps_x: dict | None = None, waive_width: dict | None = None) -> dict:
    """Smallest degree reaching TARGET_M on held-out samples and their faces and corners
    with no sign error; if none, of the degrees within 5 % of the best held-out RMS the
    one with the fewest sign errors. Outliers excluded, reported. edge_fit / edge_test: (x, L, R)
    of the face and corner postures this muscle uses (fitted / checked); jumps_x: per
    spanned-joint position, the normalised angles of the pair's wrapping jumps."""
    if edge_fit is not None:
        xf = np.concatenate([xf, edge_fit[0]])
        Lf = np.concatenate([Lf, edge_fit[1]])
        Rf = np.concatenate([Rf, edge_fit[2]])
    Rf_s, Rt_s = Rf[:, span], Rt[:, span]
    xc, Rc = xt[:, span], Rt_s
    xe, Ye = xc[:0], np.zeros((0, 1 + len(span)))
    if edge_test is not None:
        xe, Ye = edge_test[0][:, span], np.column_stack([edge_test[1], edge_test[2][:, span]])
        xc, Rc = np.concatenate([xc, xe]), np.concatenate([Rc, Ye[:, 1:]])
    sgn1 = one_signed(Rf_s, Rc)
    need_f, need_c = required_sign(Rf_s, sgn1), required_sign(Rc, sgn1)
    if jumps_x:
        waive_near_jumps(need_f, xf[:, span], jumps_x, waive_width)
        waive_near_jumps(need_c, xc, jumps_x, waive_width)
    candidates = []
    xs, xts = xf[:, span], xt[:, span]
    Y, Yt = np.column_stack([Lf, Rf_s]), np.column_stack([Lt, Rt_s])
    for degree in range(1, MAX_DEGREE + 1):
        exps = exponents(len(span), degree)
        if len(exps) > MAX_TERMS:
            break
        A = design(xf[:, span], exps)
        Y = np.column_stack([Lf, Rf_s])
        keep = np.ones(len(A), bool)
        for _ in range(3):
            coef, *_ = np.linalg.lstsq(A[keep], Y[keep], rcond=None)
            res = np.abs(A @ coef - Y)
            sigma = 1.4826 * np.median(res, axis=0) + 1e-12
            out = ((res > OUTLIER_K * sigma) & (res > TARGET_M)).any(axis=1)
            if out.sum() > 0.02 * len(A) or np.array_equal(~out, keep):
                break
            keep = ~out
        n_con = 0
        for k in np.nonzero(sign_violations(coef[:, 1:], A, need_f))[0]:
            coef[:, 1 + k], n = constrained_fit(A[keep], Y[keep, 1 + k], A, need_f[:, k],
                                                Rf_s[:, k], coef[:, 1 + k])
            n_con += n
        At = design(xt[:, span], exps)
        Yt = np.column_stack([Lt, Rt_s])
        err = At @ coef - Yt
        rms = np.sqrt(np.mean(err ** 2, axis=0))
        viol = sign_violations(coef[:, 1:], design(xc, exps), need_c)
        edge_rms = np.sqrt(np.mean((design(xe, exps) @ coef - Ye) ** 2, axis=0)) \
            if len(xe) else np.zeros_like(rms)
        fit = {"degree": degree, "exps": exps, "coef": coef, "rms": rms, "edge_rms": edge_rms,
               "max": np.abs(err).max(axis=0), "excluded": int((~keep).sum()),
               "sign_violations": viol, "sign_constraints": n_con, "pair_bases": {},
               "keep": keep}
        if rms.max() <= TARGET_M and edge_rms.max() <= EDGE_TARGET_M and viol.sum() == 0:
            return fit
        candidates.append(fit)
    # no total degree meets the target: the failing pairs of the chosen degree get their
    # own bases (refine_pairs)
    def data(f):
        return xs, Y, f["keep"], need_f, Rf_s, xts, Yt, xc, need_c, xe, Ye

    best = min(float(f["rms"].max()) for f in candidates)  # the reported figure decides
    near = [f for f in candidates if f["rms"].max() <= 1.05 * best]
    fallback = min(near, key=lambda f: (int(f["sign_violations"].sum()), float(f["rms"].max())))
    return refine_pairs(fallback, data(fallback))
