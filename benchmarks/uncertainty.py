"""Calibration of the torque σ (issue 19): is the band as wide as the error, per DOF group?

    .venv/bin/python benchmarks/uncertainty.py             (all 65 movements, ~3-6 min loaded)
    .venv/bin/python benchmarks/uncertainty.py --every 4   (a quarter: tuning runs)

No ROS: the offline API (uncertainty.inverse_dynamics_with_std), i.e. the same estimator
update() calls and TorqueStd as torque_node, one per sample. Streams: the estimation
benchmark's (benchmarks/estimation.py Truth: each movement after 0.5 s of held start posture,
estimator reset per movement, Gaussian noise on every joint), for the sensor zoo below
and the exact input of trajectory_publisher (1 kHz, exact velocities). The σ is scored
against the SAME model's torques at the exact analytic state (the model part is left out:
that truth has no model error; check_bag scores it the same way), over the movements'
samples (the held lead is not scored):
  - coverage: the fraction of samples with |τ - τ_true| <= 1.96 σ, per DOF group (all its
    DOFs' samples together);
  - ratio: RMS(σ) / RMSE per group.
Targets: coverage 0.90-0.98 and ratio 0.8-1.5 for every group of every zoo row. Also the
uncalibrated variants, which must miss them: the raw filter posterior P without the lag
part ("posterior"), and the noise covariance without the lag part ("no_lag").

Writes benchmarks/uncertainty.json.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from benchmarks.estimation import GROUP_IDX, Truth, machine  # noqa: E402
from benchmarks.stats import write_json  # noqa: E402
from forearm_dynamics.dynamics import build_model  # noqa: E402
from forearm_dynamics.uncertainty import inverse_dynamics_with_std  # noqa: E402

SEED = 20261201
#: (label, rate Hz, position noise deg, velocity noise deg/s or None = positions only).
#: Until the sensors helper's zoo (benchmarks/sensors.py) lands: the estimation benchmark's
#: Gaussian noise model at the rates its rows use.
ZOO = (
    ("mocap_100hz", 100.0, 0.5, None),
    ("glove_30hz", 30.0, 2.0, None),
    ("imu_250hz", 250.0, 0.1, None),
    ("encoder_1khz", 1000.0, 0.1, 2.0),
    ("exact_1khz", 1000.0, 0.0, 0.0),
)
COVERAGE = (0.90, 0.98)
RATIO = (0.8, 1.5)
VARIANTS = {"calibrated": {}, "no_lag": {"lag": False},
            "posterior": {"lag": False, "covariance": "posterior"}}


def stream(arm, truth: Truth, noise_deg: float, vel_dps: float | None, seed: int, every: int,
           offset: int = 0, **kw) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(error, σ, σ_est², σ_lag²) over the scored samples of every `every`-th movement."""
    rng = np.random.default_rng(seed)
    errs, stds, ve, vl = [], [], [], []
    for k, (_mv, stamps, _t, q, qd, qdd, i0) in enumerate(truth.items):
        zq = q + rng.normal(0.0, math.radians(noise_deg), q.shape) if noise_deg else q
        zv = None
        if vel_dps is not None:
            zv = qd + rng.normal(0.0, math.radians(vel_dps), qd.shape) if vel_dps else qd
        if (k - offset) % every:
            continue
        out = inverse_dynamics_with_std(arm, stamps, zq, zv, model=False, t_in_ns=True, **kw)
        tau = truth.tau[k]
        errs.append(out.tau[i0:] - tau)
        stds.append(out.std[i0:])
        ve.append(out.var_est[i0:])
        vl.append(out.var_lag[i0:])
    return tuple(np.concatenate(x) for x in (errs, stds, ve, vl))


def zoo_stream(arm, sensor, every: int, seed: int, offset: int = 0, **kw):
    """(error, σ, σ_est², σ_lag²) of benchmarks/sensors.py's sensor over every `every`-th
    movement: each after 0.5 s held, its own stream (a fresh estimator per movement: the API
    call), joints the sensor does not measure held (their truth too), gaps dropped."""
    from benchmarks import sensors
    from forearm_dynamics.movements import movement_library

    rng = np.random.default_rng(seed)
    rate = sensor.rate_hz
    errs, stds, ve, vl = [], [], [], []
    for mv in movement_library()[offset::every]:
        ev = sensors.held_movement(mv, sensor.measured)
        t = np.concatenate([np.arange(-round(0.5 * rate), 0) / rate, mv.sample_times(rate)])
        q, qd, qdd = ev(t)
        keep, z, zv = sensors.stream(sensor, mv, q, qd, rng)
        sel = np.flatnonzero(keep)
        out = inverse_dynamics_with_std(arm, t[sel], z[sel], None if zv is None else zv[sel],
                                        model=False, **kw)
        i0 = int(np.searchsorted(t[sel], 0.0))
        tau = arm.inverse_dynamics_batch(q[sel][i0:], qd[sel][i0:], qdd[sel][i0:])
        errs.append(out.tau[i0:] - tau)
        stds.append(out.std[i0:])
        ve.append(out.var_est[i0:])
        vl.append(out.var_lag[i0:])
    return tuple(np.concatenate(x) for x in (errs, stds, ve, vl))


