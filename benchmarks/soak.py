"""Soak benchmark: the pipeline replaying the 65 movements in a loop at 1 kHz for minutes.

    python -m benchmarks.soak [--minutes 10] [--out benchmarks/soak.json]
    make soak [SOAK_MINUTES=10]

Processes: torque_node, bag_recorder (into a temporary bag, deleted unless --keep-bag),
trajectory_publisher (loop:=true, all 65 movements) and, in this process, a monitor that
subscribes raw to joint_states and joint_torques (header stamps read from the CDR bytes),
to the movement markers and to /diagnostics; a sampler thread reads VmRSS and CPU time of
every process from /proc once a second. DDS stays on loopback in its own ROS_DOMAIN_ID.

Measured per minute of the run (from the first sample):
- loss: joint_states without a joint_torques of the same stamp (the last 0.5 s of the run
  excepted: answers in flight), and samples missing from the publisher's own count (each
  marker announces its movement's samples; complete movements are checked);
- latency: joint_torques receive time here - joint_states stamp (publisher -> torque_node
  -> this process; what check_bag measures at the recorder), p50 / p99 / max;
- RSS and CPU of each process, and the machine's highest 1-min load average (2 cores:
  above ~1.5 someone else is using the machine too).
At the end: the recorder's bag must hold as many joint_states and joint_torques as the
monitor received, torque_node must have refused nothing.

Verdicts (exit 1 if one fails): no loss anywhere; RSS growth (median of the last full
minute - median of the first) < --rss-growth-mb (5) for torque_node, bag_recorder and
trajectory_publisher; latency p99 of the last full minute within --p99-tolerance (25 %,
at least --p99-floor-ms 0.1 ms) of the first. Writes --out (JSON) and prints a table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.procstat import Sampler
from forearm_dynamics.exit_codes import DATA, OK
from forearm_dynamics.processes import Child, ros_env

from .stats import claim_domain_arg, loadavg, machine_info, percentiles

PROCESSES = ("torque_node", "bag_recorder", "trajectory_publisher")
TAIL_GRACE_NS = 500_000_000


def _started(child: Child, needle: str, timeout: float) -> None:
    if not child.wait_for(needle, timeout):
        raise RuntimeError(f"{child.name} did not report {needle!r}:\n{child.text()[-2000:]}")


class Monitor:
    """Raw joint_states / joint_torques: stamps and receive times in preallocated arrays."""

    def __init__(self, node, capacity: int):
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        from forearm_dynamics.nodes.common import stream_qos
        from forearm_dynamics.nodes.trajectory_publisher import marker_qos

        self.stamp = {t: np.zeros(capacity, np.int64) for t in ("states", "torques")}
        self.recv = {t: np.zeros(capacity, np.int64) for t in ("states", "torques")}
        self.n = {"states": 0, "torques": 0}
        self.overflow = 0
        self.markers: list[dict] = []
        self.diag: dict[str, str] = {}
        node.create_subscription(JointState, "joint_states", self._sink("states"), stream_qos(1000),
                                 raw=True)
        node.create_subscription(JointState, "joint_torques", self._sink("torques"),
                                 stream_qos(1000), raw=True)
        node.create_subscription(String, "movement", lambda m: self.markers.append(json.loads(m.data)),
                                 marker_qos())
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def _sink(self, topic: str):
        stamps, recvs, counts = self.stamp[topic], self.recv[topic], self.n
        unpack, now, cap = struct.Struct("<iI").unpack_from, time.time_ns, len(stamps)

        def on_raw(data: bytes) -> None:
            t = now()
            i = counts[topic]
            if i >= cap:
                self.overflow += 1
                return
            sec, nsec = unpack(data, 4)
            stamps[i] = sec * 1_000_000_000 + nsec
            recvs[i] = t
            counts[topic] = i + 1

        return on_raw

    def _on_diag(self, msg) -> None:
        for status in msg.status:
            if status.name.startswith("torque_node"):
                self.diag = {kv.key: kv.value for kv in status.values}

    def arrays(self, topic: str) -> tuple[np.ndarray, np.ndarray]:
        n = self.n[topic]
        return self.stamp[topic][:n], self.recv[topic][:n]


def _pct(x: np.ndarray) -> dict[str, float]:
    """p50 / p99 / max (NaN when empty: a minute without samples still has a table row)."""
    p = percentiles(x)
    return {k: p.get(k, float("nan")) for k in ("p50", "p99", "max")}


def analyse(mon: Monitor, sampler: Sampler, t_first_ns: int, minutes: float) -> dict:
    s_stamp, s_recv = mon.arrays("states")
    q_stamp, q_recv = mon.arrays("torques")
    answered = np.isin(s_stamp, q_stamp)
    end_ns = s_recv.max() if len(s_recv) else t_first_ns
    considered = s_recv <= end_ns - TAIL_GRACE_NS
    lost_mask = considered & ~answered
    matched = np.isin(q_stamp, s_stamp)
    latency_ms = (q_recv[matched] - q_stamp[matched]) / 1e6
    lat_minute = ((q_recv[matched] - t_first_ns) // 60_000_000_000).astype(int)
    s_minute = ((s_recv - t_first_ns) // 60_000_000_000).astype(int)
    n_full = int(minutes) if minutes >= 1 else 0
    rows = []
    for m in range(max(n_full, 1)):
        sel = s_minute == m
        lat = latency_ms[lat_minute == m]
        row = {"minute": m + 1, "joint_states": int(sel.sum()),
               "joint_torques": int(((q_recv - t_first_ns) // 60_000_000_000 == m).sum()),
               "lost": int((lost_mask & sel).sum()), "latency_ms": _pct(lat)}
        lo, hi = t_first_ns / 1e9 + 60 * m, t_first_ns / 1e9 + 60 * (m + 1)
        load = [x for t, x in sampler.load if lo <= t < hi]
        row["load_avg_1min"] = float(max(load)) if load else float("nan")
        for name, series in sampler.series.items():
            rss = series.rss_between(lo, hi - 1e-9)
            cpu = series.cpu_percent(lo, hi - 1e-9)
            if len(rss) >= 2 and cpu is not None:
                row[name] = {"rss_mb": float(np.median(rss)) / 1024, "cpu_pct": cpu}
        rows.append(row)
    # samples the publisher announced (per complete movement) that never arrived here
    markers = sorted(mon.markers, key=lambda d: d["t0_ns"])
    missing, complete = 0, 0
    order = np.sort(s_stamp)
    for a, b in itertools.pairwise(markers):
        if a["t0_ns"] < t_first_ns or b["t0_ns"] > (order[-1] if len(order) else 0):
            continue
        got = int(np.searchsorted(order, b["t0_ns"]) - np.searchsorted(order, a["t0_ns"]))
        missing += max(int(a["samples"]) - got, 0)
        complete += 1
    return {"rows": rows, "joint_states": len(s_stamp), "joint_torques": len(q_stamp),
            "lost": int(lost_mask.sum()), "considered": int(considered.sum()),
            "unmatched_torques": int((~matched).sum()), "latency_ms": _pct(latency_ms),
            "movements_complete": complete, "publisher_samples_missing": missing,
            "monitor_overflow": mon.overflow}


def verdicts(res: dict, args: argparse.Namespace) -> dict[str, dict]:
    rows = [r for r in res["rows"] if r["joint_states"]]
    first, last = rows[0], rows[-1]
    out = {}
    lost = res["lost"] + res["publisher_samples_missing"] + res["monitor_overflow"]
    out["no_loss"] = {"ok": lost == 0 and res["recorder"]["matches_monitor"]
                      and res["torque_node"].get("rejected_total") == "0"
                      and res["publisher_skipped_warnings"] == 0,
                      "detail": f"{res['lost']} unanswered of {res['considered']}, "
                                f"{res['publisher_samples_missing']} publisher samples missing, "
                                f"recorder matches monitor: {res['recorder']['matches_monitor']}, "
                                f"torque_node rejected {res['torque_node'].get('rejected_total')}"}
    for name in PROCESSES:
        if name in first and name in last:
            growth = last[name]["rss_mb"] - first[name]["rss_mb"]
            out[f"rss_{name}"] = {"ok": growth < args.rss_growth_mb,
                                  "detail": f"{first[name]['rss_mb']:.1f} -> {last[name]['rss_mb']:.1f} MB "
                                            f"({growth:+.2f} MB, limit {args.rss_growth_mb} MB)"}
    p1, pn = first["latency_ms"]["p99"], last["latency_ms"]["p99"]
    allowed = max(args.p99_tolerance * p1, args.p99_floor_ms)
    out["latency_p99_unchanged"] = {
        "ok": bool(abs(pn - p1) <= allowed),
        "detail": f"minute {first['minute']} {p1:.3f} ms, minute {last['minute']} {pn:.3f} ms "
                  f"(allowed +-{allowed:.3f} ms)"}
    return out


def table(res: dict) -> str:
    head = (f"{'min':>3} {'states':>7} {'torques':>7} {'lost':>4} {'lat p50':>8} {'p99':>7} "
            f"{'max ms':>7} {'load':>5} | " + " | ".join(f"{n[:14]:>14} RSS MB  CPU%" for n in PROCESSES))
    lines = [head, "-" * len(head)]
    for r in res["rows"]:
        lat = r["latency_ms"]
        procs = " | ".join(f"{r[n]['rss_mb']:>21.1f} {r[n]['cpu_pct']:>5.1f}" if n in r else f"{'-':>27}"
                           for n in PROCESSES)
        lines.append(f"{r['minute']:>3} {r['joint_states']:>7} {r['joint_torques']:>7} {r['lost']:>4} "
                     f"{lat['p50']:>8.3f} {lat['p99']:>7.3f} {lat['max']:>7.2f} "
                     f"{r.get('load_avg_1min', float('nan')):>5.2f} | {procs}")
    lines.append("")
    for name, v in res["verdicts"].items():
        lines.append(f"{'PASS' if v['ok'] else 'FAIL'}  {name}: {v['detail']}")
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="soak", description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="length of the replay (default 10)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/soak.json"))
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID") or 77))
    ap.add_argument("--no-record", action="store_true", help="run without bag_recorder")
    ap.add_argument("--keep-bag", type=Path, metavar="MCAP", help="keep the recorded bag here")
    ap.add_argument("--start-delay", type=float, default=5.0,
                    help="trajectory_publisher start_delay (s; see config/nodes/trajectory_publisher.yaml)")
    ap.add_argument("--rss-growth-mb", type=float, default=5.0)
    ap.add_argument("--p99-tolerance", type=float, default=0.25)
    ap.add_argument("--p99-floor-ms", type=float, default=0.1)
    args = ap.parse_args(argv)
    args.lease = claim_domain_arg(ap, args.domain, "soak")  # held until this process exits
    args.domain = args.lease.domain
    if args.minutes <= 0:
        ap.error("--minutes must be > 0")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # this process's monitor too
    os.environ["ROS_DOMAIN_ID"] = str(args.domain)
    os.environ.setdefault("HOME", tempfile.gettempdir())
    import rclpy
    from rclpy.experimental import EventsExecutor

    from forearm_dynamics.bag import open_bag

    work = Path(tempfile.mkdtemp(prefix="forearm_soak_"))
    os.environ.setdefault("ROS_LOG_DIR", str(work))
    env = ros_env(args.domain, work)
    bag_path = work / "soak.mcap"
    children: dict[str, Child] = {}
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=args.domain)
    node = rclpy.create_node("soak_monitor", context=ctx)
    capacity = int(args.minutes * 60 * 1000 * 1.1) + 100_000
    mon = Monitor(node, capacity)
    executor = EventsExecutor(context=ctx)
    executor.add_node(node)
    result: dict = {}
    try:
        children["torque_node"] = Child.script("torque_node", ["-p", "diagnostics_period:=1.0"],
                                               env, work)
        if not args.no_record:
            children["bag_recorder"] = Child.script("bag_recorder", ["-p", f"output:={bag_path}"],
                                                    env, work)
        _started(children["torque_node"], "config on", 60)
        if not args.no_record:
            _started(children["bag_recorder"], "recording", 60)
        subscribers = 3 if not args.no_record else 2  # torque_node, (recorder), this monitor
        children["trajectory_publisher"] = Child.script("trajectory_publisher", [
            "-p", "loop:=true", "-p", f"start_delay:={args.start_delay}",
            "-p", f"min_subscribers:={subscribers}", "-p", "subscriber_timeout:=60.0"], env, work)
        sampler = Sampler({**{n: c.pid for n, c in children.items()}, "monitor": os.getpid()},
                          period=1.0)
        sampler.start()
        print(f"soak: {args.minutes:g} min of looping replay at 1 kHz, domain {args.domain}, "
              f"logs in {work}", flush=True)
        deadline = time.monotonic() + args.start_delay + 90
        while mon.n["states"] == 0:
            if time.monotonic() > deadline or children["trajectory_publisher"].proc.poll() is not None:
                raise RuntimeError("no joint_states:\n" + children["trajectory_publisher"].text()[-2000:])
            executor.spin_once(timeout_sec=0.1)
        t_first = int(mon.recv["states"][0])
        end = t_first + int(args.minutes * 60e9)
        next_print = time.monotonic() + 60
        while time.time_ns() < end:
            executor.spin_once(timeout_sec=0.1)
            if time.monotonic() >= next_print:
                next_print += 60
                print(f"  {(time.time_ns() - t_first) / 60e9:4.1f} min: {mon.n['states']} joint_states, "
                      f"{mon.n['torques']} joint_torques", flush=True)
        children["trajectory_publisher"].stop()
        drain = time.monotonic() + 1.0
        while time.monotonic() < drain:
            executor.spin_once(timeout_sec=0.05)
        sampler.stop()
        codes = {n: children[n].stop() for n in ("bag_recorder", "torque_node") if n in children}
        codes["trajectory_publisher"] = children["trajectory_publisher"].proc.returncode
        result = analyse(mon, sampler, t_first, args.minutes)
        result["exit_codes"] = codes
        result["torque_node"] = {k: mon.diag.get(k) for k in (
            "received_total", "processed_total", "rejected_total", "warmup_total",
            "reset.stamp_gap", "reset.stamp_jump_back")}
        result["publisher_skipped_warnings"] = children["trajectory_publisher"].text().count("skipping")
        if args.no_record:
            result["recorder"] = {"matches_monitor": True, "recorded": False}
        else:
            counts = open_bag(bag_path).info.topic_counts()
            result["recorder"] = {
                "recorded": True, "bag_mb": bag_path.stat().st_size / 1e6,
                "joint_states": counts.get("/joint_states", 0),
                "joint_torques": counts.get("/joint_torques", 0),
                "matches_monitor": counts.get("/joint_states") == result["joint_states"]
                and counts.get("/joint_torques") == result["joint_torques"]}
            if args.keep_bag:
                shutil.move(bag_path, args.keep_bag)
    finally:
        for child in children.values():
            child.stop()
        executor.remove_node(node)
        node.destroy_node()
        ctx.try_shutdown()
    result["verdicts"] = verdicts(result, args)
    result.update(command=" ".join([Path(sys.argv[0]).name, *(argv or sys.argv[1:])]),
                  minutes=args.minutes, rate_hz=1000.0, domain=args.domain,
                  machine={**machine_info(), "load_avg_end": loadavg()},
                  finished=time.strftime("%Y-%m-%d %H:%M:%S"))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    print(table(result))
    print(f"written {args.out}")
    if all(v["ok"] for v in result["verdicts"].values()):
        shutil.rmtree(work, ignore_errors=True)
        return OK
    print(f"logs kept in {work}")
    return DATA


if __name__ == "__main__":
    sys.exit(main())
