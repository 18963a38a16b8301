"""Benchmark: arm_viz beside the 1 kHz torque path, and bag_viz's speed.

    .venv/bin/python benchmarks/viz.py [--repeats 3] [--movements 4] [--samples 30000]
                                       [--out benchmarks/viz.json]

1. arm_viz at 30 Hz: the torque path of benchmarks/torque_path.py (trajectory_publisher ->
   torque_node -> receiver, 1 kHz movement replay) run alternately without and with arm_viz
   subscribed to joint_torques and the config, `repeats` times each (ABAB..., so a change
   of the machine's load hits both alike). Reported: torque path latency p50/p99 per run
   and the median ratio with/without (target: p50 within 5 %), arm_viz CPU (% of one core,
   /proc utime+stime over the replay), markers published.
2. bag_viz on a 1 kHz bag (joint_states + joint_torques from bag_torques, `samples` s/1000
   of recording): wall and CPU seconds, x real time (target >= 50); baseline in the same
   run: copying the same bag message by message with our reader and writer, no markers.
Every figure is stated with the load average at the time (2 shared cores here).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parent / "test"))

from benchmarks.stats import claim_domain_arg, loadavg, write_json  # noqa: E402
from benchmarks.torque_path import Variant, run_variant  # noqa: E402


def torque_path(repeats: int, movements: list[int], work: Path, domain: int) -> dict:
    runs = []
    for rep in range(repeats):
        for viewer in (False, True):
            v = Variant(f"{'with' if viewer else 'without'}_arm_viz_{rep}", viewer=viewer)
            load = loadavg()
            r = run_variant(v, movements, domain, work)
            runs.append({"arm_viz": viewer, "rep": rep, "load_before": load,
                         "load_after": loadavg(), "latency_ms": r.get("latency_ms"),
                         "lost": r.get("lost"), "rate_hz": r.get("rate_hz"),
                         "arm_viz_cpu_percent": (r.get("arm_viz_process") or {}).get("cpu_percent"),
                         "torque_node_cpu_percent": r["node_process"]["cpu_percent"]})
            print(json.dumps(runs[-1]), file=sys.stderr)
    p50 = {b: [r["latency_ms"]["p50"] for r in runs if r["arm_viz"] == b] for b in (False, True)}
    ratios = [w / wo for wo, w in zip(p50[False], p50[True])]
    cpu = [r["arm_viz_cpu_percent"] for r in runs if r["arm_viz"]]
    return {"runs": runs, "latency_p50_ms_without": statistics.median(p50[False]),
            "latency_p50_ms_with": statistics.median(p50[True]),
            "latency_p50_ratio_median": statistics.median(ratios), "ratios": ratios,
            "arm_viz_cpu_percent_median": statistics.median(cpu),
            "target_p50_within_5_percent": abs(statistics.median(ratios) - 1.0) <= 0.05}


def bag_viz_speed(samples: int, work: Path) -> dict:
    from bagkit import write_stream_bag

    from forearm_dynamics.bag import BagWriter, open_bag
    from forearm_dynamics.cli.bag_viz import main as bag_viz
    from forearm_dynamics.dynamics import build_model
    from forearm_dynamics.offline.torques import bag_torques

    states, src = work / "states.mcap", work / "torques.mcap"
    write_stream_bag(states, samples)
    bag_torques(states, src, build_model("segmented", 50))
    info = open_bag(src).info
    bag_s = (info.end_ns - info.start_ns) / 1e9
    out = {"bag_seconds": bag_s, "messages": info.message_count}
    # baseline: the plain copy, message by message
    load, t, c = loadavg(), time.perf_counter(), time.process_time()
    bag = open_bag(src)
    with BagWriter(work / "copy.mcap") as w:
        ids = {ch.id: w.add_channel(ch.topic, w.add_schema(ch.schema_name, ch.schema_encoding,
                                                          ch.schema_data), ch.schema_name,
                                    ch.metadata, ch.message_encoding)
               for ch in bag.info.channels.values()}
        for ch, msg in bag.messages():
            w.write(ids[ch.id], msg.data, msg.log_time, msg.publish_time)
    out["copy"] = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
                   "load_before": load}
    load, t, c = loadavg(), time.perf_counter(), time.process_time()
    code = bag_viz([str(src), str(work / "viz.mcap")])
    out["bag_viz"] = {"wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c,
                      "load_before": load, "exit_code": code}
    for k in ("copy", "bag_viz"):
        out[k]["x_real_time_wall"] = bag_s / out[k]["wall_s"]
        out[k]["x_real_time_cpu"] = bag_s / out[k]["cpu_s"]
    out["bag_viz_over_copy_wall"] = out["bag_viz"]["wall_s"] / out["copy"]["wall_s"]
    out["target_50x_real_time_met"] = out["bag_viz"]["x_real_time_wall"] >= 50.0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--movements", type=int, default=4, help="movements per replay (1.5 s each)")
    ap.add_argument("--samples", type=int, default=30000, help="bag_viz bag length at 1 kHz")
    ap.add_argument("--skip-path", action="store_true", help="bag_viz only")
    ap.add_argument("--out", type=Path, default=HERE / "viz.json")
    ap.add_argument("--domain", type=int, default=81, help="ROS_DOMAIN_ID of the run (81)")
    args = ap.parse_args()
    lease = claim_domain_arg(ap, args.domain, "viz")  # held until this process exits
    work = Path(tempfile.mkdtemp(prefix="bench_viz_"))
    out = {"command": " ".join(["python", "benchmarks/viz.py", *sys.argv[1:]]),
           "when": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
           "machine": {"cpus": os.cpu_count(), "loadavg_start": loadavg()}}
    out["bag_viz"] = bag_viz_speed(args.samples, work)
    print(json.dumps(out["bag_viz"], indent=1), file=sys.stderr)
    if args.skip_path and args.out.exists():  # keep the torque path section of an earlier run
        old = json.loads(args.out.read_text())
        if "arm_viz" in old:
            out["arm_viz"] = {**old["arm_viz"], "from_run": {"command": old.get("command"),
                                                             "when": old.get("when")}}
    if not args.skip_path:
        out["arm_viz"] = torque_path(args.repeats, list(range(1, 1 + args.movements)), work,
                                     lease.domain)
    out["machine"]["loadavg_end"] = loadavg()
    write_json(args.out, out)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
