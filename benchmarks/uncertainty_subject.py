"""The σ's subject part (issue 19 part 4, uncertainty/subject.py) on one movement: its size,
how well its first order explains real people, and what it costs.

    nice -n 15 .venv/bin/python benchmarks/uncertainty_subject.py            (~1 min loaded)

No ROS. Sections of benchmarks/uncertainty_subject.json:
  - size: per DOF group, the RMS over the movement (exact states at 1 kHz, every --every-th
    sample) of σ_subject, of |τ| and of the model part, for the default model at men's 50th
    and women's 50th percentile, a custom body size of the men's 50th stature and mass
    (ANSUR group "all": both sexes pooled), and the men's 50th with the three lengths
    measured (only the masses spread);
  - published: RMS of the σ as published by default and with subject "ansur", the offline
    API on the movement (warm samples) at 100 Hz with 0.5 deg of noise (the figure's stream)
    and at 1 kHz with 0.1 deg;
  - real_people: every ANSUR man's residuals (n = 4082) as a model (perturbed_tree), the RMS
    of his torques minus the model's against the first-order σ of the JSON covariance,
    pooled per group (RMS σ / RMS difference) and per DOF (min, max of the ratio);
  - cost: SubjectSpread.variance per call against one RNEA in the same run, and
    TorqueStd.update on a 1 kHz stream with subject "none" and "ansur" (median, mean, p99,
    µs; alternated, two rounds).
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pinocchio as pin

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from benchmarks.stats import loadavg, machine_info, percentiles, save_sections  # noqa: E402
from forearm_dynamics.description import DOF_GROUPS, JOINT_NAMES  # noqa: E402
from forearm_dynamics.dynamics import build_model, pinocchio_model  # noqa: E402
from forearm_dynamics.estimation import make_estimator  # noqa: E402
from forearm_dynamics.movements import get_movement  # noqa: E402
from forearm_dynamics.uncertainty import inverse_dynamics_with_std  # noqa: E402
from forearm_dynamics.uncertainty.model_term import model_variance  # noqa: E402
from forearm_dynamics.uncertainty.subject import SubjectSpread, perturbed_tree  # noqa: E402
from forearm_dynamics.uncertainty.subject_stats import derive  # noqa: E402
from forearm_dynamics.uncertainty.torque_std import TorqueStd  # noqa: E402

GROUP_IDX = {g: [JOINT_NAMES.index(d) for d in dofs] for g, dofs in DOF_GROUPS.items()}
LENGTHS = ("forearm_length", "hand_length", "hand_breadth")


def group_rms(x: np.ndarray) -> dict[str, float]:
    """RMS per DOF group over samples (rows) and the group's DOFs (columns)."""
    return {g: float(np.sqrt(np.mean(x[:, i] ** 2))) for g, i in GROUP_IDX.items()}


def states(movement, every: int):
    t = movement.sample_times(1000.0)[::every]
    return movement.evaluate(t)


def size_section(q, qd, qdd) -> dict:
    cases = {
        "male_50": (50, {}),
        "female_50": ("female_50", {}),
        "custom_male_50_stature_mass": ({"stature": 1.755, "body_mass": 84.6}, {}),
        "male_50_lengths_measured": (50, {"measured": LENGTHS}),
    }
    out = {}
    for name, (size, kw) in cases.items():
        arm = build_model(body_size=size)
        spread = SubjectSpread(arm, **kw)
        sig = np.array([np.sqrt(spread.variance(*s)) for s in zip(q, qd, qdd, strict=True)])
        tau = arm.inverse_dynamics_batch(q, qd, qdd)
        out[name] = {"group": spread.group, "sigma_subject_rms": group_rms(sig),
                     "tau_rms": group_rms(tau),
                     "model_std": group_rms(np.sqrt(model_variance(arm)[0])[None, :]),
                     "sigma_subject_rms_per_dof": dict(zip(JOINT_NAMES, np.sqrt((sig**2).mean(0)).tolist(),
                                                           strict=True))}
    return out


STREAMS = {"100hz_0.5deg": (100.0, 0.5), "1khz_0.1deg": (1000.0, 0.1)}


def published_section(movement) -> dict:
    """RMS σ per group as published (warm samples), subject none and ansur, for two streams."""
    arm = build_model()
    out = {}
    for name, (rate, noise_deg) in STREAMS.items():
        t = movement.sample_times(rate)
        q = movement.evaluate(t)[0]
        qn = q + np.random.default_rng(0).normal(0.0, np.radians(noise_deg), q.shape)
        for subject in ("none", "ansur"):
            r = inverse_dynamics_with_std(arm, t, qn, subject=subject)
            ok = r.warm & np.isfinite(r.std).all(axis=1)
            out[f"{name}_{subject}"] = group_rms(r.std[ok])
    return out


def real_people_section(q, qd, qdd) -> dict:
    arm = build_model(body_size=50)
    _, residuals = derive()
    spread = SubjectSpread(arm)  # the JSON's covariance: what is published
    pred = np.array([np.sqrt(spread.variance(*s)) for s in zip(q, qd, qdd, strict=True)])
    tau0 = arm.inverse_dynamics_batch(q, qd, qdd)
    ss = np.zeros_like(tau0)
    for r in residuals["male"]:
        m = pinocchio_model(perturbed_tree(arm, r))
        d = m.createData()
        for k in range(len(q)):
            ss[k] += (pin.rnea(m, d, q[k], qd[k], qdd[k]) - tau0[k]) ** 2
    rms = np.sqrt(ss / len(residuals["male"]))
    per_dof = np.sqrt((pred**2).mean(0)) / np.sqrt((rms**2).mean(0))
    p, r = group_rms(pred), group_rms(rms)
    return {"n": len(residuals["male"]), "ratio": {g: p[g] / r[g] for g in p},
            "ratio_per_dof_min": float(per_dof.min()), "ratio_per_dof_max": float(per_dof.max()),
            "rms_difference": r}


