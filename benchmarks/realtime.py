"""The torque path under CPU load, normal vs real-time scheduling (issue: deadlines on a busy machine).

    python -m benchmarks.realtime [--movements 6] [--reps 2] [--hogs 0,1,2] [--out benchmarks/results.json]

For each number of CPU hogs (normal-priority `while True` processes, each ending itself after
--hog-limit s and stopped by PID after the run) and each repetition, the two modes run back
to back (alternating, one session): `normal` (torque_node as configured by default) and
`realtime` (`-p realtime_priority:=50 -p lock_memory:=true`). The publisher and the receiver
run at SCHED_FIFO 60 in both modes, so only the torque node's scheduling differs. Per run
(torque_path.run_variant): latency p50/p99/p99.9/max (receive time - stamp of the
joint_states answered), lost samples, deadline misses (the node's own /diagnostics,
deadline_ms 1) and its CPU. Then, under the most hogs, `output_rate_hz: 1000` from a 100 Hz
input: the publish-interval jitter at the receiver (interval - 1 ms) in both modes.

Writes the `realtime` section of --out (other sections kept). Runs ~40 s per run: ~8 min
for the defaults. The machine's load (loadavg) is recorded at start and end of each run.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from forearm_dynamics.processes import Child

from .stats import claim_domain_arg, loadavg, machine_info, merge_results, percentiles, write_json
from .torque_path import Variant, run_variant

RT_ARGS = ["-p", "realtime_priority:=50", "-p", "lock_memory:=true"]
OTHERS_FIFO = 60
HOG_CODE = ("import time\nend = time.monotonic() + {limit}\n"
            "while time.monotonic() < end:\n    pass\n")


def start_hogs(n: int, work: Path, limit: float) -> list[Child]:
    env = dict(os.environ)
    return [Child(f"hog{i}", [sys.executable, "-c", HOG_CODE.format(limit=limit)], env, work / "hogs")
            for i in range(n)]


def _diag_last(run_dir: Path) -> dict:
    import json

    try:
        diag = json.loads((run_dir / "rx.diag.json").read_text())
    except (OSError, ValueError):
        return {}
    return diag[-1]["values"] if diag else {}


def _summary_deadline(run_dir: Path) -> dict:
    """The node's shutdown summary (every output, unlike the last 1 s diagnostics)."""
    import re

    text = "".join(p.read_text(errors="replace") for p in run_dir.glob("torque_node*.log"))
    m = re.search(r"deadline ([\d.]+) ms: missed (\d+) of (\d+) \([\d.]+ %\)(?: \(([^)]*)\); "
                  r"worst ([\d.]+) ms)?", text)
    if not m:
        return {}
    out = {"deadline_checked_total": m.group(3), "deadline_missed_total": m.group(2),
           "deadline_worst_ms": m.group(5) or "0"}
    for part in filter(None, (m.group(4) or "").split(", ")):
        k, n = part.rsplit(" ", 1)
        out[f"deadline_missed.{k}"] = n
    return out


