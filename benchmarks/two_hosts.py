"""Two hosts and a lossy link: torque_node in host A, trajectory_publisher + bag_recorder in B.

    sudo .venv/bin/python -m benchmarks.two_hosts [--movements 10] [--cases a,b] \
        [--out benchmarks/two_hosts.json] [--profile XML] [--stall-ms MS] [--repeat N]

One run per case (benchmarks/two_host_run.py: the hosts, the counters, B's bag): Fast DDS's
default timing vs config/fastdds_lossy_link.xml, reliable vs best-effort input, at 0, 1 and
5 % of A's incoming UDP dropped at random (and 1 % both ways). Per case: samples lost,
latency p50/p99/max (B's receive time of joint_torques - the stamp of the joint_states it
answers; one machine, one clock), packets the rule dropped, the kernel's receive-buffer
drops (RcvbufErrors) and A's incoming datagrams (heartbeats, acknowledgements and repairs
on top of the samples: the retransmission effect), check_bag's verdict, the load average.
The baseline is the same run's 0 % case. Timing is reported, never a pass/fail: that is
test/test_two_hosts_loss.py's job, for correctness. Needs root. ~30 s per case and movement
count 4; ~45 s with 10.

`--stall-ms`: SIGSTOP the node that long every second (a receiver descheduled as on a
loaded machine, reproducibly); `--node-cpu`: a cgroup CPU quota for the node; `--profile`:
another profile file for the lossy-profile cases (the timing curve).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from forearm_dynamics.processes import claim_domain

from .stats import loadavg
from .two_host_run import LOSSY_PROFILE, Case, hostkit, run_case

HERE = Path(__file__).resolve().parent

CASES = (
    Case("default_0", 0),
    Case("default_1", 1),
    Case("lossy_profile_1", 1, profile=True),
    Case("default_5", 5),
    Case("lossy_profile_5", 5, profile=True),
    Case("default_1_both", 1, both=True),
    Case("lossy_profile_1_both", 1, both=True, profile=True),
    Case("best_effort_input_1", 1, best_effort=True),
    Case("best_effort_input_5", 5, best_effort=True),
    Case("best_effort_input_profile_1", 1, profile=True, best_effort=True),
    Case("best_effort_input_profile_5", 5, profile=True, best_effort=True),
)


def heartbeat_variant(profile: Path, ms: float, out: Path) -> Path:
    """`profile` with the writers' heartbeat period set to `ms` (the timing curve)."""
    text = profile.read_text()
    start = text.index("<heartbeatPeriod>")
    end = text.index("</heartbeatPeriod>", start) + len("</heartbeatPeriod>")
    sec, ns = divmod(round(ms * 1e6), 1_000_000_000)
    period = f"<heartbeatPeriod><sec>{sec}</sec><nanosec>{ns}</nanosec></heartbeatPeriod>"
    out.write_text(text[:start] + period + text[end:])
    return out


def line(r: dict) -> str:
    lat = r.get("latency_ms", {})
    a = r["udp"].get("a", {})
    return (f"{r['case']:28s} lost {r['lost']} of {r['sent']} (node input {r['node_received']}), "
            f"latency p50/p99/max {lat.get('p50', float('nan')):.2f}/{lat.get('p99', float('nan')):.1f}/"
            f"{lat.get('max', float('nan')):.1f} ms, dropped {r['packets_dropped']}, A in "
            f"{a.get('InDatagrams')} rcvbuf-drops {a.get('RcvbufErrors')} "
            f"(socket {r['node_socket_rcvbuf']}), "
            f"node CPU {r['node_cpu_s']} s, check_bag {r['check_bag_exit']}, "
            f"load {r['loadavg_start'][0]:.2f}-{r['loadavg_end'][0]:.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--movements", type=int, default=10)
    ap.add_argument("--cases", default=",".join(c.name for c in CASES))
    ap.add_argument("--repeat", type=int, default=1, help="runs of each case, interleaved")
    ap.add_argument("--out", type=Path, default=HERE / "two_hosts.json")
    ap.add_argument("--profile", type=Path, default=LOSSY_PROFILE,
                    help="the Fast DDS profile of the lossy-profile cases (default: the shipped one)")
    ap.add_argument("--heartbeat-ms", default="",
                    help="comma-separated: run the lossy-profile cases once per heartbeat period "
                    "(the profile with only that changed)")
    ap.add_argument("--stall-ms", type=float, default=0.0,
                    help="SIGSTOP torque_node this many ms every second while streaming")
    ap.add_argument("--node-cpu", type=float, default=None,
                    help="torque_node gets only this %% of one CPU (a cgroup's cfs quota)")
    ap.add_argument("--node-args", default="", help="extra torque_node -p name:=value, comma-separated "
                    "(e.g. realtime_priority:=50)")
    args = ap.parse_args()
    why = hostkit.can_make_hosts()
    if why:
        print(f"two_hosts: {why}", file=sys.stderr)
        return 2
    wanted = args.cases.split(",")
    unknown = set(wanted) - {c.name for c in CASES}
    if unknown:
        ap.error(f"unknown case(s) {sorted(unknown)}; known: {[c.name for c in CASES]}")
    hostkit.ensure_nft()
    lease = claim_domain(87, "two_hosts benchmark")
    work = Path(tempfile.mkdtemp(prefix="bench_two_hosts_"))
    node_args = tuple(x for a in filter(None, args.node_args.split(",")) for x in ("-p", a))
    profiles = {None: args.profile.resolve()}
    for ms in filter(None, args.heartbeat_ms.split(",")):
        profiles[float(ms)] = heartbeat_variant(args.profile, float(ms), work / f"hb{ms}ms.xml")
    if len(profiles) > 1:
        del profiles[None]
    t0 = time.time()
    runs = []
    for k in range(args.repeat):
        for case in (c for c in CASES if c.name in wanted):
            for hb, profile in (profiles.items() if case.profile else [(None, None)]):
                if hb is not None:
                    case = dataclasses.replace(case, name=f"{case.name.split('@')[0]}@hb{hb:g}ms")
                r = run_case(case, args.movements, lease.domain, work / str(k), node_args=node_args,
                             profile=profile or args.profile.resolve(), stall_ms=args.stall_ms,
                             node_cpu=args.node_cpu)
                r.update(repeat=k, heartbeat_ms=hb)
                check = r.pop("check") or {}
                r["check_delivery"] = check.get("delivery")
                print(line(r), file=sys.stderr, flush=True)
                runs.append(r)
    result = {"command": "python -m benchmarks.two_hosts " + " ".join(sys.argv[1:]),
              "when": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(t0)),
              "machine": {"cpus": os.cpu_count(), "loadavg_end": loadavg()},
              "movements": args.movements, "runs": runs}
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