def cost_section(movement, reps: int) -> dict:
    arm = build_model()
    spread = SubjectSpread(arm)
    q, qd, qdd = states(movement, 50)
    k = len(q) // 2
    model, data = arm.model, arm.data
    rnea, var = [], []
    for _ in range(reps):
        t0 = time.perf_counter_ns()
        pin.rnea(model, data, q[k], qd[k], qdd[k])
        t1 = time.perf_counter_ns()
        spread.variance(q[k], qd[k], qdd[k])
        t2 = time.perf_counter_ns()
        rnea.append(t1 - t0)
        var.append(t2 - t1)
    out = {"rnea_us": percentiles(rnea, 1e-3), "subject_variance_us": percentiles(var, 1e-3)}
    out["variance_over_rnea_p50"] = out["subject_variance_us"]["p50"] / out["rnea_us"]["p50"]
    t = movement.sample_times(1000.0)
    qs = movement.evaluate(t)[0]
    for rnd in (1, 2):  # alternated, twice: the machine's load moves between runs
        for subject in ("none", "ansur"):
            est = make_estimator("kalman", arm.nv)
            ts = TorqueStd(arm, est, subject=subject)
            dts = []
            for i, tt in enumerate(t):
                tn = round(tt * 1e9)
                est.update(tn, qs[i], None)
                a = time.perf_counter_ns()
                ts.update(tn, False)
                dts.append(time.perf_counter_ns() - a)
            out[f"torque_std_update_{subject}_us_round{rnd}"] = percentiles(dts[100:], 1e-3)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--movement", type=int, default=4)
    ap.add_argument("--every", type=int, default=10, help="every n-th 1 kHz sample of the movement")
    ap.add_argument("--reps", type=int, default=3000, help="timed calls of the cost section")
    ap.add_argument("--out", default=str(HERE / "uncertainty_subject.json"))
    args = ap.parse_args(argv)
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    load0 = loadavg()
    mv = get_movement(args.movement)
    q, qd, qdd = states(mv, args.every)
    t0 = time.perf_counter()
    result = {"movement": args.movement, "samples": len(q), "size": size_section(q, qd, qdd),
              "published": published_section(mv), "real_people": real_people_section(q, qd, qdd),
              "cost": cost_section(mv, args.reps)}
    result.update(machine=machine_info(), loadavg_start=load0, loadavg_end=loadavg(),
                  seconds=round(time.perf_counter() - t0, 1))
    save_sections(Path(args.out), {"subject": result}, "benchmarks/uncertainty_subject.py", argv, started)
    print(table(result))
    return 0


def table(r: dict) -> str:
    groups = list(GROUP_IDX)
    head = (f"movement {r['movement']}, {r['samples']} states; load {r['loadavg_start'][0]:.1f} -> "
            f"{r['loadavg_end'][0]:.1f} (2 cores)")
    lines = [head, "",
             "| model | ANSUR group | " + " | ".join(groups) + " |", "|---|---|" + "---|" * len(groups)]
    for name, s in r["size"].items():
        sig, tau = s["sigma_subject_rms"], s["tau_rms"]
        cells = [f"{sig[g]:.3g} ({100 * sig[g] / tau[g]:.1f} %)" for g in groups]
        lines.append(f"| {name} | {s['group']} | " + " | ".join(cells) + " |")
    m = r["size"]["male_50"]
    lines.append("| male_50: RMS torque | | " + " | ".join(f"{m['tau_rms'][g]:.3g}" for g in groups) + " |")
    lines.append("| male_50: model part | | " + " | ".join(f"{m['model_std'][g]:.3g}" for g in groups) + " |")
    for s, v in r["published"].items():
        lines.append(f"| published σ, {s} | | " + " | ".join(f"{v[g]:.3g}" for g in groups) + " |")
    rp = r["real_people"]
    lines += ["", f"real men (n = {rp['n']}): first-order σ / RMS difference: "
              + ", ".join(f"{g} {rp['ratio'][g]:.3f}" for g in groups)
              + f"; per DOF {rp['ratio_per_dof_min']:.3f}-{rp['ratio_per_dof_max']:.3f}"]
    c = r["cost"]
    lines.append(f"cost: variance p50 {c['subject_variance_us']['p50']:.1f} µs (p99 "
                 f"{c['subject_variance_us']['p99']:.1f}) = {c['variance_over_rnea_p50']:.1f} RNEAs "
                 f"(p50 {c['rnea_us']['p50']:.2f} µs)")
    for rnd in (1, 2):
        cells = []
        for subject in ("none", "ansur"):
            p = c[f"torque_std_update_{subject}_us_round{rnd}"]
            cells.append(f"{subject} p50 {p['p50']:.1f} / mean {p['mean']:.1f} / p99 {p['p99']:.1f} µs")
        lines.append(f"TorqueStd.update at 1 kHz, round {rnd}: " + "; ".join(cells))
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
