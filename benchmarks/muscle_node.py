"""Muscle layer benchmark (issue 31): cost, delivery, and agreement with OpenSim.

    python -m benchmarks.muscle_node [--quick] [--out benchmarks/muscle_node.json]

Sections (each states the load average; 2 cores):
- `solve`: in process, no ROS: the 65 movements at 1 kHz (torques by Pinocchio from the exact
  q, q̇, q̈), per sample: geometry (surrogate moment arms, lengths, speeds), the QP alone
  (MuscleSolution.solve_time) and both; p50/p99 in µs.
- `callback`: in process, a real MuscleNode (rclpy; its publishers have no reader) fed the
  torque node's bytes (the 65 movements' torques, CDR as torque_node writes them), each call of
  its joint_torques callback timed (p50/p99 µs) beside the node's own split (publish, own):
  the node's cost without DDS delivery and other processes. Read it against `solve` (the
  geometry + QP alone, same run): the difference is the node's reading, writing and
  bookkeeping.
- `chain`: trajectory_publisher -> torque_node -> muscle_node -> receiver at 1 kHz over the
  movements (real processes, loopback DDS): muscle_forces received (unique stamps) vs
  samples sent (lost), muscle_node's own callback time and QP time from its /diagnostics
  (median over the 1 s periods of their p50/p99), muscle_forces latency (receive time - the
  joint_states stamp), joint_torques latency in the same run. After the publisher ends the
  chain waits while muscle_node still works (its own input queue, muscle_backlog.py; at most
  DRAIN_WAIT_S): a late answer counts as answered, with its latency (`--no-drain-wait`: 1 s,
  as before). `--muscle-args backlog_limit:=0` runs the node without its own queue.
- `torque_path`: the same replay through null_echo_node and torque_node alone (the torque
  benchmark's variants): the torque node's latency p50 as a ratio to null_echo_node's, without
  and (chain) with muscle_node subscribed: "torque-path latency unchanged".
- `opensim`: our per-sample QP against the cached OpenSim StaticOptimization reference
  (muscle_validation/reference.py; `make muscle-reference`) and against the exact-geometry
  solve (MuJoCo tendon Jacobians + BVLS), per muscle.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.procstat import Sampler
from forearm_dynamics.dynamics import build_model
from forearm_dynamics.movements import get_movement, movement_library
from forearm_dynamics.muscle_validation.opensim_so import model_digest, our_movement
from forearm_dynamics.muscle_validation.reference import (
    REFERENCE_FILE,
    accepted_frames,
    figures,
    load_reference,
)
from forearm_dynamics.muscles import StaticOptimizer, load_muscle_model
from forearm_dynamics.processes import Child, ros_env

from . import module_env
from .muscle_callback import torque_payloads
from .stats import claim_domain_arg, loadavg, machine_info, percentiles, write_json
from .torque_path import Variant, _expected, _figures, _sent_by_publisher, run_variant

OUT = Path(__file__).with_name("muscle_node.json")


def solve_section(movements: list[int]) -> dict:
    mm = load_muscle_model()
    arm = build_model("segmented", 50)
    so = StaticOptimizer(mm)
    geo, qp, whole = [], [], []
    residual, infeasible = 0.0, 0
    load0 = loadavg()
    for mid in movements:
        mv = get_movement(mid)
        q, qd, qdd = mv.evaluate(mv.sample_times(1000.0))
        tau = arm.inverse_dynamics_batch(q, qd, qdd)
        so.reset()
        for k in range(len(q)):
            t0 = time.perf_counter_ns()
            R, L, V = mm.geometry(q[k], qd[k])
            t1 = time.perf_counter_ns()
            s = so.solve_geometry(R, L, V, tau[k])
            t2 = time.perf_counter_ns()
            geo.append(t1 - t0)
            whole.append(t2 - t0)
            qp.append(s.solve_time * 1e9)
            residual = max(residual, s.residual)
            infeasible += s.infeasible
    return {"samples": len(qp), "movements": len(movements), "muscles": mm.n,
            "geometry_us": percentiles(geo, 1e-3), "qp_us": percentiles(qp, 1e-3),
            "geometry_plus_qp_us": percentiles(whole, 1e-3), "max_residual_nm": residual,
            "infeasible_samples": int(infeasible), "loadavg": [load0, loadavg()]}


def callback_section(movements: list[int], domain: int) -> dict:
    """Time MuscleNode's joint_torques callback in this process (see the module docstring)."""
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    import rclpy

    from forearm_dynamics.nodes.muscle_node import MuscleNode

    rclpy.init(args=["--ros-args", "-p", "nice:=0", "-p", "diagnostics_period:=0.0",
                     "-p", "config_topic:=''"])
    load0 = loadavg()
    try:
        node = MuscleNode()
        calls, own, pub = [], [], []
        stats = node.stats
        for data in torque_payloads(get_movement(mid) for mid in movements):
            t0 = time.perf_counter_ns()
            node._on_torques(data)
            calls.append(time.perf_counter_ns() - t0)
            i = (stats._n - 1) % stats._window
            own.append(stats._compute_ns[i] - stats._publish_ns[i])
            pub.append(stats._publish_ns[i])
        out = {"samples": len(calls), "published": stats.published,
               "rejected": sum(stats.rejected.values()), "callback_us": percentiles(calls, 1e-3),
               "node_compute_minus_publish_us": percentiles(own, 1e-3),
               "node_publish_us": percentiles(pub, 1e-3),
               "note": "publishers without readers: publish() here is not the DDS delivery of "
                       "the chain", "loadavg": [load0, loadavg()]}
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return out


