"""Two hosts and a lossy link: torque_node in host A, trajectory_publisher + bag_recorder in B.

    sudo .venv/bin/python -m benchmarks.two_hosts [--movements 10] [--out benchmarks/two_hosts.json]

Hosts are network namespaces joined by a veth pair (test/hostkit.py: 192.0.2.0/30, nothing
else reachable, torn down after each case); every process uses UDPv4 only (shared memory
would bypass the veth) and ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET. Loss: nftables in A drops
N % of A's incoming UDP packets at random (`numgen random mod 100 < N drop`), or of both
directions. Per case, from B's bag: joint_torques lost of the samples sent (unique stamps),
latency = B's receive (log) time - the stamp B's publisher put on the joint_states answered
(one clock: one machine), p50/p99/max; packets dropped by the rules; check_bag's exit code.
Cases: default Fast DDS timing vs config/fastdds_lossy_link.xml at 0, 1 and 5 % input loss,
and 1 % both ways. Needs root. ~1 min per case.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from forearm_dynamics.paths import config_file
from forearm_dynamics.processes import BIN, claim_domain, ros_env

from .stats import loadavg, percentiles

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "test"))
import hostkit  # noqa: E402 - the test support's harness

CASES = [  # (name, loss %, directions, lossy profile, best-effort input)
    ("default_0", 0, "input", False, False),
    ("default_1", 1, "input", False, False),
    ("lossy_profile_1", 1, "input", True, False),
    ("default_5", 5, "input", False, False),
    ("lossy_profile_5", 5, "input", True, False),
    ("default_1_both", 1, "both", False, False),
    ("lossy_profile_1_both", 1, "both", True, False),
    ("best_effort_input_1", 1, "input", False, True),
    ("best_effort_input_5", 5, "input", False, True),
]
#: check_bag thresholds for a best-effort run: loss is expected (counted), a wrong torque not
BEST_EFFORT_THRESHOLDS = "loss_max: 100000\n"


def _env(domain: int, logs: Path, profile: bool) -> dict[str, str]:
    env = ros_env(domain, logs)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    if profile:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(config_file("fastdds_lossy_link.xml"))
    return env


def _bag_figures(bag: Path) -> dict:
    from forearm_dynamics.bag import open_bag

    stamps, logs, inputs = [], [], []
    unpack = struct.Struct("<iI").unpack_from
    for ch, msg in open_bag(bag).messages(["/joint_torques", "/joint_states"]):
        sec, nsec = unpack(msg.data, 4)
        t = sec * 1_000_000_000 + nsec
        if ch.topic == "/joint_states":  # B's own publisher, recorded in B: every sample sent
            inputs.append(t)
            continue
        stamps.append(t)
        logs.append(msg.log_time)
    s, lg = np.array(stamps, np.int64), np.array(logs, np.int64)
    sent = np.unique(np.array(inputs, np.int64))
    missing = np.setdiff1d(sent, s)
    first = s.min() if s.size else np.iinfo(np.int64).max
    return {"torques": int(s.size), "unique": int(np.unique(s).size),
            "inputs_recorded": int(sent.size), "missing": int(missing.size),
            "missing_before_first_answer": int((missing < first).sum()),
            "latency_ms": percentiles((lg - s) / 1e6) if s.size else {"n": 0}}


def run_case(name: str, loss: int, directions: str, profile: bool, best_effort: bool,
             movements: int, domain: int, work: Path, extra_node_args: list[str] | None = None) -> dict:
    logs = work / name
    logs.mkdir(parents=True)
    bag = logs / "b.mcap"
    env = _env(domain, logs, profile)
    load0 = loadavg()
    with hostkit.TwoHosts() as h:
        h.a.loss(loss, ("input", "output") if directions == "both" else ("input",))
        node_args = (["-p", "qos_reliability_input:=best_effort"] if best_effort else []) \
            + list(extra_node_args or [])
        node_args = ["--ros-args", *node_args] if node_args else []
        node = h.a.start([str(BIN / "torque_node"), *node_args], env, logs / "a_node.log")
        rec = h.b.start([str(BIN / "bag_recorder"), "--ros-args", "-p", f"output:={bag}"], env,
                        logs / "b_rec.log")
        pub = h.b.start([str(BIN / "trajectory_publisher"), "--ros-args", "-p",
                         f"movements:={list(range(1, movements + 1))}", "-p", "start_delay:=8.0",
                         "-p", "min_subscribers:=2", "-p", "subscriber_timeout:=30.0",
                         "-p", "drain:=5.0", *(["-p", "qos_reliable:=false"] if best_effort else [])],
                        env, logs / "b_pub.log")
        code = pub.wait(timeout=600)
        time.sleep(1.0)
        dropped = h.a.dropped()
        for p in (rec, node):
            p.send_signal(2)
            p.wait(timeout=30)
    pub_text = (logs / "b_pub.log").read_text()
    sent = None
    for line in pub_text.splitlines():
        if "done: " in line and " samples" in line:
            sent = int(line.split("done: ")[1].split()[0])
    th = []
    if best_effort:
        (logs / "thresholds.yaml").write_text(BEST_EFFORT_THRESHOLDS)
        th = ["--thresholds", str(logs / "thresholds.yaml")]
    check = subprocess.run([str(BIN / "check_bag"), str(bag), *th], check=False, capture_output=True,
                           text=True, timeout=600)
    fig = _bag_figures(bag) if bag.exists() else {"torques": 0}
    node_log = (logs / "a_node.log").read_text(errors="replace")
    received = None
    for line in node_log.splitlines():
        if "summary: received " in line:
            received = int(line.split("summary: received ")[1].split(",")[0])
    return {"case": name, "loss_percent": loss, "directions": directions, "lossy_profile": profile,
            "best_effort_input": best_effort, "node_received": received,
            "input_loss_percent": (100 * (1 - received / sent)) if received is not None and sent else None,
            "loadavg_start": load0, "publisher_exit": code, "sent": sent,
            "lost": (sent - fig.get("unique", 0)) if sent is not None else None,
            "packets_dropped": dropped, **fig, "check_bag_exit": check.returncode,
            "check_bag_tail": (check.stdout + check.stderr)[-400:]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--movements", type=int, default=10)
    ap.add_argument("--cases", default=",".join(c[0] for c in CASES))
    ap.add_argument("--out", type=Path, default=HERE / "two_hosts.json")
    ap.add_argument("--node-args", default="", help="extra torque_node -p name:=value, comma-separated "
                    "(e.g. realtime_priority:=50)")
    args = ap.parse_args()
    why = hostkit.can_make_hosts()
    if why:
        print(f"two_hosts: {why}", file=sys.stderr)
        return 2
    hostkit.ensure_nft()
    lease = claim_domain(87, "two_hosts benchmark")
    work = Path(tempfile.mkdtemp(prefix="bench_two_hosts_"))
    wanted = set(args.cases.split(","))
    t0 = time.time()
    runs = []
    for name, loss, directions, profile, best_effort in CASES:
        if name not in wanted:
            continue
        extra = [x for a in filter(None, args.node_args.split(",")) for x in ("-p", a)]
        r = run_case(name, loss, directions, profile, best_effort, args.movements, lease.domain, work,
                     extra)
        r["node_args"] = extra
        lat = r.get("latency_ms", {})
        print(f"{name:22s} lost {r['lost']} of {r['sent']} ({r.get('missing_before_first_answer')} "
              f"before the first answer), latency p50/p99/max "
              f"{lat.get('p50', float('nan')):.2f}/{lat.get('p99', float('nan')):.1f}/"
              f"{lat.get('max', float('nan')):.1f} ms, dropped {r['packets_dropped']} packets, "
              f"node input loss {r['input_loss_percent']}, check_bag {r['check_bag_exit']}, "
              f"load {r['loadavg_start']}", file=sys.stderr, flush=True)
        runs.append(r)
    result = {"command": "python -m benchmarks.two_hosts " + " ".join(sys.argv[1:]),
              "when": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(t0)),
              "machine": {"cpus": os.cpu_count(), "loadavg_end": loadavg()},
              "movements": args.movements, "runs": runs}
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
