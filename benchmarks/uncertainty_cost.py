"""What joint_torques_std costs (issue 19): torque_node with and without publish_std against
the null echo node, in the same run.

    .venv/bin/python benchmarks/uncertainty_cost.py [--movements 20] [--repeat 1] [--domain 77]

Three variants of benchmarks/torque_path.py's replay (trajectory_publisher at 1 kHz ->
node -> receiver, real processes on loopback DDS), one after the other: null_echo_node,
torque_node with publish_std false, torque_node with publish_std true (the receiver
subscribes joint_torques_std too, so the σ messages are really delivered and counted).
--repeat R runs the three R times, interleaved (the other work on a shared machine comes
and goes: each variant then meets it alike); each figure is the median over the repeats
(`runs` keeps every run). Reported: callback p50/p99 (the node's /diagnostics: entry to
the σ message published), the part spent in the torque message's publish(), torque-path
latency p50/p99, loss, and the targets: callback p50 with σ <= +30 µs over without,
latency p50 with σ <= 1.2x the null echo, 0 lost (torques and σ). The load average at
start and end is in the output: 2 cores shared with other work.
First, in this process and without DDS (`in_process`): the thread CPU time per sample
(preemption excluded) of the torque path's estimator update + RNEA and of the σ after it
(TorqueStd.update + the σ message's bytes), linearising samples apart, on four library
movements at 1 kHz with 0.1 deg noise; and (`continuous`) the σ's wall time per sample on
the replay's own stream (the movements back to back, exact, with velocities).
Writes benchmarks/uncertainty_cost.json.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from benchmarks.stats import claim_domain_arg, write_json  # noqa: E402
from benchmarks.torque_path import Variant, run_variant  # noqa: E402

VARIANTS = (
    Variant("null_echo_node", node="null_echo_node"),
    Variant("torque_node_no_std", node_args=["-p", "publish_std:=false"]),
    Variant("torque_node_std", node_args=["-p", "publish_std:=true"], also_topic="joint_torques_std"),
)


def in_process(movements=(3, 20, 37, 54), rate: float = 1000.0) -> dict:
    """Thread CPU µs per sample: {"torque_path", "std", "std_linearising", "std_other"}: p50/p99."""
    import numpy as np
    import pinocchio as pin

    from forearm_dynamics import JOINT_NAMES, build_model
    from forearm_dynamics.codec.jointstate_cdr import StdTemplate
    from forearm_dynamics.estimation import make_estimator
    from forearm_dynamics.movements import movement_library
    from forearm_dynamics.uncertainty import TorqueStd

    arm = build_model()
    lib = movement_library()
    rng = np.random.default_rng(1)
    clock = time.thread_time_ns
    rows: dict[str, list[float]] = {"torque_path": [], "std": [], "std_linearising": [], "std_other": []}
    for i in movements:
        t = lib[i].sample_times(rate)
        z = lib[i].evaluate(t)[0] + rng.normal(0.0, math.radians(0.1), (len(t), arm.nv))
        est = make_estimator("kalman", arm.nv)
        ts = TorqueStd(arm, est)
        tpl = StdTemplate(JOINT_NAMES, "")
        for k in range(len(t)):
            t_ns = round(t[k] * 1e9)
            a = clock()
            est.update(t_ns, z[k], None)
            pin.rnea(arm.model, arm.data, est.q, est.qd, est.qdd)
            b = clock()
            ts.update(t_ns, False)
            tpl.fill(0, 0, ts.std)
            c = clock()
            if k < 100:  # warm-up and the first refreshes
                continue
            rows["torque_path"].append((b - a) / 1e3)
            rows["std"].append((c - b) / 1e3)
            rows["std_linearising" if ts.evaluated_ns == t_ns else "std_other"].append((c - b) / 1e3)
    return {k: {"n": len(v), "p50": float(np.percentile(v, 50)), "p99": float(np.percentile(v, 99)),
                "mean": float(np.mean(v))} for k, v in rows.items()}


def continuous(movements: int = 10, rate: float = 1000.0) -> dict:
    """The σ's wall time per sample (µs) on the node benchmark's own input, in this process:
    library movements 1..N back to back, exact positions and velocities at 1 kHz, one
    estimator and TorqueStd for the whole stream (as the node runs); how often the filter
    regrouped and the state source re-derived, and the time in samples over 100 µs (the
    bursts that hold up a 1 kHz node)."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from forearm_dynamics import build_model
    from forearm_dynamics.estimation import make_estimator
    from forearm_dynamics.movements import movement_library
    from forearm_dynamics.uncertainty import TorqueStd

    threadpool_limits(1)  # as the nodes run (common.py)
    arm, lib = build_model(), movement_library()
    parts = [lib[i].evaluate(lib[i].sample_times(rate)) for i in range(1, movements + 1)]
    q = np.concatenate([p[0] for p in parts])
    qd = np.concatenate([p[1] for p in parts])
    est = make_estimator("kalman", arm.nv)
    ts = TorqueStd(arm, est)
    wall = np.zeros(len(q))
    derivations = regroups = 0
    version = est.groups_version
    clock = time.perf_counter_ns
    for k in range(len(q)):
        t_ns = 1_000_000_000 + round(k * 1e9 / rate)
        est.update(t_ns, q[k], qd[k])
        seated = ts.src._t
        a = clock()
        ts.update(t_ns, True)
        wall[k] = (clock() - a) / 1e3
        derivations += ts.src._t != seated
        regroups += est.groups_version != version
        version = est.groups_version
    w = wall[500:]
    return {"samples": len(q), "regroups": regroups, "derivations": derivations,
            "p50": float(np.percentile(w, 50)), "mean": float(w.mean()),
            "p99": float(np.percentile(w, 99)), "p99_9": float(np.percentile(w, 99.9)),
            "max": float(w.max()), "over_100us_ms": float(w[w > 100].sum() / 1e3),
            "seconds": len(q) / rate}