def score(err: np.ndarray, std: np.ndarray, ve: np.ndarray, vl: np.ndarray) -> dict:
    """Per group: coverage, ratio, and the parts' RMS as ratios to the RMSE (est, lag)."""
    out = {}
    for g, idx in GROUP_IDX.items():
        e, s = err[:, idx], std[:, idx]
        ok = np.isfinite(s)
        e, s, a, b = e[ok], s[ok], ve[:, idx][ok], vl[:, idx][ok]
        rmse = float(np.sqrt(np.mean(e**2)))
        out[g] = {"coverage": float(np.mean(np.abs(e) <= 1.96 * s)),
                  "ratio": float(np.sqrt(np.mean(s**2)) / rmse) if rmse > 0 else math.inf,
                  "rmse_nm": rmse, "rms_std_nm": float(np.sqrt(np.mean(s**2))),
                  "est_ratio": float(np.sqrt(np.mean(a)) / rmse) if rmse > 0 else math.inf,
                  "lag_ratio": float(np.sqrt(np.mean(b)) / rmse) if rmse > 0 else math.inf}
    return out


def met(groups: dict) -> bool:
    return all(COVERAGE[0] <= v["coverage"] <= COVERAGE[1] and RATIO[0] <= v["ratio"] <= RATIO[1]
               for v in groups.values())


def line(label: str, variant: str, groups: dict) -> str:
    cells = " ".join(f"{g} {v['coverage']:.3f}/{v['ratio']:.2f}({v['est_ratio']:.2f},{v['lag_ratio']:.2f})"
                     for g, v in groups.items())
    return f"{label:13s} {variant:10s} {cells}  {'met' if met(groups) else 'MISSED'}"


FIGURE_MOVEMENT = 3  # wrist_pronation with the elbow flexing: elbow and pro/sup move
FIGURE_DOFS = ("elbow_flexion", "pro_sup", "wrist_flexion")