def one_run(mode: str, hogs: int, rep: int, movements: list[int], domain: int, work: Path,
            hog_limit: float, rate: bool = False) -> dict:
    name = f"{'rate_' if rate else ''}{mode}_h{hogs}_r{rep}"
    node_args = ["-p", "deadline_ms:=1.0"] + (RT_ARGS if mode == "realtime" else [])
    pub_args: list[str] = []
    if rate:
        node_args += ["-p", "output_rate_hz:=1000.0", "-p", "input_timeout:=0.2"]
        pub_args = ["-p", "rate_hz:=100.0"]
    v = Variant(name, node_args=node_args, others_fifo=OTHERS_FIFO, pub_args=pub_args)
    load0 = loadavg()
    children = start_hogs(hogs, work, hog_limit)
    try:
        r = run_variant(v, movements, domain, work, start_delay=2.0)
    finally:
        for c in children:
            c.stop()
    d = _diag_last(work / name)
    d.update(_summary_deadline(work / name))
    out = {
        "mode": mode, "hogs": hogs, "rep": rep, "loadavg_start": load0, "loadavg_end": loadavg(),
        "sent": r.get("sent"), "lost": r.get("lost"), "latency_ms": r.get("latency_ms"),
        "node_cpu_percent": (r.get("node_process") or {}).get("cpu_percent"),
        "node_peak_rss_mb": (r.get("node_process") or {}).get("peak_rss_mb"),
        "foreign_cpu_percent": r.get("foreign_cpu_percent"),
        "deadline": {k.removeprefix("deadline_"): d[k] for k in d if k.startswith("deadline")},
        "realtime_policy": d.get("realtime.policy"), "realtime_threads": d.get("realtime.threads"),
        "gc": {k: d[k] for k in d if k.startswith("gc.")},
    }
    if rate:
        out.update(_intervals(work / name / "rx.npz"))
    return out


def _intervals(path: Path) -> dict:
    data = np.load(path)
    recv, stamp = data["recv_ns"], data["stamp_ns"]
    if recv.size < 3:
        return {"intervals": {"n": 0}}
    return {"received": int(recv.size),
            "receive_interval_ms": percentiles(np.diff(recv) / 1e6),
            "stamp_interval_ms": percentiles(np.diff(stamp) / 1e6),
            "receive_jitter_ms": percentiles(np.abs(np.diff(recv) / 1e6 - 1.0))}


def arm_sim_run(mode: str, hogs: int, seconds: float, domain: int, work: Path,
                hog_limit: float) -> dict:
    """arm_sim in real-time mode (1 kHz steps, zero torque) timed at a FIFO-60 receiver."""
    from forearm_dynamics.processes import ros_env

    from . import module_env
    from .procstat import Sampler

    logs = work / f"arm_sim_{mode}_h{hogs}"
    env = ros_env(domain, logs)
    rx_path = logs / "rx.npz"
    hog_children = start_hogs(hogs, work, hog_limit)
    children: list[Child] = []
    load0 = loadavg()
    try:
        sim = Child.script("arm_sim", ["-p", "command_timeout:=0.05",
                                       *(RT_ARGS if mode == "realtime" else [])], env, logs)
        children.append(sim)
        rx = Child.module("receiver", "benchmarks.receiver",
                          ["--topic", "joint_states", "--out", str(rx_path), "--diag-prefix", "arm_sim"],
                          module_env(env), logs, fifo=OTHERS_FIFO)
        children.append(rx)
        if not rx.wait_for("receiver: matched", 60):
            raise RuntimeError(f"receiver never matched arm_sim:\n{sim.text()[-2000:]}")
        time.sleep(2.0)  # past start-up
        with Sampler({"arm_sim": sim.pid}) as sampler:
            t0 = time.time()
            time.sleep(seconds)
            t1 = time.time()
            sampler.sample()
        for c in reversed(children):
            c.stop()
    finally:
        for c in children + hog_children:
            c.stop()
    data = np.load(rx_path)
    recv = data["recv_ns"]
    recv = recv[(recv >= t0 * 1e9) & (recv <= t1 * 1e9)]
    d = _diag_last(logs)
    iv = np.diff(recv) / 1e6
    return {"mode": mode, "hogs": hogs, "seconds": seconds, "loadavg_start": load0,
            "received": int(recv.size), "rate_hz": float((recv.size - 1) / (t1 - t0)),
            "receive_interval_ms": percentiles(iv), "receive_jitter_ms": percentiles(np.abs(iv - 1.0)),
            "steps_skipped": d.get("steps_skipped"), "behind_ms": d.get("behind_ms"),
            "realtime_policy": d.get("realtime.policy"),
            "cpu_percent": sampler.series["arm_sim"].cpu_percent(t0, t1)}


