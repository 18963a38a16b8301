"""Derive the shipped muscle model from MyoSuite's MyoArm (MuJoCo): parameters and surrogates.

    pip install -e '.[muscles-fit]'          # mujoco + myo-sim (Apache-2.0), fitting only
    python -m forearm_dynamics.muscles.fit   # writes forearm_dynamics/data/muscles_myoarm.json

Why MyoArm: it is the only source with the forearm and hand muscles' paths under a licence
our BSD-3 package can carry (Apache-2.0; MoBL-ARMS is non-commercial). What the script does:

1. Loads `myo_sim.load_model("myoarm_r")`, holds every shoulder joint at 0 (our humerus is
   fixed in the world, arm at the side) and the four MCP abductions at 0 (we have none).
2. Maps the source's joints onto ours by coordinate value and sign (`JOINT_MAP`): our angle
   = sign × the source's angle; the sign is the one that gives each muscle its anatomical
   action (checked by `check_signs`: PT pronates, ECU deviates ulnarly, FPL flexes the thumb
   ...). A moment arm about our joint is sign × the source's.
3. Parameters: max isometric force = MuJoCo's `force`; MuJoCo's normalised muscle has no
   optimal fibre length, tendon slack or pennation, so they follow MuJoCo's own definition
   (engine docs, `mj_setLengthRange` + muscle gain): L0 = (lengthrange[1] − lengthrange[0]) /
   (range[1] − range[0]), LTs = lengthrange[0] − range[0]·L0 (where that is negative, a
   fibre longer than its path: LTs = 0, L0 = lengthrange[1] / range[1]), pennation 0 (rigid tendon,
   fibre along the path); max contraction velocity 10 L0/s (DeGroote-Fregly's curves are
   scaled for it; MyoArm's forearm class keeps MuJoCo's default vmax 1.5 of its own curve).
4. Samples postures uniformly over our joints' ranges (README table), plus the faces and
   corners of the box (`edge_postures`: one or two joints at a range edge, where a uniform
   sample rarely goes and the library's movements often hold a joint, e.g. the elbow at 0),
   and fits, per muscle, polynomials of the joints it crosses (total degree chosen per
   muscle, the smallest that reaches 1 mm on held-out samples with no sign error, at most
   MAX_DEGREE and MAX_TERMS) to the source's own length (`ten_length`) and moment arms
   (−`ten_J`, MuJoCo's analytic tendon Jacobian, not a finite difference of the length).
   A pair that no total degree brings to the target gets its own basis on top
   (fit_core.refine_pairs: a high degree in the one or two joints its error depends on).
   Sign: wherever the source's moment arm is clearly non-zero (|r| > SIGN_MIN_M), and
   everywhere a pair is one-signed in the source (|r| > ONE_SIGNED_MIN_M: BRA flexes the
   elbow even at 0°, +0.68 mm), the fitted moment arm must have the source's sign; a least
   squares fit that misses it somewhere is refitted with those postures as constraints
   (`constrained_fit`: a QP, daqp). Checked on held-out postures and their own faces and
   corners (`sign_violations` per pair in the file).
5. Path-wrapping artefacts: 1° sweeps of each (muscle, joint) pair compare the length's step
   with the moment arm's integral; a step off by more than JUMP_TOL is a jump (the path
   switched sides of a wrap). Fitting samples whose residual is an outlier (> OUTLIER_K ×
   robust σ and > 1 mm) are excluded and refitted (at most 2 % per muscle); both are reported.
   Past the source's own joint limits a jump is repaired, posture by posture, by one rule
   for every pair (wrap_repair.py: the geometry before the jump, continued): the fit's
   target is the source with those artefacts repaired; each pair's error is reported
   against that target, and against the raw source where the rule changed nothing.
6. Errors per (muscle, joint) pair on held-out samples (RMS, max, sign errors) are written
   into the file; `--docs` writes them into docs/muscles.md (fit_report.py).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..description import JOINT_NAMES
from .fit_core import (
    JUMP_WAIVE_DEG,
    MAX_DEGREE,
    MAX_TERMS,
    ONE_SIGNED_MIN_M,
    OPENSIM_MAX_TERMS,
    PAIR_DEGREES,
    SIGN_MIN_M,
    design,
    edge_postures,
    fit_muscle,
)
from .fit_report import write_docs
from .myoarm import (  # noqa: F401  (re-exported: fit.MyoArm, fit.joint_box, ...)
    JOINT_MAP,
    SHOULDER_ONLY,
    SIGN_CHECKS,
    MyoArm,
    check_signs,
    find_spans,
    joint_box,
)
from .wrap_repair import REFINE_DEG, STEP_DEG, WRAP_REPAIR_RULE, Repairer

JUMP_TOL = 5e-4  # m: length step not explained by the moment arm over a 1° step
N_FIT = 20000
N_TEST = 4000
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "data" / "muscles_myoarm.json"


@dataclass(frozen=True)
class FitSizes:
    """How many postures build() asks of the source. The defaults are MyoArm's (MuJoCo's
    tendon Jacobians, cheap); a slow source (OpenSim's computeMomentArm, 70-140 ms a posture
    for MoBL-ARMS' 98 pairs: source_osim.py) takes fewer. n_edge_base: base postures per face and corner
    (None: fit_core's N_EDGE / N_CORNER)."""

    n_fit: int = N_FIT
    n_test: int = N_TEST
    n_edge_base: int | None = None
    jump_bases: int = 6
    n_envelope: int = 2000


def find_jumps(src: MyoArm, spans, lo, hi, rng, n_base: int = 6) -> list[dict]:
    """1° sweeps: length steps the moment arm does not explain (wrapping artefacts)."""
    found = []
    step = math.radians(1.0)
    for j in range(20):
        users = [i for i, s in enumerate(spans) if j in s]
        if not users:
            continue
        grid = np.arange(lo[j], hi[j] + 1e-12, step)
        for _ in range(n_base):
            base = rng.uniform(lo, hi)
            q = np.repeat(base[None], len(grid), axis=0)
            q[:, j] = grid
            L, R = src.evaluate(q)
            for i in users:
                dl = np.diff(L[:, i])
                pred = -0.5 * (R[1:, i, j] + R[:-1, i, j]) * np.diff(grid)
                bad = np.abs(dl - pred) > JUMP_TOL
                for k in np.nonzero(bad)[0]:
                    found.append({"muscle": src.names[i], "joint": JOINT_NAMES[j],
                                  "at_deg": round(math.degrees(grid[k]), 1),
                                  "length_step_mm": round(float(dl[k]) * 1e3, 2),
                                  "explained_mm": round(float(pred[k]) * 1e3, 2)})
    return found


def movement_box() -> tuple[np.ndarray, np.ndarray]:
    """The box the library's 65 movements stay in (each joint's min and max)."""
    from ..movements import movement_library

    qs = [mv.evaluate(mv.sample_times(200))[0] for mv in movement_library()]
    q = np.concatenate(qs)
    return q.min(axis=0), q.max(axis=0)


def envelope_errors(src, muscles, center, half, rng, n: int = 2000, fix=None) -> None:
    """Add each pair's RMS over the movements' box (held-out samples) to the fit record
    (against the fit's target: the source, its wrapping jumps past its limits repaired)."""
    lo, hi = movement_box()
    q = rng.uniform(lo, hi, size=(n, 20))
    L, R = src.evaluate(q)
    if fix is not None:
        L, R, _ = fix(q, L, R)
    x = np.clip((q - center) / half, -1, 1)
    for i, mus in enumerate(muscles):
        span = [JOINT_NAMES.index(j) for j in mus["spans"]]
        A = design(x[:, span], np.asarray(mus["surrogate"]["exponents"]))
        mus["fit"]["movement_box_length_rms_mm"] = round(
            float(np.sqrt(np.mean((A @ mus["surrogate"]["length"] - L[:, i]) ** 2))) * 1e3, 4)
        mus["fit"]["movement_box_moment_arm_rms_mm"] = {
            j: round(float(np.sqrt(np.mean((A @ mus["surrogate"]["moment_arms"][j]
                                            - R[:, i, c]) ** 2))) * 1e3, 4)
            for j, c in zip(mus["spans"], span)}


HELDOUT = Path(__file__).resolve().parents[2] / "test" / "data" / "muscles_myoarm_heldout.npz"


def write_heldout(src: MyoArm, path: Path, rng, n: int = 120, n_edge: int = 6,
                  fix=None) -> None:
    """The source's exact geometry at postures the fit never saw (test_muscles.py): n over
    our joints' ranges, n inside the library's movement box, and n_edge postures per face
    of the range box (each joint at either edge: where a sign goes wrong first). Beside the
    raw source (`length`, `moment_arm`, ...): where the fit's target differs from it (its
    wrapping jumps past the source's limits repaired, wrap_repair.py), as (posture, muscle)
    rows `repaired*` and their target values `repaired*_length`, `repaired*_moment_arm`
    (test_muscles.target() rebuilds the target arrays)."""
    fix = fix if fix is not None else Repairer(src, JUMP_TOL)
    lo, hi = joint_box()
    q = rng.uniform(lo, hi, size=(n, 20))
    L, R = src.evaluate(q)
    blo, bhi = movement_box()
    qb = rng.uniform(blo, bhi, size=(n, 20))
    Lb, Rb = src.evaluate(qb)
    qe = np.repeat(rng.uniform(lo, hi, size=(n_edge, 20))[None], 40, axis=0)
    for j in range(20):
        qe[2 * j, :, j], qe[2 * j + 1, :, j] = lo[j], hi[j]
    qe = qe.reshape(-1, 20)
    Le, Re = src.evaluate(qe)
    f32 = np.float32  # 0.03 µm at 0.3 m: far below the errors compared
    repaired = {}
    for key, (qs, Ls, Rs) in {"": (q, L, R), "_box": (qb, Lb, Rb), "_edge": (qe, Le, Re)}.items():
        Lr, Rr, m = fix(qs, Ls, Rs)
        rows = np.argwhere(m)
        repaired.update({f"repaired{key}": rows,
                         f"repaired{key}_length": Lr[m].astype(f32),
                         f"repaired{key}_moment_arm": Rr[m].astype(f32)})
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, names=np.array(src.names), q=q, length=L.astype(f32),
                        moment_arm=R.astype(f32), q_box=qb, moment_arm_box=Rb.astype(f32),
                        q_edge=qe, moment_arm_edge=Re.astype(f32), **repaired,
                        source_lo=src.joint_limits()[0], source_hi=src.joint_limits()[1],
                        source=np.array(f"MyoArm myo_sim {src.version}; Apache-2.0"))


def build(out: Path, seed: int = 0, heldout: Path | None = None,
          xml: Path | None = None, *, src=None, source: dict | None = None,
          sizes: FitSizes = FitSizes(), box: tuple | None = None) -> dict:
    """MyoArm (or the MuJoCo model `xml`), or any `src` with MyoArm's interface (names,
    evaluate, parameters: source_osim.OsimSource) described by `source` (provenance).
    box: (lo, hi) rad of the fit (default our joints' ranges; the surrogate holds its edge
    value outside it)."""
    t0 = time.perf_counter()
    own = src is None
    src = MyoArm(xml) if own else src
    rng = np.random.default_rng(seed)
    lo, hi = joint_box() if box is None else box
    bad = check_signs(src, lo, hi) if own else []
    if bad:
        raise SystemExit("joint mapping gives the wrong action: " + "; ".join(bad))
    spans = find_spans(src, lo, hi, rng)
    center, half = 0.5 * (hi + lo), 0.5 * (hi - lo)
    qf = rng.uniform(lo, hi, size=(sizes.n_fit, 20))
    qt = rng.uniform(lo, hi, size=(sizes.n_test, 20))
    # the fit's target: the source, its wrapping jumps past its own limits repaired
    fix = Repairer(src, JUMP_TOL)
    Lf, Rf, mf = fix(qf, *src.evaluate(qf))
    Lt_src, Rt_src = src.evaluate(qt)
    Lt, Rt, mt = fix(qt, Lt_src, Rt_src)
    xf, xt = (qf - center) / half, (qt - center) / half
    qef, moved_f = edge_postures(qf[:sizes.n_edge_base], lo, hi, spans)  # fitted
    qet, moved_t = edge_postures(qt[:sizes.n_edge_base], lo, hi, spans)  # checked only
    Lef, Ref, mef = fix(qef, *src.evaluate(qef))
    Let, Ret, met = fix(qet, *src.evaluate(qet))
    xef, xet = (qef - center) / half, (qet - center) / half
    jumps = find_jumps(src, spans, lo, hi, rng, sizes.jump_bases)
    muscles = []
    for i, name in enumerate(src.names):
        span = spans[i]
        uf = np.array([mv <= set(span) for mv in moved_f])
        ut = np.array([mv <= set(span) for mv in moved_t])
        jx = {k: [(math.radians(jp["at_deg"]) - center[j]) / half[j] for jp in jumps
                  if jp["muscle"] == name and jp["joint"] == JOINT_NAMES[j]]
              for k, j in enumerate(span)}
        width = {k: math.radians(JUMP_WAIVE_DEG) / half[j] for k, j in enumerate(span)}
        fit = fit_muscle(xf, Lf[:, i], Rf[:, i], xt, Lt[:, i], Rt[:, i], span,
                         (xef[uf], Lef[uf, i], Ref[uf, i]), (xet[ut], Let[ut, i], Ret[ut, i]),
                         {k: v for k, v in jx.items() if v}, width)
        joints = [JOINT_NAMES[j] for j in span]
        # against the raw source: where the repair left it alone, and where it did not
        err = design(xt[:, span], fit["exps"]) @ fit["coef"][:, 1:] - Rt_src[:, i][:, span]
        clean = ~mt[:, i]
        muscles.append({
            "name": name,
            **src.parameters(i),
            "spans": joints,
            "surrogate": {
                "exponents": fit["exps"].tolist(),
                "length": [float(f"{c:.9g}") for c in fit["coef"][:, 0]],
                "moment_arms": {jn: [float(f"{c:.9g}") for c in fit["coef"][:, 1 + k]]
                                for k, jn in enumerate(joints)},
            },
            "fit": {
                "degree": fit["degree"],
                "length_rms_mm": round(float(fit["rms"][0]) * 1e3, 4),
                "length_max_mm": round(float(fit["max"][0]) * 1e3, 4),
                "moment_arm_rms_mm": {jn: round(float(fit["rms"][1 + k]) * 1e3, 4)
                                      for k, jn in enumerate(joints)},
                "moment_arm_max_mm": {jn: round(float(fit["max"][1 + k]) * 1e3, 4)
                                      for k, jn in enumerate(joints)},
                "excluded_samples": fit["excluded"],
                "sign_violations": {jn: int(fit["sign_violations"][k])
                                    for k, jn in enumerate(joints)},
                "sign_constraints": fit["sign_constraints"],
                "pair_bases": {joints[k]: {"joints": [joints[j] for j in S], "degree": D}
                               for k, (S, D) in fit["pair_bases"].items()},
                "jumps": sum(1 for jp in jumps if jp["muscle"] == name),
                "repaired": {"fit": int(mf[:, i].sum() + mef[uf, i].sum()),
                             "held_out": int(mt[:, i].sum()),
                             "edge_held_out": int(met[ut, i].sum())},
                "moment_arm_rms_unrepaired_mm": {
                    jn: round(float(np.sqrt(np.mean(err[clean, k] ** 2))) * 1e3, 4)
                    for k, jn in enumerate(joints)},
                "moment_arm_rms_vs_artefact_mm": {
                    jn: round(float(np.sqrt(np.mean(err[~clean, k] ** 2))) * 1e3, 4)
                    for k, jn in enumerate(joints)} if (~clean).any() else {},
            },
        })
        print(f"{name:8s} deg {fit['degree']} K {len(fit['exps']):4d} "
              f"L {fit['rms'][0] * 1e3:.3f} mm  r max-RMS {fit['rms'][1:].max() * 1e3:.3f} mm "
              f"excl {fit['excluded']} sign viol {int(fit['sign_violations'].sum())} "
              f"constr {fit['sign_constraints']} pairs {fit['pair_bases']}", flush=True)
    envelope_errors(src, muscles, center, half, rng, sizes.n_envelope, fix)
    if heldout is not None:
        write_heldout(src, heldout, np.random.default_rng(seed + 1000), fix=fix)
    source = source if not own else {
        "name": "MyoSuite myo_sim MyoArm (myoarm_r), MuJoCo",
        "version": src.version,
        "licence": "Apache-2.0",
        "url": "https://github.com/MyoHub/myo_sim (PyPI: myo-sim)",
        "notice": ("Muscle parameters and path geometry derived from MyoSim "
                   "(MyoSuite, Apache License 2.0; copyright its authors: Vittorio "
                   "Caggiano, Huiyi Wang et al.), itself converted from the MoBL "
                   "upper-extremity model and a hand model; see "
                   "muscles_myoarm.LICENSE for the licence text."),
        "derived_by": "python -m forearm_dynamics.muscles.fit (forearm_dynamics)",
        "mapping": {k: {"source_joint": v[0], "sign": v[1]} for k, v in JOINT_MAP.items()},
        "held": "every shoulder joint at 0 (arm at the side), MCP abductions at 0",
        "parameter_rule": ("L0 = (lengthrange_hi - lengthrange_lo) / (range_hi - range_lo); "
                           "LTs = lengthrange_lo - range_lo * L0; where that is < 0 "
                           "(PQ, OP, RI3): LTs = 0, L0 = lengthrange_hi / range_hi; "
                           "pennation 0; "
                           "vmax 10 L0/s"),
    }
    if own and xml is not None:
        source.update(name=f"MuJoCo model {xml}", licence="as stated by that model",
                      url=str(xml), notice="derived from the user's own model")
    doc = {
        "format": "forearm_dynamics.muscles/1",
        "side": "right",
        "source": source,
        "body_size": {"reference": "50th-percentile male (model.yaml)"},
        "joints": {"names": list(JOINT_NAMES), "center": center.tolist(),
                   "half_range": half.tolist()},
        "fit": {"samples": sizes.n_fit, "held_out": sizes.n_test, "seed": seed, "target_mm": 1.0,
                "edge_samples": len(qef), "edge_held_out": len(qet),
                "sign_min_mm": SIGN_MIN_M * 1e3, "one_signed_min_mm": ONE_SIGNED_MIN_M * 1e3,
                "max_degree": MAX_DEGREE, "max_terms": MAX_TERMS,
                "pair_degrees": list(PAIR_DEGREES), "opensim_max_terms": OPENSIM_MAX_TERMS,
                "jump_tolerance_mm": JUMP_TOL * 1e3, "jumps": jumps[:200],
                "wrap_repair": {"rule": WRAP_REPAIR_RULE, "applied": fix.limits is not None,
                                "postures_evaluated": fix.evaluated,
                                "step_deg": STEP_DEG, "refine_deg": REFINE_DEG},
                "n_jumps": len(jumps), "seconds": round(time.perf_counter() - t0, 1)},
        "muscles": muscles,
    }
    out.write_text(json.dumps(doc, separators=(",", ":")) + "\n", encoding="utf-8")
    return doc


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--heldout", type=Path, default=HELDOUT,
                    help="where to write the held-out source geometry the tests compare with")
    ap.add_argument("--xml", type=Path, default=None,
                    help="a MuJoCo model of your own (MyoArm's joint names) instead of MyoArm")
    ap.add_argument("--docs", type=Path, nargs="?", const=Path("docs/muscles.md"),
                    help="only rewrite the per-pair error block of this doc from the -o file")
    args = ap.parse_args(argv)
    if args.docs is not None:
        write_docs(json.loads(args.output.read_text(encoding="utf-8")), args.docs)
        return 0
    doc = build(args.output, args.seed, None if args.xml else args.heldout, args.xml)
    pairs = [(m["fit"]["moment_arm_rms_mm"][j], m["name"], j)
             for m in doc["muscles"] for j in m["spans"]]
    pairs.sort(reverse=True)
    print(f"wrote {args.output}: {len(doc['muscles'])} muscles, {len(pairs)} pairs, "
          f"{doc['fit']['n_jumps']} jump steps; worst pairs (RMS mm):")
    for r, n, j in pairs[:10]:
        print(f"  {n} {j}: {r:.3f}")
    env = sorted(((m["fit"]["movement_box_moment_arm_rms_mm"][j], m["name"], j)
                  for m in doc["muscles"] for j in m["spans"]), reverse=True)
    print(f"over the movements' box: {sum(r <= 1.0 for r, _, _ in env)}/{len(env)} pairs "
          "<= 1 mm; worst:")
    for r, n, j in env[:10]:
        print(f"  {n} {j}: {r:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