MEDIAN_OF = (("callback_us", "p50"), ("callback_us", "p99"), ("callback_us", "publish_p50"),
             ("latency_ms", "p50"), ("latency_ms", "p99"), ("node_process", "cpu_percent"))


def _medians(runs: list[dict]) -> dict[str, float]:
    """Median over the repeats of each reported figure ("callback_us.p50", ...)."""
    out = {}
    for keys in MEDIAN_OF:
        vals = []
        for r in runs:
            x = r
            for k in keys:
                x = (x or {}).get(k)
            if x is not None:
                vals.append(float(x))
        if vals:
            out[".".join(keys)] = float(statistics.median(vals))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--movements", type=int, default=20, help="library movements 1..N (65: all)")
    ap.add_argument("--repeat", type=int, default=1, help="run the three variants this often, interleaved")
    ap.add_argument("--domain", type=int, default=77)
    ap.add_argument("--out", default=str(HERE / "uncertainty_cost.json"))
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "uncertainty_cost")
    movements = list(range(1, args.movements + 1))
    load0 = list(os.getloadavg())
    cmd = f"python benchmarks/uncertainty_cost.py --movements {args.movements}"
    out: dict = {"command": cmd + (f" --repeat {args.repeat}" if args.repeat > 1 else ""),
                 "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "loadavg_start": load0,
                 "movements": len(movements), "repeat": args.repeat, "variants": {},
                 "runs": {v.name: [] for v in VARIANTS}}
    out["in_process"] = in_process()
    for k, x in out["in_process"].items():
        print(f"in process, no DDS: {k:16s} p50 {x['p50']:6.1f} p99 {x['p99']:6.1f} mean {x['mean']:6.1f} "
              f"us CPU ({x['n']} samples)", flush=True)
    c = out["continuous"] = continuous(args.movements)
    print(f"in process, the benchmark's stream ({c['samples']} samples, {c['regroups']} regroups, "
          f"{c['derivations']} derivations): σ p50 {c['p50']:.1f} mean {c['mean']:.1f} p99 "
          f"{c['p99']:.1f} p99.9 {c['p99_9']:.1f} max {c['max']:.0f} us wall; "
          f"{c['over_100us_ms']:.0f} ms in samples over 100 us", flush=True)
    with tempfile.TemporaryDirectory(prefix="std_cost_") as tmp:
        for r in range(args.repeat):
            for v in VARIANTS:
                print(f"{v.name} ({r + 1}/{args.repeat}): {len(movements)} movements at 1 kHz ...",
                      flush=True)
                before = os.getloadavg()[0]
                res = run_variant(v, movements, lease.domain, Path(tmp) / str(r), start_delay=2.0)
                res["loadavg_before"] = before
                out["runs"][v.name].append(res)
    lease.release()
    out["loadavg_end"] = list(os.getloadavg())
    for name, runs in out["runs"].items():  # the run whose callback p50 is the median one
        ranked = sorted(runs, key=lambda x: (x.get("callback_us") or {}).get("p50", math.inf))
        out["variants"][name] = {**ranked[(len(ranked) - 1) // 2], "medians": _medians(runs)}
    var = out["variants"]

    def fig(name, *keys):
        med = var[name]["medians"].get(".".join(keys))
        if med is not None:
            return med
        r = var[name]
        for k in keys:
            r = (r or {}).get(k)
        return r

    cb_std = fig("torque_node_std", "callback_us", "p50")
    cb_no = fig("torque_node_no_std", "callback_us", "p50")
    lat_std = fig("torque_node_std", "latency_ms", "p50")
    lat_null = fig("null_echo_node", "latency_ms", "p50")
    lost = {n: sum(r["lost"] for r in out["runs"][n]) for n in var}
    std_missing = sum((r.get("also") or {}).get("missing_vs_torques", 0)
                      for r in out["runs"]["torque_node_std"])
    out["targets"] = {
        "callback_p50_delta_us": {"value": cb_std - cb_no, "target": 30.0, "met": cb_std - cb_no <= 30.0},
        "latency_p50_ratio_to_null": {"value": lat_std / lat_null, "target": 1.2,
                                      "met": lat_std / lat_null <= 1.2},
        "lost": {"value": {**lost, "joint_torques_std_missing": std_missing}, "target": 0,
                 "met": all(x == 0 for x in lost.values()) and std_missing == 0},
    }
    for n in var:
        print(f"{n:20s} callback p50 {fig(n, 'callback_us', 'p50'):7.1f} "
              f"p99 {fig(n, 'callback_us', 'p99'):7.1f} us "
              f"(publish p50 {fig(n, 'callback_us', 'publish_p50'):.1f})"
              f"  latency p50 {fig(n, 'latency_ms', 'p50'):.3f} p99 {fig(n, 'latency_ms', 'p99'):.3f} ms"
              f"  lost {lost[n]}  cpu {fig(n, 'node_process', 'cpu_percent'):.1f} %"
              f"  (per run: callback p50 {[round(r['callback_us']['p50']) for r in out['runs'][n]]}, "
              f"latency p50 {[round(r['latency_ms']['p50'], 3) for r in out['runs'][n]]}, "
              f"load {[round(r['loadavg_before'], 1) for r in out['runs'][n]]})")
    for k, t in out["targets"].items():
        print(f"{k}: {t['value']} (target {t['target']}) {'met' if t['met'] else 'MISSED'}")
    print(f"load average {load0} -> {out['loadavg_end']}")
    write_json(Path(args.out), out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