def _diag_stats(diag: list[dict], t0: float, t1: float) -> dict:
    rows = [d["values"] for d in diag if t0 <= d["t"] <= t1 + 1.5
            and float(d["values"].get("output_rate_hz", 0)) > 0
            and d["values"].get("compute_us_p50", "nan") != "nan"]
    if not rows:
        return {"periods": 0}
    out = {"periods": len(rows)}
    for key in ("compute_us_p50", "compute_us_p99", "solve_us_p50", "solve_us_p99",
                "publish_us_p50", "own_us_p50", "executor_cpu_us_per_sample"):
        vals = np.array([float(r[key]) for r in rows if key in r])
        if len(vals):
            out[key] = float(np.median(vals))
            out[key + "_worst_period"] = float(vals.max())
    last = rows[-1]
    for key in ("reserve_use_total", "infeasible_total", "solver_failed_total", "rejected_total",
                "received_total", "processed_total", "backlog_max_samples_total",
                "drained_total", "backlog_dropped_total", "input_gaps_total"):
        if key in last:
            out[key] = int(last[key])
    return out


#: after the publisher ends, how long the chain waits at most for muscle_node to answer what
#: it still holds (its own input queue: muscle_backlog.py): an answer seconds late is late
#: (its latency is reported), not lost
DRAIN_WAIT_S = 300.0
CORES = os.cpu_count() or 1


def _wait_while_busy(pid: int, limit_s: float, idle_cpu: float = 0.05) -> float:
    """Wait until process pid uses < idle_cpu of a core over 2 s while the machine had a
    quarter of a core to spare (its backlog answered, not starved: at nice 10 beside busy
    processes it gets a few % and is still working) or limit_s passed; returns the seconds
    waited."""
    from benchmarks.procstat import machine_busy, proc_stat

    t0 = time.time()
    last, busy = proc_stat(pid), machine_busy()
    while last is not None and time.time() - t0 < limit_s:
        time.sleep(2.0)
        now, busy_now = proc_stat(pid), machine_busy()
        if now is None:
            break
        spare = busy is None or busy_now is None or (busy_now - busy) < CORES * 2.0 - 0.5
        if now.cpu_s - last.cpu_s < idle_cpu * 2.0 and spare:
            break
        last, busy = now, busy_now
    return time.time() - t0


