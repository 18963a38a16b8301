"""What joint_torques_std costs (issue 19): torque_node with and without publish_std against
the null echo node, in the same run.

    .venv/bin/python benchmarks/uncertainty_cost.py [--movements 20] [--domain 77]

Three variants of benchmarks/torque_path.py's replay (trajectory_publisher at 1 kHz ->
node -> receiver, real processes on loopback DDS), one after the other: null_echo_node,
torque_node with publish_std false, torque_node with publish_std true (the receiver
subscribes joint_torques_std too, so the σ messages are really delivered and counted).
Reported: callback p50/p99 (the node's /diagnostics: entry to the σ message published),
torque-path latency p50/p99, loss, and the targets: callback p50 with σ <= +30 µs over
without, latency p50 with σ <= 1.2x the null echo, 0 lost (torques and σ). The load
average at start and end is in the output: 2 cores shared with other work.
Writes benchmarks/uncertainty_cost.json.
"""

from __future__ import annotations

import argparse
import os
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--movements", type=int, default=20, help="library movements 1..N (65: all)")
    ap.add_argument("--domain", type=int, default=77)
    ap.add_argument("--out", default=str(HERE / "uncertainty_cost.json"))
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "uncertainty_cost")
    movements = list(range(1, args.movements + 1))
    load0 = list(os.getloadavg())
    out: dict = {"command": f"python benchmarks/uncertainty_cost.py --movements {args.movements}",
                 "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "loadavg_start": load0,
                 "movements": len(movements), "variants": {}}
    with tempfile.TemporaryDirectory(prefix="std_cost_") as tmp:
        for v in VARIANTS:
            print(f"{v.name}: {len(movements)} movements at 1 kHz ...", flush=True)
            out["variants"][v.name] = run_variant(v, movements, lease.domain, Path(tmp), start_delay=2.0)
    lease.release()
    out["loadavg_end"] = list(os.getloadavg())
    var = out["variants"]

    def fig(name, *keys):
        r = var[name]
        for k in keys:
            r = (r or {}).get(k)
        return r

    cb_std = fig("torque_node_std", "callback_us", "p50")
    cb_no = fig("torque_node_no_std", "callback_us", "p50")
    lat_std = fig("torque_node_std", "latency_ms", "p50")
    lat_null = fig("null_echo_node", "latency_ms", "p50")
    lost = {n: fig(n, "lost") for n in var}
    std_missing = fig("torque_node_std", "also", "missing_vs_torques")
    out["targets"] = {
        "callback_p50_delta_us": {"value": cb_std - cb_no, "target": 30.0, "met": cb_std - cb_no <= 30.0},
        "latency_p50_ratio_to_null": {"value": lat_std / lat_null, "target": 1.2,
                                      "met": lat_std / lat_null <= 1.2},
        "lost": {"value": {**lost, "joint_torques_std_missing": std_missing}, "target": 0,
                 "met": all(x == 0 for x in lost.values()) and std_missing == 0},
    }
    for n in var:
        print(f"{n:20s} callback p50 {fig(n, 'callback_us', 'p50'):7.1f} "
              f"p99 {fig(n, 'callback_us', 'p99'):7.1f} us"
              f"  latency p50 {fig(n, 'latency_ms', 'p50'):.3f} p99 {fig(n, 'latency_ms', 'p99'):.3f} ms"
              f"  lost {fig(n, 'lost')}  cpu {fig(n, 'node_process', 'cpu_percent')}")
    for k, t in out["targets"].items():
        print(f"{k}: {t['value']} (target {t['target']}) {'met' if t['met'] else 'MISSED'}")
    print(f"load average {load0} -> {out['loadavg_end']}")
    write_json(Path(args.out), out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
