"""The whole pipeline (`make demo`) beside a process that writes and fsyncs gigabytes.

    python -m benchmarks.pipeline_disk_load [--movements IDS] [--block-mib 1] [--gib 3]
                                            [--depths 1000,5000]
                                            [--out benchmarks/pipeline_disk_load.json]

Why: `make demo` beside a `dd bs=1M count=3000 conv=fsync` loop once failed, losing 121
joint_states (stop 49; 2 370-4 371 in 3 of 3 runs with a /proc sampler at 3 ms beside it
too, stop 50), while the recorder alone beside the same writer loses nothing
(recorder_disk_stall). Sampling every thread of the three nodes (/proc: state, kernel stack,
run-queue wait) showed no node held in the kernel while streaming; every thread of every node
waited for a CPU, 30-130 ms at a time, and the torque node's callbacks took ~200 us instead of
~100 (the kernel is not preemptible here, `Dynamic Preempt: none`, and the writer takes about
one of the two cores). The node fell up to 1.4 s behind its input, past its queue (qos_depth
1000 = 1 s at 1 kHz), and DDS dropped the oldest samples, which the node cannot count.

So this runs `demo` once quiet (the default queue) and, beside a `dd` loop (DD_LOOP), once
per --depths value (torque_node `qos_depth`), and reports per run check_bag's exit code
and loss, how far behind the answers after the lost ones came (check_bag's
behind_after_loss_ms), the latency, the torque node's "behind" warnings and the load average.
docs/reliability.md's row is `reliability_row` of the committed JSON
(test/test_pipeline_disk_load.py). Real processes, loopback DDS, a domain of its own.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from forearm_dynamics.processes import BIN

from .recorder_disk_stall import writer_rate
from .stats import claim_domain_arg, loadavg, machine_info

HERE = Path(__file__).resolve().parent
#: `dd` itself, as in the failing runs (recorder_disk_stall's Python writer, 1 MiB blocks of
#: one buffer, did not reproduce them: 0 lost, latency max 222 ms; dd copies from /dev/zero)
DD_LOOP = r"""
import subprocess, sys, time
path, block_mib, gib = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
count = round(gib * 1024 / block_mib)
written, t0 = 0, time.monotonic()
while True:
    subprocess.run(["dd", "if=/dev/zero", f"of={path}", f"bs={block_mib}M", f"count={count}",
                    "conv=fsync", "status=none"], check=True)
    written += count * (block_mib << 20)
    print(f"WRITER {written} {time.monotonic() - t0:.3f}", flush=True)
"""
BEHIND = "s behind the input's stamps"  # torque_node's warning (nodes/stream_node.py)


def run_demo(domain: int, work: Path, movements: str, depth: int | None,
             writer: list[str] | None) -> dict:
    """One `demo` run (beside the writer if given); check_bag's delivery and verdict."""
    load0 = loadavg()
    proc = None
    if writer is not None:
        proc = subprocess.Popen([sys.executable, "-c", DD_LOOP, *writer], stdout=subprocess.PIPE,
                                text=True, start_new_session=True)
        time.sleep(3.0)  # the page cache fills and the first throttling starts
    argv = [str(BIN / "demo"), "--out", str(work), "--domain", str(domain)]
    if movements:
        argv += ["--movements", movements]
    if depth is not None:
        argv += ["--param", f"qos_depth:={depth}"]
    try:
        demo = subprocess.run(argv, capture_output=True, text=True, check=False, timeout=1800)
    finally:
        out = ""
        if proc is not None:
            os.killpg(proc.pid, signal.SIGTERM)  # the loop and its dd (its own session)
            out = proc.communicate(timeout=60)[0]
            Path(writer[0]).unlink(missing_ok=True)
    res = {"qos_depth": depth, "exit_code": demo.returncode, "loadavg_start": load0,
           "loadavg_end": loadavg(), "writer_mb_per_s": writer_rate(out) if proc else None}
    runs = sorted(work.glob("*/check.json"))
    if not runs:
        res["error"] = (demo.stdout + demo.stderr)[-2000:]
        return res
    report = json.loads(runs[-1].read_text(encoding="utf-8"))
    d = report["delivery"]
    res.update({k: d[k] for k in ("joint_states", "considered", "lost", "lost_runs",
                                  "behind_after_loss_ms", "latency_ms")})
    res["failures"] = report["failures"]
    log = runs[-1].parent / "logs" / "torque_node.log"
    text = log.read_text(encoding="utf-8", errors="replace") if log.exists() else ""
    res["node_behind_warnings"] = sum(BEHIND in line for line in text.splitlines())
    return res


