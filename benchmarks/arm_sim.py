"""The virtual arm (arm_sim) on real processes: real-time rate, lockstep speed, closed loop.

    python benchmarks/arm_sim.py [--seconds 10] [--parts realtime,lockstep,closed_loop]
        [--domain 81] [--out benchmarks/sim.json]

Run from the repository root with the venv's python. Nodes run as their own processes
(forearm_dynamics/processes.py) on loopback DDS in their own ROS_DOMAIN_ID; this process
talks to them through raw subscriptions and publishers. Timing figures are reported,
never judged (the exit code is 0 unless a part could not run): the machine is shared,
so every section states the load average and the CPU the rest of the machine used.

- `arm_sim_realtime`: arm_sim at rate_hz 1000 for --seconds, this process sending it a
  1 kHz command stream; beside it, as the baseline measured in the same run,
  trajectory_publisher's 1 kHz stream (a timer-driven publisher of the same message
  type). For both: achieved rate (messages / receive span), receive interval p50/p99/max
  (ms); for arm_sim also the steps it skipped (stamp gaps), the CPU of each process (% of
  one core) and the ratio arm_sim / baseline of the p99 interval.
- `arm_sim_lockstep`: arm_sim with lockstep true; this process answers every joint_states
  with the next command at once (ping-pong) for --seconds: steps per second and the
  multiple of real time (steps/s / rate_hz). Baseline: the same ping-pong with
  null_echo_node (JointState in -> JointState out, nothing computed): the DDS round trip
  through a Python node, the ceiling for any lockstep node; ratio = arm_sim / echo.
- `core_step` (no ROS): the cost of one ArmSimulator.step (RK4 and semi-implicit Euler,
  limits and damping on, 50th-percentile segmented model) per call, p50/p99 in us, and as
  the baseline in the same run one inverse-dynamics call (ArmModel.inverse_dynamics, what
  torque_node computes per sample): ratio step / ID.
- `closed_loop`: examples/closed_loop.py on movements 1, 26, 51, in real time and in
  lockstep: tracking RMS per joint per movement (worst joint, elbow, pro_sup, wrist), loop
  latency p50/p99, steps skipped by arm_sim.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.procstat import Sampler
from benchmarks.stats import (
    claim_domain_arg,
    loadavg,
    machine_info,
    percentiles,
    save_sections,
)
from forearm_dynamics import JOINT_NAMES
from forearm_dynamics.codec.jointstate_cdr import STAMP, OutputTemplate
from forearm_dynamics.nodes.peer import Peer
from forearm_dynamics.processes import Child, ros_env

ROOT = Path(__file__).resolve().parent.parent


def _stream_stats(recv_ns: list[int]) -> dict:
    r = np.asarray(recv_ns, dtype=np.int64)
    if r.size < 2:
        return {"messages": int(r.size)}
    span = (r[-1] - r[0]) / 1e9
    return {"messages": int(r.size), "rate_hz": (r.size - 1) / span,
            "interval_ms": percentiles(np.diff(r), 1e-6)}


def realtime(env, logs: Path, seconds: float) -> dict:
    from sensor_msgs.msg import JointState

    from forearm_dynamics.nodes.common import stream_qos

    sim = Child.script("arm_sim", ["-p", "command_timeout:=0.5"], env, logs)
    base = Child.script("trajectory_publisher", [
        "-p", "output_topic:=baseline/joint_states", "-p", "marker_topic:=baseline/movement",
        "-p", "loop:=true", "-p", "start_delay:=0.3", "-p", "min_subscribers:=1",
        "-p", "movements:=[1, 2, 3, 4, 5]"], env, logs)
    peer = Peer("arm_sim_bench", int(env["ROS_DOMAIN_ID"]))
    recv = {"arm_sim": [], "baseline": []}
    stamps: list[int] = []
    stamp_of = STAMP.unpack_from

    def on_sim(data: bytes) -> None:
        recv["arm_sim"].append(time.monotonic_ns())
        sec, nsec = stamp_of(data, 4)
        stamps.append(sec * 1_000_000_000 + nsec)

    node = peer.node
    qos = stream_qos(1000)
    node.create_subscription(JointState, "joint_states", on_sim, qos, raw=True)
    node.create_subscription(JointState, "baseline/joint_states",
                             lambda _d: recv["baseline"].append(time.monotonic_ns()), qos, raw=True)
    pub = node.create_publisher(JointState, "joint_commands", qos)
    cmd = OutputTemplate(JOINT_NAMES).payload()  # zero torques on all joints, by name
    node.create_timer(0.001, lambda: pub.publish(cmd))
    try:
        peer.spin_for(5.0)  # discovery, start-up; then the window
        for times in recv.values():
            times.clear()
        stamps.clear()
        t0 = time.time()
        with Sampler({"arm_sim": sim.pid, "trajectory_publisher": base.pid}) as sampler:
            peer.spin_for(seconds)
        t1 = time.time()
    finally:
        peer.close()
        for c in (base, sim):
            c.stop()
    st = np.diff(np.asarray(stamps, dtype=np.int64))
    out = {"arm_sim": _stream_stats(recv["arm_sim"]), "baseline": _stream_stats(recv["baseline"]),
           "steps_skipped": int(((st // 1_000_000) - 1).clip(0).sum()) if st.size else None,
           "stamp_gaps": int((st > 1_000_000).sum()) if st.size else None,
           "cpu_percent": {n: s.cpu_percent(t0, t1) for n, s in sampler.series.items()},
           "foreign_cpu_percent": sampler.foreign_cpu_percent(t0, t1),
           "loadavg": [x for _, x in sampler.load][-1:] or None, "seconds": seconds}
    a, b = out["arm_sim"].get("interval_ms"), out["baseline"].get("interval_ms")
    if a and b:
        out["interval_p99_ratio_to_baseline"] = a["p99"] / b["p99"]
    return out


def pingpong(env, logs: Path, seconds: float, node_name: str) -> dict:
    """Answer every output with the next input at once; count the round trips."""
    from sensor_msgs.msg import JointState

    from forearm_dynamics.nodes.common import stream_qos

    if node_name == "arm_sim":
        child = Child.script("arm_sim", ["-p", "lockstep:=true"], env, logs)
        in_topic, out_topic = "joint_commands", "joint_states"
    else:
        child = Child.script("null_echo_node", [], env, logs)
        in_topic, out_topic = "joint_states", "joint_torques"
    peer = Peer("arm_sim_bench", int(env["ROS_DOMAIN_ID"]))
    node = peer.node
    qos = stream_qos(1000)
    msg = OutputTemplate(JOINT_NAMES)
    pub = node.create_publisher(JointState, in_topic, qos)
    count = [0]
    last = [0]

    def send() -> None:
        t = max(time.time_ns(), last[0] + 1000)  # the echo node wants increasing stamps
        last[0] = t
        msg.pack_stamp(*divmod(t, 1_000_000_000))
        pub.publish(msg.payload())

    def on_out(_data: bytes) -> None:
        count[0] += 1
        send()

    node.create_subscription(JointState, out_topic, on_out, qos, raw=True)
    try:
        end = time.monotonic() + 20
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            peer.spin_for(0.1)
        peer.spin_for(1.0)
        send()  # the first ping; every answer sends the next
        peer.spin_for(1.0)  # warm-up
        n0, t0 = count[0], time.monotonic()
        with Sampler({node_name: child.pid}) as sampler:
            peer.spin_for(seconds)
        n1, t1 = count[0], time.monotonic()
        cpu = sampler.series[node_name].cpu_percent(sampler.series[node_name].t[0],
                                                    sampler.series[node_name].t[-1])
    finally:
        peer.close()
        child.stop()
    return {"round_trips_per_s": (n1 - n0) / (t1 - t0), "cpu_percent": cpu,
            "loadavg": loadavg(), "seconds": seconds}


def core_step(n: int = 5000) -> dict:
    from forearm_dynamics import build_model
    from forearm_dynamics.simulation import ArmSimulator, SimSettings

    arm = build_model("segmented", 50)
    tau = arm.gravity_torques(ArmSimulator(arm).q) * 0.9
    out = {"calls": n, "loadavg_before": loadavg()}
    perf = time.perf_counter_ns
    for method in ("rk4", "semi_implicit_euler"):
        sim = ArmSimulator(arm, SimSettings(method=method))
        times = np.empty(n, dtype=np.int64)
        for k in range(n):
            t = perf()
            sim.step(tau)
            times[k] = perf() - t
        out[method] = percentiles(times, 1e-3)
    q, qd, qdd = ArmSimulator(arm).q, np.full(20, 0.1), np.full(20, 0.5)
    times = np.empty(n, dtype=np.int64)
    for k in range(n):
        t = perf()
        arm.inverse_dynamics(q, qd, qdd)
        times[k] = perf() - t
    out["baseline_inverse_dynamics"] = percentiles(times, 1e-3)
    out["rk4_p50_ratio_to_baseline"] = out["rk4"]["p50"] / out["baseline_inverse_dynamics"]["p50"]
    out["loadavg_after"] = loadavg()
    return out


def closed_loop(domain: int) -> dict:
    out = {}
    for mode in ("realtime", "lockstep"):
        d = Path(tempfile.mkdtemp(prefix=f"bench_closed_loop_{mode}_"))
        argv = [sys.executable, str(ROOT / "examples" / "closed_loop.py"), "--movements", "1,26,51",
                "--out", str(d), "--domain", str(domain)] + (["--lockstep"] if mode == "lockstep" else [])
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=600, check=False)
        print(proc.stdout, end="", flush=True)
        if proc.returncode != 0:
            out[mode] = {"error": proc.stderr.strip().splitlines()[-1:] or ["exit"], "code": proc.returncode}
            continue
        res = json.loads((d / "results.json").read_text())
        logs = "".join(p.read_text() for p in (d / "logs").glob("arm_sim*.log"))
        skipped = re.findall(r"steps skipped (\d+)", logs)
        rows = {}
        for m in res["movements"]:
            rms = m["rms_rad"]
            worst = max(rms, key=rms.get)
            rows[m["id"]] = {"worst_joint": worst, "worst_rms_rad": rms[worst],
                             **{f"{j}_rms_rad": rms[j] for j in ("elbow_flexion", "pro_sup",
                                                                 "wrist_flexion")},
                             "rms_rad": rms}
        out[mode] = {"movements": rows, "loop_latency_ms_p50_p99": res["loop_latency_ms"],
                     "ff_latency_ms_p50_p99": res["ff_latency_ms"],
                     "arm_sim_steps_skipped": int(skipped[-1]) if skipped else None,
                     "loadavg": res["loadavg"]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--parts", default="core_step,realtime,lockstep,closed_loop")
    ap.add_argument("--domain", type=int, default=81)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/sim.json"))
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "arm_sim benchmark")
    logs = Path(tempfile.mkdtemp(prefix="arm_sim_bench_"))
    env = ros_env(lease.domain, logs)
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    parts = args.parts.split(",")
    new: dict = {}
    if "core_step" in parts:
        c = new["core_step"] = core_step()
        print(f"core step (us, p50/p99): rk4 {c['rk4']['p50']:.1f}/{c['rk4']['p99']:.1f}, "
              f"semi-implicit Euler {c['semi_implicit_euler']['p50']:.1f}/"
              f"{c['semi_implicit_euler']['p99']:.1f}; one inverse dynamics "
              f"{c['baseline_inverse_dynamics']['p50']:.1f}/{c['baseline_inverse_dynamics']['p99']:.1f}"
              f" (rk4 / ID = {c['rk4_p50_ratio_to_baseline']:.1f}); load {c['loadavg_before']}",
              flush=True)
    if "realtime" in parts:
        r = new["arm_sim_realtime"] = realtime(env, logs, args.seconds)
        a, b = r["arm_sim"], r["baseline"]
        print(f"arm_sim real time: {a.get('rate_hz', 0):.1f} Hz, interval p50/p99/max "
              f"{a['interval_ms']['p50']:.3f}/{a['interval_ms']['p99']:.3f}/"
              f"{a['interval_ms']['max']:.1f} ms, {r['steps_skipped']} steps skipped, CPU "
              f"{r['cpu_percent']['arm_sim']:.1f} %; baseline trajectory_publisher "
              f"{b.get('rate_hz', 0):.1f} Hz, p50/p99 {b['interval_ms']['p50']:.3f}/"
              f"{b['interval_ms']['p99']:.3f} ms, CPU {r['cpu_percent']['trajectory_publisher']:.1f} %; "
              f"others {r['foreign_cpu_percent']:.0f} % of a core, load {r['loadavg']}", flush=True)
    if "lockstep" in parts:
        sim = pingpong(env, logs, args.seconds, "arm_sim")
        echo = pingpong(env, logs, args.seconds, "null_echo_node")
        new["arm_sim_lockstep"] = {"arm_sim": sim, "baseline_null_echo_node": echo,
                                   "realtime_multiple": sim["round_trips_per_s"] / 1000.0,
                                   "ratio_to_baseline": sim["round_trips_per_s"] / echo["round_trips_per_s"]}
        print(f"arm_sim lockstep: {sim['round_trips_per_s']:.0f} steps/s "
              f"({sim['round_trips_per_s'] / 1000:.2f} x real time), CPU {sim['cpu_percent']:.0f} %; "
              f"null_echo_node ping-pong {echo['round_trips_per_s']:.0f}/s (ratio "
              f"{sim['round_trips_per_s'] / echo['round_trips_per_s']:.2f}); load {loadavg()}", flush=True)
    if "closed_loop" in parts:
        lease.release()  # the example claims its own domain
        new["closed_loop"] = closed_loop(args.domain)
    new["arm_sim_machine"] = machine_info()
    save_sections(args.out, new, "benchmarks/arm_sim.py", argv, started)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