def summarise(runs: list[dict]) -> dict:
    """Per (hogs, mode): the median over repetitions of each latency figure, summed counts."""
    out: dict = {}
    for r in runs:
        key = f"h{r['hogs']}_{r['mode']}"
        out.setdefault(key, []).append(r)
    summary = {}
    for key, rs in out.items():
        lat = [x["latency_ms"] or {} for x in rs]
        missed = sum(int(x["deadline"].get("missed_total", 0)) for x in rs)
        checked = sum(int(x["deadline"].get("checked_total", 0)) for x in rs)
        summary[key] = {
            "runs": len(rs),
            **{f"latency_{q}_ms": float(np.median([x.get(q, np.nan) for x in lat]))
               for q in ("p50", "p99", "p99_9", "max")},
            "latency_p99_ms_each": [x.get("p99") for x in lat],
            "lost": sum(x["lost"] or 0 for x in rs), "sent": sum(x["sent"] or 0 for x in rs),
            "deadline_missed": missed, "deadline_checked": checked,
            "deadline_missed_fraction": missed / checked if checked else None,
            "node_cpu_percent": float(np.median([x["node_cpu_percent"] or np.nan for x in rs])),
        }
    return summary


def goals(summary: dict, hogs_max: int) -> dict:
    rt, nm = summary.get(f"h{hogs_max}_realtime", {}), summary.get(f"h{hogs_max}_normal", {})
    r0, n0 = summary.get("h0_realtime", {}), summary.get("h0_normal", {})
    g = {}

    def goal(name, target, value, ok):
        g[name] = {"target": target, "value": value, "met": None if value is None else bool(ok(value))}

    goal(f"h{hogs_max}_realtime_p99_le_0.8ms", "<= 0.8 ms", rt.get("latency_p99_ms"), lambda x: x <= 0.8)
    ratio = (rt["latency_p99_ms"] / nm["latency_p99_ms"]) if rt and nm else None
    goal(f"h{hogs_max}_realtime_p99_ratio_le_0.6", "<= 0.6 x normal", ratio, lambda x: x <= 0.6)
    goal(f"h{hogs_max}_realtime_lost_0", "0", rt.get("lost"), lambda x: x == 0)
    goal(f"h{hogs_max}_realtime_misses_le_0.1pct", "<= 0.1 %", rt.get("deadline_missed_fraction"),
         lambda x: x <= 0.001)
    p50 = (r0["latency_p50_ms"] / n0["latency_p50_ms"]) if r0 and n0 else None
    goal("h0_p50_ratio_within_5pct", "0.95 .. 1.05", p50, lambda x: 0.95 <= x <= 1.05)
    return g


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--movements", type=int, default=6)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--hogs", default="0,1,2")
    ap.add_argument("--rate-movements", type=int, default=4, help="output_rate_hz 1000 runs; 0 = none")
    ap.add_argument("--only-arm-sim", action="store_true", help="only the arm_sim runs "
                    "(the section's other keys are kept from the file)")
    ap.add_argument("--arm-sim-seconds", type=float, default=10.0, help="arm_sim runs; 0 = none")
    ap.add_argument("--hog-limit", type=float, default=120.0, help="a hog ends itself after this (s)")
    env_domain = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    ap.add_argument("--domain", type=int, default=env_domain or 83)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results.json"))
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "realtime")
    domain = lease.domain
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    t_start = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="bench_realtime_"))
    movements = list(range(1, args.movements + 1))
    hog_counts = [int(h) for h in args.hogs.split(",")]
    runs, rate_runs = [], []
    for hogs in ([] if args.only_arm_sim else hog_counts):
        for rep in range(1, args.reps + 1):
            order = ("normal", "realtime") if rep % 2 else ("realtime", "normal")
            for mode in order:
                r = one_run(mode, hogs, rep, movements, domain, work, args.hog_limit)
                lat = r["latency_ms"] or {}
                print(f"[realtime] {hogs} hog(s) {mode:8s} rep {rep}: latency p50/p99/p99.9/max "
                      f"{lat.get('p50', np.nan):.3f}/{lat.get('p99', np.nan):.3f}/"
                      f"{lat.get('p99_9', np.nan):.3f}/{lat.get('max', np.nan):.2f} ms, lost {r['lost']}, "
                      f"missed {r['deadline'].get('missed_total')} of {r['deadline'].get('checked_total')}, "
                      f"CPU {r['node_cpu_percent'] or np.nan:.0f} %, load {r['loadavg_start']}",
                      file=sys.stderr, flush=True)
                runs.append(r)
    if args.rate_movements and not args.only_arm_sim:
        hogs = max(hog_counts)
        for mode in ("normal", "realtime"):
            r = one_run(mode, hogs, 1, list(range(1, args.rate_movements + 1)), domain, work,
                        args.hog_limit, rate=True)
            j = r.get("receive_jitter_ms", {})
            print(f"[realtime] output_rate_hz 1000, {hogs} hog(s), {mode}: jitter p50/p99/max "
                  f"{j.get('p50', np.nan):.3f}/{j.get('p99', np.nan):.3f}/{j.get('max', np.nan):.2f} ms, "
                  f"missed {r['deadline'].get('missed_total')} of {r['deadline'].get('checked_total')}",
                  file=sys.stderr, flush=True)
            rate_runs.append(r)
    sim_runs = []
    if args.arm_sim_seconds:
        hogs = max(hog_counts)
        for mode in ("normal", "realtime", "realtime", "normal"):
            r = arm_sim_run(mode, hogs, args.arm_sim_seconds, domain, work, args.hog_limit)
            j = r["receive_jitter_ms"]
            print(f"[realtime] arm_sim 1 kHz, {hogs} hog(s), {mode}: {r['rate_hz']:.1f} Hz, jitter "
                  f"p50/p99/max {j.get('p50', np.nan):.3f}/{j.get('p99', np.nan):.3f}/"
                  f"{j.get('max', np.nan):.2f} ms, steps skipped {r['steps_skipped']}, load "
                  f"{r['loadavg_start']}", file=sys.stderr, flush=True)
            sim_runs.append(r)
    provenance = {"command": "python -m benchmarks.realtime " + " ".join(argv or sys.argv[1:]),
                  "started": started}
    if args.only_arm_sim:  # the arm_sim key only; the rest of the section as it was
        import json

        try:
            old = json.loads(args.out.read_text()).get("realtime") or {}
        except (OSError, ValueError):
            old = {}
        old["arm_sim"] = sim_runs
        old["arm_sim_provenance"] = provenance
        write_json(args.out, merge_results(args.out, {"realtime": old}, provenance, sections=[]))
        return 0
    summary = summarise(runs)
    section = {"movements": len(movements), "reps": args.reps, "hogs": hog_counts,
               "others_fifo": OTHERS_FIFO, "realtime_args": RT_ARGS,
               "machine": {**machine_info(), "loadavg_end": loadavg()},
               "wall_time_s": time.monotonic() - t_start,
               "summary": summary, "goals": goals(summary, max(hog_counts)),
               "runs": runs, "output_rate_1000": rate_runs, "arm_sim": sim_runs}
    merged = merge_results(args.out, {"realtime": section}, provenance)
    write_json(args.out, merged)
    for k, s in summary.items():
        print(f"{k:14s} p50/p99/p99.9/max {s['latency_p50_ms']:.3f}/{s['latency_p99_ms']:.3f}/"
              f"{s['latency_p99_9_ms']:.3f}/{s['latency_max_ms']:.2f} ms  lost {s['lost']}  missed "
              f"{s['deadline_missed']}/{s['deadline_checked']}  CPU {s['node_cpu_percent']:.0f} %")
    for k, g in section["goals"].items():
        print(f"goal {k}: {g['value']} ({g['target']}) met={g['met']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
