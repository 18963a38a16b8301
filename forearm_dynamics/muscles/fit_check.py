"""Check the shipped surrogates' moment-arm signs against the source on fresh postures.

    python -m forearm_dynamics.muscles.fit_check [--model FILE] [--n 3000] [--seed 7]

Needs the `muscles-fit` extra (MuJoCo + myo_sim). Postures: n uniform over our joints' ranges
plus the faces and corners of that box (fit_core.edge_postures). Per (muscle, joint) pair it
counts postures where the source's moment arm exceeds 1 mm (or the pair is one-signed in the
source and it exceeds 0.1 mm) and the surrogate has the other sign, apart from those within
10° of a wrapping jump the fit recorded for the pair; split into postures whose joints the
muscle crosses are all inside MyoArm's own joint limits, and those past them (our wrist
flexes to 80°, MyoArm's to 45°: geometry the source was never built for). Why a separate
check: the fit's own record (`sign_violations`) does not make this split, and a check on
postures the fit never saw is the stronger evidence. The same fresh uniform postures give
each pair's RMS (`rms_errors`): the fit chose each pair's basis by its own held-out
postures, so these are the unbiased figures. Both compare with the fit's target, the source
with its wrapping jumps past its own limits repaired (wrap_repair.py, the same rule on these
postures); `rms_errors` also gives each pair's RMS against the raw source on the postures
the rule left alone, and how many it repaired.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..description import JOINT_NAMES
from .fit import DEFAULT_OUT, JUMP_TOL, MyoArm, find_spans, joint_box
from .fit_core import JUMP_WAIVE_DEG, ONE_SIGNED_MIN_M, SIGN_MIN_M, edge_postures
from .model import load_muscle_model
from .wrap_repair import Repairer


def sign_errors(model=DEFAULT_OUT, n: int = 3000, seed: int = 7) -> list[dict]:
    src, mm = MyoArm(), load_muscle_model(model)
    doc = json.loads(Path(mm.path).read_text(encoding="utf-8"))
    lo, hi = joint_box()
    slo, shi = src.joint_limits()
    rng = np.random.default_rng(seed)
    spans = find_spans(src, lo, hi, rng)
    qt = rng.uniform(lo, hi, size=(n, 20))
    qe, _ = edge_postures(qt[: max(1, n // 20)], lo, hi, spans)
    q = np.concatenate([qt, qe])
    _, R, _ = Repairer(src, JUMP_TOL)(q, *src.evaluate(q))
    Rs = mm.moment_arms(q)
    inside_joint = (q >= slo - 1e-9) & (q <= shi + 1e-9)
    out = []
    for i, mus in enumerate(doc["muscles"]):
        sp = [JOINT_NAMES.index(j) for j in mus["spans"]]
        inside = inside_joint[:, sp].all(axis=1)
        for jn, j in zip(mus["spans"], sp):
            r, rs = R[:, i, j], Rs[:, i, j]
            one = 1 if r.min() > -ONE_SIGNED_MIN_M else -1 if r.max() < ONE_SIGNED_MIN_M else 0
            need = (np.abs(r) > SIGN_MIN_M) | ((one != 0) & (np.abs(r) > ONE_SIGNED_MIN_M))
            for jp in doc["fit"]["jumps"]:
                if (jp["muscle"], jp["joint"]) == (mus["name"], jn):
                    need &= np.abs(np.degrees(q[:, j]) - jp["at_deg"]) >= JUMP_WAIVE_DEG
            wrong = need & (np.sign(rs) != np.sign(r))
            if wrong.any():
                out.append({"muscle": mus["name"], "joint": jn, "postures": len(q),
                            "inside": int((wrong & inside).sum()),
                            "outside": int((wrong & ~inside).sum()),
                            "max_source_mm": round(float(np.abs(r[wrong]).max()) * 1e3, 2)})
    return out


def rms_errors(model=DEFAULT_OUT, n: int = 3000, seed: int = 7) -> list[tuple]:
    """(RMS mm, max mm, muscle, joint, RMS mm against the raw source on the postures the
    repair left alone, postures repaired) per spanned pair on n fresh uniform postures over
    our joints' ranges, worst first (the first two against the fit's target)."""
    src, mm = MyoArm(), load_muscle_model(model)
    lo, hi = joint_box()
    q = np.random.default_rng(seed + 1).uniform(lo, hi, size=(n, 20))
    L, R = src.evaluate(q)
    _, Rt, rep = Repairer(src, JUMP_TOL)(q, L, R)
    Rs = mm.moment_arms(q)
    err, raw = Rs - Rt, Rs - R
    out = [(float(np.sqrt(np.mean(err[:, i, j] ** 2))) * 1e3,
            float(np.abs(err[:, i, j]).max()) * 1e3, name, JOINT_NAMES[j],
            float(np.sqrt(np.mean(raw[~rep[:, i], i, j] ** 2))) * 1e3, int(rep[:, i].sum()))
           for i, name in enumerate(mm.names)
           for j in (JOINT_NAMES.index(jn) for jn in mm.spans[i])]
    return sorted(out, reverse=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=str(DEFAULT_OUT))
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    errs = sign_errors(args.model, args.n, args.seed)
    for e in errs:
        print(f"{e['muscle']} {e['joint']}: {e['inside']} inside MyoArm's limits, "
              f"{e['outside']} past them (of {e['postures']}; |r| up to {e['max_source_mm']} mm)")
    print(f"{len(errs)} pairs with a sign error; {sum(e['inside'] > 0 for e in errs)} inside "
          "MyoArm's own joint limits")
    rms = rms_errors(args.model, args.n, args.seed)
    print(f"moment-arm RMS on {args.n} fresh uniform postures, against the fit's target: "
          f"{sum(r[0] <= 1.0 for r in rms)} / {len(rms)} pairs <= 1 mm, median "
          f"{np.median([r[0] for r in rms]):.2f} mm; above 1 mm: "
          + (", ".join(f"{m} {j} {r:.2f} (max {mx:.1f})" for r, mx, m, j, *_ in rms
                       if r > 1.0) or "none"))
    clean = sorted(((r[4], r[2], r[3]) for r in rms), reverse=True)
    print(f"against the raw source where the repair changed nothing: "
          f"{sum(c <= 1.0 for c, *_ in clean)} / {len(clean)} pairs <= 1 mm, worst "
          + ", ".join(f"{m} {j} {c:.2f}" for c, m, j in clean[:3]))
    rep = {r[2]: r[5] for r in rms if r[5]}
    print("postures repaired (wrapping jumps past MyoArm's limits): "
          + (", ".join(f"{m} {k} of {args.n}" for m, k in rep.items()) or "none"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
