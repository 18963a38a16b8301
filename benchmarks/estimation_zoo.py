"""The sensor zoo and the real recordings through the estimators; the delay-accuracy curve.

    .venv/bin/python benchmarks/estimation_zoo.py [--recordings DIR] [--every 4]
    (make bench-estimation runs it after benchmarks/estimation.py)

No ROS: each estimator's update() calls, as torque_node makes them. For every sensor of
benchmarks/sensors.py, every `--every`-th movement of the library (16 of 65 by default: a
short run on a loaded machine) is streamed as that sensor delivers it (rate, joints, noise,
spikes, quantisation, gaps; one noise draw shared by every estimator), one movement after
the other through ONE estimator (reset at each movement start, as the node does after a
stamp gap). Torques of the segmented model at the estimates are scored against the truth
(the movement, with the joints the sensor does not measure held) at the delivered samples:
global NRMSE per DOF group (RMSE over the movements / the DOF's torque range over the
library, averaged over the group), as benchmarks/estimation.py. Also the qdd lag (delay
minimising the squared error against the truth, moving DOFs), the CPU time of each
update() call (median, p99; `backward` measured in the same run as the cost baseline).
Estimators: kalman (the default), kalman with delay_s 0.05, the causal 6 Hz Butterworth
baseline, the OpenSimRT-style window (35 samples, 14 back), and the offline floor (6 Hz
zero-phase + derivatives of the same noisy stream; not causal).

Real recordings: scored against the offline practice on the same data (no truth exists).
Delay-accuracy curve: mocap IK at 100 Hz, kalman delay_s 0 .. 0.2 s, against the floor,
the baseline and the OpenSimRT-style window at its own delay; figure estimation_delay.png.
Writes the `estimation_zoo` key of benchmarks/results.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sensors

from forearm_dynamics.description import JOINT_NAMES
from forearm_dynamics.dynamics import build_model
from forearm_dynamics.estimation import make_estimator
from forearm_dynamics.estimation.offline import zero_phase
from forearm_dynamics.filtering import analysis_config
from forearm_dynamics.movements import movement_library

HERE = Path(__file__).resolve().parent
SEED = 20261201
LEAD_S = 0.5
GAP_S = 1.0
DELAYS_S = (0.0, 0.01, 0.025, 0.05, 0.1, 0.14, 0.2)  # 0.14: OpenSimRT's 14 samples at 100 Hz


#: estimators added by --add (label, name, settings), scored after the standard ones
EXTRA: list[tuple[str, str, dict]] = []


def candidates() -> list[tuple[str, str, dict]]:
    return [("kalman", "kalman", {}), ("kalman_delay_50ms", "kalman", {"delay_s": 0.05}),
            ("baseline", "butterworth", {"butterworth_cutoff_hz": 6.0}),
            ("opensimrt_style", "opensimrt_style", {}), ("backward", "backward", {}), *EXTRA]


def build(name: str, settings: dict, n: int):
    if name == "opensimrt_style":
        return sensors.OpenSimRTStyle(n, settings)
    return make_estimator(name, n, settings)


class SensorRun:
    """The delivered streams and truths of one sensor over the chosen movements."""

    def __init__(self, arm, sensor: sensors.Sensor, movements, seed: int):
        rng = np.random.default_rng(seed)
        self.sensor, self.items, t0 = sensor, [], 0
        rate = sensor.rate_hz
        for mv in movements:
            ev = sensors.held_movement(mv, sensor.measured)
            t = np.concatenate([np.arange(-round(LEAD_S * rate), 0) / rate, mv.sample_times(rate)])
            q, qd, qdd = ev(t)
            keep, z, zv = sensors.stream(sensor, mv, q, qd, rng)
            origin = t0 + round(LEAD_S * 1e9)
            stamps = origin + np.round(t * 1e9).astype(np.int64)
            sel = np.flatnonzero(keep)
            i0 = int(np.searchsorted(t[sel], 0.0))
            tau = arm.inverse_dynamics_batch(q[sel][i0:], qd[sel][i0:], qdd[sel][i0:])
            self.items.append({"mv": mv, "ev": ev, "stamps": stamps[sel], "t": t[sel], "z": z[sel],
                               "zv": None if zv is None else zv[sel], "i0": i0, "tau": tau})
            t0 = int(stamps[-1]) + round(GAP_S * 1e9)


def run(est_factory, srun: SensorRun):
    outs, cpu = [], []
    clock = time.perf_counter_ns
    est = est_factory()
    for it in srun.items:
        if srun.sensor.fresh:
            est = est_factory()
        est.reset()
        st, z, zv = it["stamps"], it["z"], it["zv"]
        n = len(st)
        res = np.zeros((3, n, z.shape[1]))
        res[0] = z
        rows = {int(s): k for k, s in enumerate(st)}
        ns = np.empty(n, np.int64)
        for k in range(n):
            c0 = clock()
            est.update(int(st[k]), z[k], None if zv is None else zv[k])
            ns[k] = clock() - c0
            if est.stamp_ns is not None:
                i = rows[est.stamp_ns]
                res[0, i], res[1, i], res[2, i] = est.q, est.qd, est.qdd
        for s, x in est.drain():
            res[:, rows[s]] = x
        outs.append(res)
        cpu.append(ns)
    return outs, np.concatenate(cpu)


def floor_run(srun: SensorRun):
    outs = []
    for it in srun.items:
        f, v, a = zero_phase(it["stamps"], it["z"], None, max_gap_ns=round(0.4e9))
        outs.append(np.stack([f, v, a]))
    return outs


def score(arm, srun: SensorRun, outs, ptp_lib) -> dict:
    mse = []
    for it, est in zip(srun.items, outs, strict=True):
        i0 = it["i0"]
        err = arm.inverse_dynamics_batch(est[0, i0:], est[1, i0:], est[2, i0:]) - it["tau"]
        mse.append((np.sum(err**2, axis=0), len(err)))
    tot = sum(m for m, _ in mse) / sum(n for _, n in mse)
    glob = np.sqrt(tot) / ptp_lib
    return {g: float(np.mean(glob[idx])) for g, idx in sensors.GROUP_IDX.items()}


def lag_ms(srun: SensorRun, outs) -> float:
    shifts = np.arange(0.0, 0.2005, 0.002)
    cost = np.zeros(len(shifts))
    for it, est in zip(srun.items, outs, strict=True):
        cols = [JOINT_NAMES.index(n) for n in it["mv"].moving if n in srun.sensor.measured]
        if not cols:
            continue
        t, x = it["t"][it["i0"]:], est[2][it["i0"]:, cols]
        for i, d in enumerate(shifts):
            cost[i] += np.sum((x - it["ev"](t - d)[2][:, cols]) ** 2)
    return float(shifts[int(np.argmin(cost))] * 1e3)


def library_ptp(arm) -> np.ndarray:
    taus = [arm.inverse_dynamics_batch(*mv.evaluate(mv.sample_times(1000.0))) for mv in movement_library()]
    allt = np.concatenate(taus)
    return allt.max(axis=0) - allt.min(axis=0)


def row(arm, srun, label, outs, ptp, cpu=None) -> dict:
    r = {"estimator": label, "groups": score(arm, srun, outs, ptp), "lag_qdd_ms": lag_ms(srun, outs)}
    if cpu is not None:
        r["cpu_us"] = {"p50": float(np.percentile(cpu, 50) / 1e3), "p99": float(np.percentile(cpu, 99) / 1e3)}
    return r


def sensor_section(arm, sensor, movements, ptp, seed) -> dict:
    srun = SensorRun(arm, sensor, movements, seed)
    rows = []
    for label, name, settings in candidates():
        outs, cpu = run(lambda name=name, settings=settings: build(name, settings, len(JOINT_NAMES)), srun)
        rows.append(row(arm, srun, label, outs, ptp, cpu))
        print(f"{sensor.name:18s} {label:18s} " + _fmt(rows[-1]), flush=True)
    rows.append(row(arm, srun, "offline_floor", floor_run(srun), ptp))
    print(f"{sensor.name:18s} {'offline_floor':18s} " + _fmt(rows[-1]), flush=True)
    return {"sensor": sensor.name, "rate_hz": sensor.rate_hz, "measured": list(sensor.measured),
            "source": sensor.source, "rows": rows}


def delay_curve(arm, movements, ptp, seed) -> dict:
    sensor = next(s for s in sensors.zoo() if s.name == "mocap_ik_100hz")
    srun = SensorRun(arm, sensor, movements, seed)
    pts = []
    for d in DELAYS_S:
        outs, cpu = run(lambda d=d: make_estimator("kalman", len(JOINT_NAMES), {"delay_s": d}), srun)
        pts.append({"delay_s": d, **row(arm, srun, f"kalman_delay_{d:g}", outs, ptp, cpu)})
        print(f"delay {d:5.3f} s " + _fmt(pts[-1]), flush=True)
    ref = {}
    for label, name, settings in (("baseline", "butterworth", {"butterworth_cutoff_hz": 6.0}),
                                  ("opensimrt_style", "opensimrt_style", {})):
        outs, cpu = run(lambda name=name, settings=settings: build(name, settings, len(JOINT_NAMES)), srun)
        ref[label] = row(arm, srun, label, outs, ptp, cpu)
    ref["opensimrt_style"]["delay_s"] = 14 / sensor.rate_hz
    ref["offline_floor"] = row(arm, srun, "offline_floor", floor_run(srun), ptp)
    return {"sensor": sensor.name, "points": pts, "references": ref}


def recording_section(arm, rec: sensors.Recording) -> dict:
    """Online estimators on a recording vs the offline practice on the same data."""
    f, v, a = zero_phase(rec.stamps_ns, rec.q, None)
    ref_tau = arm.inverse_dynamics_batch(f, v, a)
    ptp = np.maximum(np.ptp(ref_tau, axis=0), float(analysis_config()["ptp_floor_nm"]))
    rows = []
    rate = 1e9 / float(np.median(np.diff(rec.stamps_ns)))
    for label, name, settings in candidates():
        est = build(name, settings, len(JOINT_NAMES))
        q, qd, qdd, _ = est.run(rec.stamps_ns, rec.q)
        err = arm.inverse_dynamics_batch(q, qd, qdd) - ref_tau
        nr = np.sqrt(np.mean(err**2, axis=0)) / ptp
        groups = {g: float(np.mean(nr[idx])) for g, idx in sensors.GROUP_IDX.items()
                  if any(JOINT_NAMES[i] in rec.measured for i in idx)}
        rows.append({"estimator": label, "groups": groups,
                     "noise_believed_deg": (None if name != "kalman" else
                                            {j: math.degrees(est.noise_per_joint()[JOINT_NAMES.index(j)])
                                             for j in rec.moving})})
        cells = " ".join(f"{k}={x:.4f}" for k, x in groups.items())
        print(f"{rec.name:24s} {label:18s} {cells}", flush=True)
    d3 = sensors.third_difference_noise(rec.q)
    return {"recording": rec.name, "source": rec.source, "rate_hz": rate, "samples": len(rec.stamps_ns),
            "moving": list(rec.moving), "rows": rows,
            "third_difference_noise_deg": {j: math.degrees(d3[JOINT_NAMES.index(j)]) for j in rec.moving}}


def _fmt(r) -> str:
    g = r["groups"]
    cpu = r.get("cpu_us", {}).get("p50", float("nan"))
    cells = " ".join(f"{k}={v:.4f}" for k, v in g.items())
    return cells + f"  lag {r['lag_qdd_ms']:5.1f} ms cpu {cpu:6.1f} us"


def figure(curve: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, g in zip(axes, ("elbow", "pro_sup"), strict=True):
        d = [1e3 * p["delay_s"] for p in curve["points"]]
        ax.plot(d, [p["groups"][g] for p in curve["points"]], "o-", lw=2, label="kalman, delay_s")
        ref = curve["references"]
        ax.axhline(ref["offline_floor"]["groups"][g], color="k", ls="--",
                   label="offline floor (6 Hz zero-phase)")
        ax.axhline(ref["baseline"]["groups"][g], color="tab:red", ls=":", label="causal 6 Hz Butterworth")
        ax.plot([1e3 * ref["opensimrt_style"]["delay_s"]], [ref["opensimrt_style"]["groups"][g]], "s",
                color="tab:green", label="OpenSimRT-style (35 / 14)")
        ax.set_xlabel("delay (ms)")
        ax.set_ylabel("global torque NRMSE")
        ax.set_title(f"{g}, mocap IK 100 Hz")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(HERE / "results.json"))
    ap.add_argument("--figure", default=str(HERE / "estimation_delay.png"))
    ap.add_argument("--every", type=int, default=4, help="every n-th library movement (1: all 65)")
    ap.add_argument("--recordings", type=Path, default=None,
                    help="directory with more OpenSim IK results (see benchmarks/data/README.md)")
    ap.add_argument("--only", default="", help="comma-separated sensor names (default: all)")
    ap.add_argument("--add", default="", help="comma-separated estimator names scored beside the "
                    "standard ones at their defaults (e.g. butterworth; use with --out elsewhere: the "
                    "docs tables are the standard ones)")
    ap.add_argument("--table", action="store_true",
                    help="print the docs/estimation.md tables from --out (no benchmark run)")
    args = ap.parse_args(argv)
    if args.table:
        print(tables(json.loads(Path(args.out).read_text(encoding="utf-8"))["estimation_zoo"]))
        return 0
    wall = time.perf_counter()
    load0 = list(os.getloadavg())
    arm = build_model("segmented")
    ptp = library_ptp(arm)
    movements = movement_library()[:: args.every]
    only = {s for s in args.only.split(",") if s}
    EXTRA[:] = [(x, x, {}) for x in args.add.split(",") if x]
    secs = [sensor_section(arm, s, movements, ptp, SEED + i) for i, s in enumerate(sensors.zoo())
            if not only or s.name in only]
    curve = delay_curve(arm, movements, ptp, SEED + 100)
    recs = [recording_section(arm, r) for r in sensors.recordings(args.recordings)]
    section = {"command": "python benchmarks/estimation_zoo.py" + (f" --recordings {args.recordings}"
                                                                   if args.recordings else ""),
               "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "movements": len(movements),
               "every": args.every, "seed": SEED, "loadavg_start": load0, "sensors": secs,
               "delay_curve": curve, "recordings": recs}
    section["loadavg_end"] = list(os.getloadavg())
    section["wall_time_s"] = time.perf_counter() - wall
    section["targets"] = targets(section)
    path = Path(args.out)
    data = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
    data["estimation_zoo"] = section
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    tmp.replace(path)
    figure(curve, Path(args.figure))
    print(json.dumps(section["targets"], indent=1))
    return 0


def tables(sec: dict) -> str:
    """Markdown: per sensor and estimator, global NRMSE (%) per group, lag, us per sample;
    the recordings; the delay-accuracy curve."""
    groups = ("elbow", "pro_sup", "wrist", "thumb", "fingers")
    out = [("| sensor | estimator | elbow | pro/sup | wrist | thumb | fingers | lag q̈ (ms) "
            "| µs/sample p50 / p99 |"), "|---|---|---|---|---|---|---|---|---|"]
    for s in sec["sensors"]:
        for r in s["rows"]:
            if r["estimator"] == "backward":
                continue
            g = r["groups"]
            cpu = r.get("cpu_us")
            out.append(f"| {s['sensor']} | {r['estimator']} | "
                       + " | ".join(f"{100 * g[k]:.1f}" for k in groups)
                       + f" | {r['lag_qdd_ms']:.0f} | "
                       + (f"{cpu['p50']:.0f} / {cpu['p99']:.0f}" if cpu else "-") + " |")
    out += ["", "| recording | rate | estimator | elbow | pro/sup | wrist | kalman / baseline |",
            "|---|---|---|---|---|---|---|"]
    for rec in sec["recordings"]:
        rows = {r["estimator"]: r for r in rec["rows"]}
        for r in rec["rows"]:
            if r["estimator"] == "backward":
                continue
            g = r["groups"]
            cells = " | ".join(f"{100 * g[k]:.1f}" if k in g else "-" for k in ("elbow", "pro_sup", "wrist"))
            ratio = ""
            if r["estimator"] == "kalman":
                b = rows["baseline"]["groups"]
                ratio = " / ".join(f"{g[k] / b[k]:.2f}" for k in ("elbow", "pro_sup") if k in g)
            out.append(f"| {rec['recording']} | {rec['rate_hz']:.0f} Hz | {r['estimator']} | {cells} "
                       f"| {ratio} |")
    c = sec["delay_curve"]
    ref = c["references"]
    out += ["", "| delay | elbow | pro/sup | × offline floor (elbow / pro-sup) | µs/sample p50 |",
            "|---|---|---|---|---|"]
    fl = ref["offline_floor"]["groups"]
    for p in c["points"]:
        g = p["groups"]
        out.append(f"| {1e3 * p['delay_s']:.0f} ms | {100 * g['elbow']:.2f} | {100 * g['pro_sup']:.2f} | "
                   f"{g['elbow'] / fl['elbow']:.2f} / {g['pro_sup'] / fl['pro_sup']:.2f} | "
                   f"{p['cpu_us']['p50']:.0f} |")
    for lab in ("baseline", "opensimrt_style", "offline_floor"):
        g = ref[lab]["groups"]
        d = ref[lab].get("delay_s")
        ratio = f"{g['elbow'] / fl['elbow']:.2f} / {g['pro_sup'] / fl['pro_sup']:.2f}"
        cpu = f"{ref[lab]['cpu_us']['p50']:.0f}" if "cpu_us" in ref[lab] else "-"
        out.append(f"| {lab}{'' if d is None else f' ({1e3 * d:.0f} ms)'} | {100 * g['elbow']:.2f} | "
                   f"{100 * g['pro_sup']:.2f} | {ratio} | {cpu} |")
    out += ["", (f"{sec['movements']} movements (every {sec['every']}th), load average "
                 f"{sec['loadavg_start'][0]:.1f} at the start, {sec['loadavg_end'][0]:.1f} at the end; "
                 f"{sec['wall_time_s']:.0f} s; `{sec['command']}`.")]
    return "\n".join(out)


def targets(sec: dict) -> dict:
    out = {"worse_than_baseline": [], "mocap_ratio_elbow_pro_sup": {}, "recordings_ratio": {}}
    for s in sec["sensors"]:
        rows = {r["estimator"]: r for r in s["rows"]}
        k, b = rows["kalman"]["groups"], rows["baseline"]["groups"]
        for g in k:
            if k[g] > b[g]:
                out["worse_than_baseline"].append(f"{s['sensor']}:{g} {k[g] / b[g]:.2f}")
        if s["sensor"].startswith("mocap"):
            out["mocap_ratio_elbow_pro_sup"][s["sensor"]] = [k["elbow"] / b["elbow"],
                                                             k["pro_sup"] / b["pro_sup"]]
    for r in sec["recordings"]:
        rows = {x["estimator"]: x for x in r["rows"]}
        k, b = rows["kalman"]["groups"], rows["baseline"]["groups"]
        out["recordings_ratio"][r["recording"]] = {g: k[g] / b[g] for g in k if b[g] > 0}
        out["worse_than_baseline"] += [f"{r['recording']}:{g} {k[g] / b[g]:.2f}" for g in k if k[g] > b[g]]
    c = sec["delay_curve"]
    p50 = next(p for p in c["points"] if p["delay_s"] == 0.05)
    fl, osr = c["references"]["offline_floor"]["groups"], c["references"]["opensimrt_style"]["groups"]
    out["delay_50ms_over_floor"] = {g: p50["groups"][g] / fl[g] for g in ("elbow", "pro_sup")}
    p140 = next(p for p in c["points"] if p["delay_s"] == 0.14)
    both = ("elbow", "pro_sup")
    out["delay_140ms_over_opensimrt_at_its_140ms"] = {g: p140["groups"][g] / osr[g] for g in both}
    out["delay_50ms_over_opensimrt_at_its_140ms"] = {g: p50["groups"][g] / osr[g] for g in both}
    return out


if __name__ == "__main__":
    raise SystemExit(main())