def run_chain(movements: list[int], domain: int, work: Path, start_delay: float = 5.0,
              muscle_args: tuple[str, ...] = (), drain_wait: bool = True) -> dict:
    """trajectory_publisher -> torque_node -> muscle_node -> receiver (muscle_forces; also
    joint_torques). muscle_args: extra -p assignments for muscle_node; drain_wait: after the
    publisher ends, wait while muscle_node still works (DRAIN_WAIT_S at most)."""
    logs = work / "chain"
    logs.mkdir(parents=True, exist_ok=True)
    env = ros_env(domain, logs)
    rx_path = logs / "rx.npz"
    children: list[Child] = []
    try:
        torque = Child.script("torque_node", ["-p", "diagnostics_period:=1.0"], env, logs)
        children.append(torque)
        margs = ["-p", "diagnostics_period:=1.0"]
        for a in muscle_args:
            margs += ["-p", a]
        muscle = Child.script("muscle_node", margs, env, logs)
        children.append(muscle)
        rx = Child.module("receiver", "benchmarks.receiver",
                          ["--topic", "muscle_forces", "--out", str(rx_path), "--diag-prefix",
                           "muscle_node", "--also", "joint_torques"], module_env(env), logs)
        children.append(rx)
        for c, text in ((torque, "joint_torques ("), (muscle, "muscle_forces"),
                        (rx, "receiver: matched")):
            if not c.wait_for(text, 120):
                raise RuntimeError(f"{c.name} did not start:\n{c.text()[-2000:]}")
        with Sampler({"torque_node": torque.pid, "muscle_node": muscle.pid,
                      "receiver": rx.pid}) as sampler:
            pub_args = ["-p", f"movements:={movements}", "-p", f"start_delay:={start_delay}",
                        "-p", "min_subscribers:=2", "-p", "subscriber_timeout:=60.0"]
            pub_started = time.time()
            pub = Child.script("trajectory_publisher", pub_args, env, logs)
            children.append(pub)
            sampler.add("publisher", pub.pid)
            code = pub.wait(start_delay + 1.5 * len(movements) * 3 + 60)
            if code != 0:
                raise RuntimeError(f"trajectory_publisher exited {code}:\n{pub.text()[-2000:]}")
            pub_ended = time.time()
            time.sleep(1.0)  # the last answers in flight
            drain_s = _wait_while_busy(muscle.pid, DRAIN_WAIT_S) if drain_wait else 0.0
            sampler.sample()
        codes = {c.name: c.stop() for c in reversed(children)}
    finally:
        for c in children:
            c.stop()
    sent, _ = _sent_by_publisher(pub.text())
    data = np.load(rx_path)
    diag = json.loads(rx_path.with_suffix(".diag.json").read_text())
    expected = _expected(movements)
    res = _figures(data["recv_ns"], data["stamp_ns"], sent if sent is not None else expected,
                   sampler, diag, pub_started)
    res.pop("callback_us", None)
    t0, t1 = data["recv_ns"][0] / 1e9, data["recv_ns"][-1] / 1e9
    tq_lat = (data["also_recv_ns"] - data["also_stamp_ns"]) / 1e6
    lat = (data["recv_ns"] - data["stamp_ns"]) / 1e9
    res.update({"muscle_args": list(muscle_args),
                "waited_after_publisher_s": round(drain_s + 1.0, 1),
                "answered_after_publisher_ended": int((data["recv_ns"] / 1e9 > pub_ended).sum()),
                "muscle_forces_latency_s_max": float(lat.max()) if len(lat) else None})
    res.update({"expected": expected, "sent": sent, "exit_codes": codes,
                "muscle_node_diagnostics": _diag_stats(diag, t0, t1),
                "joint_torques": {"unique": int(np.unique(data["also_stamp_ns"]).size),
                                  "latency_ms": percentiles(tq_lat)},
                "muscle_node_log_summary": next((line for line in muscle.text().splitlines()
                                                 if "summary:" in line), None)})
    return res


def torque_path_section(movements: list[int], domain: int, work: Path, chain: dict) -> dict:
    out = {}
    for v in (Variant("null_echo_node", node="null_echo_node"), Variant("torque_node")):
        r = run_variant(v, movements, domain, work)
        out[v.name] = {"latency_ms_p50": r["latency_ms"]["p50"],
                       "latency_ms_p99": r["latency_ms"]["p99"], "lost": r["lost"],
                       "callback_us": r["callback_us"]}
    base = out["null_echo_node"]["latency_ms_p50"]
    out["ratio_torque_alone"] = out["torque_node"]["latency_ms_p50"] / base
    out["ratio_torque_with_muscle_node"] = chain["joint_torques"]["latency_ms"]["p50"] / base
    out["note"] = ("torque_node's joint_torques latency p50 / null_echo_node's in the same "
                   "session; with muscle_node: the chain run's joint_torques latency")
    return out