def figure(arm, path: Path, seed: int = SEED) -> dict:
    """Torque ± 2σ against the truth for one movement, 100 Hz mocap-like input (0.5 deg):
    the inner band is the σ without the model part (what covers the same-model truth drawn
    here), the outer one the published σ (model part included). Returns its coverage."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from forearm_dynamics.movements import movement_library

    mv = movement_library()[FIGURE_MOVEMENT]
    rate = 100.0
    t = np.concatenate([np.arange(-round(0.5 * rate), 0) / rate, mv.sample_times(rate)])
    q, qd, qdd = mv.evaluate(t)
    rng = np.random.default_rng(seed)
    out = inverse_dynamics_with_std(arm, t, q + rng.normal(0.0, math.radians(0.5), q.shape))
    truth = arm.inverse_dynamics_batch(q, qd, qdd)
    inner = np.sqrt(out.var_est + out.var_lag)
    fig, axes = plt.subplots(len(FIGURE_DOFS), 1, figsize=(8, 7), sharex=True)
    cover = {}
    for ax, name in zip(axes, FIGURE_DOFS, strict=True):
        j = arm.joint_names.index(name)
        ok = np.isfinite(out.std[:, j])
        ax.fill_between(t[ok], (out.tau - 2 * out.std)[ok, j], (out.tau + 2 * out.std)[ok, j],
                        color="tab:blue", alpha=0.15, lw=0, label="± 2σ published (model part included)")
        ax.fill_between(t[ok], (out.tau - 2 * inner)[ok, j], (out.tau + 2 * inner)[ok, j],
                        color="tab:blue", alpha=0.35, lw=0, label="± 2σ estimation + lag")
        ax.plot(t, out.tau[:, j], color="tab:blue", lw=1, label="torque (node, noisy input)")
        ax.plot(t, truth[:, j], color="k", lw=1, ls="--", label="truth (exact state, same model)")
        ax.set_ylabel(f"{name}\nN·m")
        cover[name] = float(np.mean(np.abs(out.tau - truth)[ok, j] <= 2 * inner[ok, j]))
    axes[0].set_title(f"{mv.name}, {mv.elbow}: 100 Hz, 0.5 deg noise, kalman (movement {mv.id})")
    axes[0].legend(fontsize=7, loc="best")
    axes[-1].set_xlabel("s from the movement start (0.5 s held before)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"path": str(path), "movement": mv.id, "within_2sigma": cover}


def table(section: dict) -> str:
    """docs/uncertainty.md's calibration table from a results file (--table)."""
    groups = ("pro_sup", "elbow", "wrist", "thumb", "fingers")
    out = ["| input | σ | " + " | ".join(groups) + " | targets |", "|---|---|" + "---|" * (len(groups) + 1)]
    for r in section["rows"]:
        cells = [f"{r['groups'][g]['coverage']:.3f} / {r['groups'][g]['ratio']:.2f}" for g in groups]
        out.append(f"| {r['row']} | {r['variant']} | " + " | ".join(cells)
                   + f" | {'met' if r['met'] else 'missed'} |")
    m = section["machine"]
    out.append(f"\nLoad average {m['loadavg_start'][0]:.1f} at the start, {m['loadavg_end'][0]:.1f} at "
               f"the end ({m['cores']} cores); {section['wall_time_s']:.0f} s; `{section['command']}`.")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--every", type=int, default=1, help="score every N-th movement (tuning: 4)")
    ap.add_argument("--offset", type=int, default=0,
                    help="start at this movement (with --every 8: 0 = the tuning set, 4 = held out)")
    ap.add_argument("--gain", type=float, default=None, help="lag gain (default: lag.LAG_GAIN)")
    ap.add_argument("--tau", type=float, default=None,
                    help="jerk RMS time constant s (default: lag.JERK_TAU_S)")
    ap.add_argument("--rows", default="", help="comma-separated row / zoo sensor names (default: all)")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--out", default=str(HERE / "uncertainty.json"))
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--zoo", action=argparse.BooleanOptionalAction, default=True,
                    help="also benchmarks/sensors.py's sensor zoo (held joints, coloured noise, "
                         "spikes, quantisation, gaps)")
    ap.add_argument("--figure", default=str(HERE.parent / "docs" / "uncertainty.png"),
                    help="torque ± 2σ vs truth for one movement ('' = none)")
    ap.add_argument("--table", action="store_true", help="print the docs table from --out, run nothing")
    args = ap.parse_args(argv)
    if args.table:
        import json

        print(table(json.loads(Path(args.out).read_text())))
        return 0
    wall = time.perf_counter()
    info = machine()
    arm = build_model("segmented")
    want = set(filter(None, args.rows.split(",")))
    rows = []
    truths: dict[float, Truth] = {}
    for i, (label, rate, noise, vel) in enumerate(ZOO):
        if want and label not in want:
            continue
        truth = truths.get(rate) or truths.setdefault(rate, Truth(arm, rate))
        for variant in args.variants.split(","):
            kw = dict(VARIANTS[variant])
            if variant == "calibrated":
                kw.update({k: v for k, v in (("gain", args.gain), ("tau_s", args.tau)) if v is not None})
            err, std, ve, vl = stream(arm, truth, noise, vel, SEED + i, args.every, args.offset, **kw)
            groups = score(err, std, ve, vl)
            rows.append({"row": label, "rate_hz": rate, "noise_deg": noise, "velocity_noise_dps": vel,
                         "variant": variant, "groups": groups, "met": met(groups),
                         "samples": len(err)})
            print(line(label, variant, groups), flush=True)
    if args.zoo:
        from benchmarks import sensors

        for i, sensor in enumerate(sensors.zoo()):
            if want and sensor.name not in want:
                continue
            for variant in args.variants.split(","):
                kw = dict(VARIANTS[variant])
                kw.update({k: v for k, v in (("gain", args.gain), ("tau_s", args.tau))
                           if v is not None and variant == "calibrated"})
                err, std, ve, vl = zoo_stream(arm, sensor, args.every, SEED + 100 + i, args.offset, **kw)
                groups = score(err, std, ve, vl)
                rows.append({"row": f"zoo:{sensor.name}", "rate_hz": sensor.rate_hz,
                             "sensor": sensor.name, "source": sensor.source, "variant": variant,
                             "groups": groups, "met": met(groups), "samples": len(err)})
                print(line(sensor.name, variant, groups), flush=True)
    info["loadavg_end"] = list(os.getloadavg())
    cal = [r for r in rows if r["variant"] == "calibrated"]
    command = ("python benchmarks/uncertainty.py" + (f" --every {args.every}" if args.every > 1 else "")
               + (f" --offset {args.offset}" if args.offset else ""))
    section = {"command": command,
               "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": info,
               "targets": {"coverage": COVERAGE, "ratio": RATIO,
                           "met": bool(cal) and all(r["met"] for r in cal)},
               "zoo": [dict(zip(("label", "rate_hz", "noise_deg", "velocity_noise_dps"), z, strict=True))
                       for z in ZOO],
               "rows": rows, "wall_time_s": time.perf_counter() - wall}
    if args.figure:
        section["figure"] = figure(arm, Path(args.figure))
        print(f"figure {args.figure}: within ±2σ {section['figure']['within_2sigma']}")
    print(f"targets met: {section['targets']['met']}; load {info['loadavg_start']} -> "
          f"{info['loadavg_end']}; {section['wall_time_s']:.0f} s")
    if not args.no_write:
        write_json(Path(args.out), section)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