def reliability_row(res: dict) -> str:
    """The row docs/reliability.md shows (test_pipeline_disk_load.py checks it)."""
    def n(x: int) -> str:
        return f"{x:,}".replace(",", " ")

    loaded = [r for r in res["runs"] if r["writer_mb_per_s"] is not None]
    default, deep = loaded[0], loaded[-1]
    mb = min(r["writer_mb_per_s"] for r in loaded)
    late = default["latency_ms"]["max"] / 1e3
    named = any("the node fell behind its input" in f for f in default["failures"])
    k = default["node_behind_warnings"]
    warned = f"{k} warning{'s' if k != 1 else ''}"
    if default["lost"]:
        what = (f"answers came up to {late:.1f} s late: the torque node fell past its queue "
                f"(`qos_depth` {default['qos_depth']}) and DDS dropped the oldest; the node warned "
                f"({warned}), check_bag failed" + (" naming the overflow" if named else ""))
    else:
        what = (f"answers came up to {late:.1f} s late; the torque node warned past half its "
                f"queue ({warned})")
    return (f"| the whole pipeline (`demo`) beside a disk writer ({res['gib']:g} GiB written and "
            f"fsynced in a loop, ≥ {mb:.0f} MB/s) | {what} "
            f"(`python -m benchmarks.pipeline_disk_load`, load {default['loadavg_end'][0]:.1f}) | "
            f"{n(default['considered'] - default['lost'])} of {n(default['considered'])}; with "
            f"`qos_depth` {deep['qos_depth']}: {n(deep['considered'] - deep['lost'])} of "
            f"{n(deep['considered'])} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--movements", default="", help="comma-separated ids (default: all 65)")
    ap.add_argument("--block-mib", type=int, default=1)
    ap.add_argument("--gib", type=float, default=3.0, help="fsync after this much")
    ap.add_argument("--depths", default="1000,5000", help="torque_node qos_depth values beside "
                    "the writer")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID") or 84))
    ap.add_argument("--out", type=Path, default=HERE / "pipeline_disk_load.json")
    args = ap.parse_args(argv)
    depths = [int(x) for x in args.depths.split(",") if x.strip()]
    lease = claim_domain_arg(ap, args.domain, "pipeline_disk_load")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    res = {"command": "python -m benchmarks.pipeline_disk_load" + "".join(
               f" --{k.replace('_', '-')} {getattr(args, k)}"
               for k in ("movements", "block_mib", "gib", "depths") if getattr(args, k) != ""),
           "machine": machine_info(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
           "gib": args.gib, "block_mib": args.block_mib, "runs": []}
    with tempfile.TemporaryDirectory(prefix="pipeline_disk_") as d:
        work = Path(d)
        res["runs"].append(run_demo(lease.domain, work / "quiet", args.movements, None, None))
        for depth in depths:
            writer = [str(work / "writer.bin"), str(args.block_mib), str(args.gib)]
            res["runs"].append(run_demo(lease.domain, work / f"disk_{depth}", args.movements,
                                        depth, writer))
    args.out.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    for r in res["runs"]:
        print(f"qos_depth {r['qos_depth'] or 'default':>7} writer {r['writer_mb_per_s'] or 0:4.0f} MB/s "
              f"lost {r.get('lost')} of {r.get('considered')} in {r.get('lost_runs')} runs, behind "
              f"after loss {r.get('behind_after_loss_ms')} ms, latency max "
              f"{(r.get('latency_ms') or {}).get('max', float('nan')):.0f} ms, node warnings "
              f"{r.get('node_behind_warnings')}, load {r['loadavg_end'][0]:.1f}, exit {r['exit_code']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