def opensim_section() -> dict:
    if not REFERENCE_FILE.is_file():
        return {"error": f"{REFERENCE_FILE} missing: make muscle-reference"}
    ref = load_reference()
    mm = load_muscle_model()
    arm = build_model("segmented", 50)
    stale = ref.meta.get("muscle_model_sha256") != model_digest(mm)
    A, F, Q, T = [], [], [], []
    for i, mid in enumerate(ref.movement_ids):
        sl = ref.frames(i)
        mv = get_movement(int(mid))
        ser, tau = our_movement(arm, mm, mv, ref.times[sl])
        A.append(ser.activations)
        F.append(ser.forces)
        Q.append(mv.evaluate(ref.times[sl])[0])
        T.append(tau)
    A, F, Q, T = map(np.vstack, (A, F, Q, T))
    keep, rejected = accepted_frames(mm, Q, T, ref.forces, ref.reserves)
    f = figures(mm, A, ref.activations, keep, rejected, F, ref.forces)
    out = {"stale_reference": stale, "movements": [int(m) for m in ref.movement_ids],
           "frames": len(A), "reference_meta": ref.meta, "summary": f.summary(),
           "per_muscle": [f.row(i) for i in range(mm.n)]}
    if ref.exact_activations is not None:
        g = figures(mm, A, ref.exact_activations, np.ones(len(A), bool), {})
        out["exact_geometry"] = {"summary": g.summary(), "per_muscle": [g.row(i) for i in range(mm.n)]}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.muscle_node", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--quick", action="store_true", help="5 movements instead of 65")
    ap.add_argument("--sections", default="solve,chain,torque_path,opensim")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID") or 0) or 76)
    ap.add_argument("--muscle-args", default="",
                    help="comma-separated -p assignments for the chain's muscle_node, e.g. "
                         "backlog_limit:=0 (no own input queue: the node before it)")
    ap.add_argument("--no-drain-wait", action="store_true",
                    help="stop the chain 1 s after the publisher (the benchmark before the "
                         "node had its own input queue) instead of waiting while muscle_node "
                         "still answers")
    args = ap.parse_args(argv)
    sections = set(args.sections.split(","))
    movements = [m.id for m in movement_library()]
    if args.quick:
        movements = movements[::13]
    # sections run apart (e.g. opensim once the reference exists) merge into one file
    out: dict = json.loads(args.out.read_text()) if args.out.is_file() else {}
    out.update({"machine": machine_info(), f"loadavg_start_{'_'.join(sorted(sections))}": loadavg(),
                f"command_{'_'.join(sorted(sections))}":
                "python -m benchmarks.muscle_node " + " ".join(argv or sys.argv[1:])})
    if "solve" in sections:
        out["solve"] = solve_section(movements)
        print(json.dumps(out["solve"], indent=1), file=sys.stderr)
    if "callback" in sections:
        lease = claim_domain_arg(ap, args.domain, "benchmarks.muscle_node")
        out["callback"] = callback_section(movements, lease.domain)
        lease.release()
        print(json.dumps({k: out["callback"][k] for k in ("callback_us",
                          "node_compute_minus_publish_us", "node_publish_us")}, indent=1),
              file=sys.stderr)
    if "opensim" in sections:
        out["opensim"] = opensim_section()
        print(json.dumps(out["opensim"].get("summary"), indent=1), file=sys.stderr)
    if sections & {"chain", "torque_path"}:
        lease = claim_domain_arg(ap, args.domain, "benchmarks.muscle_node")
        with tempfile.TemporaryDirectory(prefix="bench_muscle_") as tmp:
            out["domain_id"] = lease.domain
            chain = run_chain(movements, out["domain_id"], Path(tmp),
                              muscle_args=tuple(a for a in args.muscle_args.split(",") if a),
                              drain_wait=not args.no_drain_wait)
            out["chain"] = chain
            print(json.dumps({k: chain[k] for k in ("sent", "unique", "lost",
                                                    "muscle_node_diagnostics")}, indent=1),
                  file=sys.stderr)
            if "torque_path" in sections:
                out["torque_path"] = torque_path_section(movements, out["domain_id"], Path(tmp), chain)
    out[f"loadavg_end_{'_'.join(sorted(sections))}"] = loadavg()
    write_json(args.out, out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
