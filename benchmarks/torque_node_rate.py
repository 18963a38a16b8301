"""torque_node's fixed-rate output and its live model changes, measured on real processes.

    python benchmarks/torque_node_rate.py [--seconds 20] [--switch-seconds 20]
        [--parts rate,switch] [--domain 79] [--out benchmarks/results.json]

Run from the repository root with the venv's python (`make bench-rate`). torque_node runs
as its own process (forearm_dynamics/processes.py), on loopback DDS
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in its own ROS_DOMAIN_ID; this process feeds it
and receives its outputs (raw subscription: the receive time and the CDR bytes of every
message).

- `output_rate` (issue 10): `output_rate_hz 1000` from a 100 Hz input (positions and exact
  velocities of a sinusoid) for --seconds. Every output is stamped with its publication
  time, so the node's rate and publish intervals are read from the stamps (the receiver's
  own scheduling does not enter). Steady window: from 0.5 s after the first input to the
  last input. Reports `rate_hz` (outputs / stamp span), `rate_error_fraction` (vs 1000),
  `interval_ms` {p50, p99, p99_9, max, ...}, `repeated_stamps`, `repeated_values`
  (consecutive outputs with the same effort vector), `outputs_after_last_input`,
  `latency_ms` (receive - stamp).
- `live_switch` (issue 12): a 1 kHz replay (constant-acceleration trajectory with exact
  velocities, one output per input) for --switch-seconds; every 2 s a live change
  (body_size 95, a 0.5 kg payload, body_size 50, no payload, ...) through
  set_parameters_atomically. Reports `lost` (inputs with no output), `wrong_model` (outputs
  not equal, to 1e-9 N·m at the exact state, to the model of the config in force at their
  stamp per the node's ~/config: a half-built or mixed model would show here),
  `warmup` (outputs of a warm-up sample, acceleration 0: the first, and any after a stamp
  gap when this process stalled, as the node's summary says), per switch
  `request_to_first_new_sample_ms` (the stamp of the first output computed with the new
  model - the wall time of the request) and `build_ms` (the node's worker thread),
  `latency_ms` (receive - stamp) p50/p99 in the switch windows (request to 300 ms after
  the first new sample) and in the steady state (all other samples after the first 1 s),
  and `latency_p99_ratio` = switch / steady (the same with 1 s windows from the request:
  `latency_ms_1s_window`, `latency_p99_ratio_1s_window`; the shorter the window, the more
  its p99 is the few samples that waited for the build); `latency_ms.request_to_first_new_sample`:
  the samples stamped while the model was being built (the worker thread's GIL share).

Exit code: DATA (1) if a sample was lost, repeated or computed with the wrong model
(forearm_dynamics/exit_codes.py); timing figures never change it.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # `python benchmarks/torque_node_rate.py` from the repo root
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.procstat import proc_stat
from benchmarks.stats import claim_domain_arg, loadavg, machine_info, percentiles, save_sections
from forearm_dynamics.exit_codes import DATA, OK
from forearm_dynamics.nodes.peer import Peer
from forearm_dynamics.processes import Child, ros_env

MS = 1_000_000
RATE_HZ = 1000.0
SWITCHES = [
    {"body_size": 95},
    {"payload_mass": 0.5, "payload_com": [0.0, -0.06, -0.04]},
    {"body_size": 50},
    {"payload_mass": 0.0},
]
SWITCH_WINDOW_MS = 300


def wait_until(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def feed(pub, t0: int, period_ns: int, n: int, state, stamps: list[int]) -> None:
    """n samples at absolute deadlines t0 + k period, each stamped at publication, exact there."""
    from sensor_msgs.msg import JointState

    from forearm_dynamics import JOINT_NAMES

    msg = JointState()
    msg.name = list(JOINT_NAMES)
    last = 0
    for k in range(n):
        delay = (t0 + k * period_ns - time.time_ns()) / 1e9
        if delay > 0:
            time.sleep(delay)
        t = max(time.time_ns(), last + 1000)
        last = t
        q, qd = state((t - t0) * 1e-9)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
        msg.position, msg.velocity = q.tolist(), qd.tolist()
        pub.publish(msg)
        stamps.append(t)


def _stamps(raw: list[tuple[int, bytes]]) -> np.ndarray:
    import struct

    unpack = struct.Struct("<iI").unpack_from
    pairs = np.array([unpack(b, 4) for _, b in raw], np.int64).reshape(-1, 2)
    return pairs[:, 0] * 1_000_000_000 + pairs[:, 1]


def _start_node(name: str, ros_args: list[str], domain: int, work: Path) -> Child:
    return Child.script("torque_node", ros_args, ros_env(domain, work), work, label=name)


def _finish(child: Child) -> dict:
    code = child.stop(signal.SIGINT)
    text = child.text()
    return {"exit_code": code, "traceback": "Traceback" in text,
            "summary": next((ln.strip() for ln in text.splitlines() if "summary:" in ln), "")}


def measure_rate(domain: int, work: Path, seconds: float) -> dict:
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from forearm_dynamics.nodes.common import stream_qos

    rng = np.random.default_rng(5)
    amp, w, phase = rng.uniform(0.1, 0.4, 20), rng.uniform(2, 8, 20), rng.uniform(0, 6, 20)

    def state(t_s: float):
        return amp * np.sin(w * t_s + phase), amp * w * np.cos(w * t_s + phase)

    child = _start_node("torque_node_rate", ["-p", f"output_rate_hz:={RATE_HZ}", "-p",
                                             "input_timeout:=0.2"], domain, work)
    peer = Peer("rate_bench", domain)
    peer.spin_in_background()
    raw: list[tuple[int, bytes]] = []
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        node.create_subscription(JointState, "joint_torques",
                                 lambda b: raw.append((time.time_ns(), b)), stream_qos(5000), raw=True)
        if not wait_until(lambda: pub.get_subscription_count() > 0, 30):
            raise RuntimeError(f"torque_node did not subscribe:\n{child.text()[-2000:]}")
        time.sleep(0.5)
        sent: list[int] = []
        n = int(seconds * 100)
        cpu0, t_cpu0 = proc_stat(child.pid), time.monotonic()
        feed(pub, time.time_ns() + 100 * MS, 10 * MS, n, state, sent)
        cpu1, t_cpu1 = proc_stat(child.pid), time.monotonic()
        time.sleep(1.0)
    finally:
        peer.close()
        proc = _finish(child)
    stamps = _stamps(raw)
    recv = np.array([r for r, _ in raw], np.int64)
    effort = np.array([deserialize_message(b, JointState).effort for _, b in raw])
    steady = stamps[(stamps >= sent[0] + 500 * MS) & (stamps <= sent[-1])]
    span = (steady[-1] - steady[0]) / 1e9
    rate = (len(steady) - 1) / span
    same_values = int((np.abs(np.diff(effort, axis=0)).max(axis=1) == 0).sum()) if len(effort) > 1 else 0
    return {
        "input_rate_hz": 100.0, "output_rate_hz": RATE_HZ, "input_samples": len(sent),
        "seconds": seconds, "outputs": len(stamps), "steady_outputs": len(steady),
        "steady_span_s": span, "rate_hz": rate, "rate_error_fraction": rate / RATE_HZ - 1.0,
        "interval_ms": percentiles(np.diff(steady), 1e-6),
        "intervals_over_2ms": int((np.diff(steady) > 2 * MS).sum()),
        "repeated_stamps": int(len(stamps) - len(np.unique(stamps))),
        "stamps_increasing": bool((np.diff(stamps) > 0).all()),
        "repeated_values": same_values,
        "outputs_after_last_input": int((stamps > sent[-1]).sum()),
        "latency_ms": percentiles(recv - stamps, 1e-6),
        "node_cpu_percent": (100 * (cpu1.cpu_s - cpu0.cpu_s) / (t_cpu1 - t_cpu0)
                             if cpu0 and cpu1 else None),
        "node": proc,
    }


def measure_switch(domain: int, work: Path, seconds: float) -> dict:
    from rcl_interfaces.srv import SetParametersAtomically
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from forearm_dynamics.model_config import config_in_force, model_from_config
    from forearm_dynamics.nodes.common import stream_qos

    rng = np.random.default_rng(7)
    q0, v0, acc = rng.uniform(-0.3, 0.3, 20), rng.uniform(-0.5, 0.5, 20), rng.uniform(-2, 2, 20)
    v0, acc = v0 / 5, acc / 20  # an arm's motion: far-out angles are refused as units (issue 30)

    def state(t_s: float):
        return q0 + v0 * t_s + 0.5 * acc * t_s * t_s, v0 + acc * t_s

    # the backward estimator: exact for this stream, so every output can be checked against
    # the model in force at its stamp (the switch is what is measured, not the estimator)
    child = _start_node("torque_node_switch", ["-p", "diagnostics_period:=0.5",
                                               "-p", "estimator:=backward"], domain, work)
    peer = Peer("rate_bench", domain)
    peer.spin_in_background()
    raw: list[tuple[int, bytes]] = []
    configs: list[tuple[int, dict]] = []
    asked: list[tuple[int, dict, object]] = []
    n = int(seconds * 1000)
    try:
        node = peer.node
        pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        node.create_subscription(JointState, "joint_torques",
                                 lambda b: raw.append((time.time_ns(), b)), stream_qos(5000), raw=True)
        latched = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(String, "/torque_node/config",
                                 lambda m: configs.append((time.time_ns(), json.loads(m.data))), latched)
        client = node.create_client(SetParametersAtomically, "/torque_node/set_parameters_atomically")
        if not (client.wait_for_service(timeout_sec=30) and
                wait_until(lambda: pub.get_subscription_count() > 0 and configs, 30)):
            raise RuntimeError(f"torque_node did not come up:\n{child.text()[-2000:]}")
        time.sleep(0.5)
        sent: list[int] = []
        t0 = time.time_ns() + 200 * MS
        feeder = threading.Thread(target=feed, args=(pub, t0, MS, n, state, sent), daemon=True)
        feeder.start()
        for i, k in enumerate(range(2000, n - 1000, 2000)):
            if not wait_until(lambda k=k: len(sent) >= k, 60):
                break
            params = SWITCHES[i % len(SWITCHES)]
            req = SetParametersAtomically.Request(parameters=[
                Parameter(name, value=x).to_parameter_msg() for name, x in params.items()])
            asked.append((time.time_ns(), params, client.call_async(req)))
        feeder.join(timeout=seconds + 60)
        wait_until(lambda: len(raw) >= len(sent), 10)
        time.sleep(0.7)  # the periodic config republication
        node.destroy_client(client)
    finally:
        peer.close()
        proc = _finish(child)
    stamps = _stamps(raw)
    recv = np.array([r for r, _ in raw], np.int64)
    sent_a = np.array(sent, np.int64)
    applied: dict[int, dict] = {}
    for _, c in configs:
        if c.get("applies_from_stamp_ns") is not None:
            applied[c["config_id"]] = c
    models = {i: model_from_config(c).arm for i, c in applied.items()}
    # correctness: every output against the model in force at its stamp, at the exact state
    # (a warm-up sample, the first and the first after an estimator reset by a stamp gap
    # when this process was stalled, has acceleration 0: counted, checked as such)
    wrong, warmup, worst = 0, 0, 0.0
    for k, (_, b) in enumerate(raw):
        m = deserialize_message(b, JointState)
        model = models[config_in_force(configs, int(stamps[k]))["config_id"]]
        q, qd = state((stamps[k] - t0) * 1e-9)
        err = float(np.abs(np.asarray(m.effort) - model.inverse_dynamics(q, qd, acc)).max())
        if err > 1e-9:
            err = float(np.abs(np.asarray(m.effort) - model.inverse_dynamics(q, qd, 0 * acc)).max())
            warmup += err <= 1e-9
        worst = max(worst, err)
        wrong += err > 1e-9
    switches = []
    in_switch = np.zeros(len(stamps), bool)
    in_switch_1s = np.zeros(len(stamps), bool)
    in_build = np.zeros(len(stamps), bool)  # stamped while the worker thread was building
    for (wall, params, fut), cid in zip(asked, sorted(i for i in applied if i > 1), strict=False):
        ok = fut.done() and fut.result().result.successful
        first = applied[cid]["applies_from_stamp_ns"]
        switches.append({"params": params, "accepted": bool(ok), "config_id": cid,
                         "request_to_first_new_sample_ms": (first - wall) / 1e6,
                         "build_ms": applied[cid]["build_ms"]})
        in_switch |= (stamps >= wall) & (stamps <= first + SWITCH_WINDOW_MS * MS)
        in_build |= (stamps >= wall) & (stamps < first)
        in_switch_1s |= (stamps >= wall) & (stamps <= wall + 1000 * MS)
    latency = (recv - stamps) * 1e-6
    settled = stamps >= sent_a[0] + 1000 * MS
    steady = percentiles(latency[settled & ~in_switch])
    during = percentiles(latency[in_switch])
    steady_1s = percentiles(latency[settled & ~in_switch_1s])
    during_1s = percentiles(latency[in_switch_1s])
    return {
        "input_rate_hz": 1000.0, "samples": len(sent), "switch_every_s": 2.0,
        "received": len(stamps), "lost": len(np.setdiff1d(sent_a, stamps)),
        "repeated": int(len(stamps) - len(np.unique(stamps))),
        "wrong_model": int(wrong), "warmup": int(warmup), "worst_error_nm": worst,
        "switches": switches,
        "request_to_first_new_sample_ms": percentiles([s["request_to_first_new_sample_ms"]
                                                       for s in switches]),
        "build_ms": percentiles([s["build_ms"] for s in switches]),
        "switch_window_ms": SWITCH_WINDOW_MS,
        "latency_ms": {"steady": steady, "switch": during,
                       "request_to_first_new_sample": percentiles(latency[in_build])},
        "latency_p99_ratio": during.get("p99", float("nan")) / steady.get("p99", float("nan")),
        "latency_ms_1s_window": {"steady": steady_1s, "switch": during_1s},
        "latency_p99_ratio_1s_window": (during_1s.get("p99", float("nan"))
                                        / steady_1s.get("p99", float("nan"))),
        "node": proc,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="fixed-rate run (s)")
    ap.add_argument("--switch-seconds", type=float, default=20.0, help="1 kHz replay with switches (s)")
    ap.add_argument("--parts", default="rate,switch")
    env_domain = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    ap.add_argument("--domain", type=int, default=env_domain or 79)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results.json"))
    args = ap.parse_args(argv)
    lease = claim_domain_arg(ap, args.domain, "torque_node_rate")  # held until this process exits
    args.domain = lease.domain
    parts = set(args.parts.split(","))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_DOMAIN_ID"] = str(args.domain)
    # The feeder thread shares this process with the spinning one: hand the GIL over often.
    sys.setswitchinterval(1e-4)
    started = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    machine = {**machine_info(), "loadavg_start": loadavg()}
    work = Path(tempfile.mkdtemp(prefix="torque_node_rate_"))
    new: dict = {}
    try:
        if "rate" in parts:
            new["output_rate"] = r = measure_rate(args.domain, work, args.seconds)
            print(f"output_rate_hz {RATE_HZ:g} from 100 Hz: {r['rate_hz']:.1f} Hz "
                  f"({100 * r['rate_error_fraction']:+.2f} %), interval p50/p99/max "
                  f"{r['interval_ms']['p50']:.3f}/{r['interval_ms']['p99']:.3f}/"
                  f"{r['interval_ms']['max']:.3f} ms, repeated stamps {r['repeated_stamps']}, "
                  f"repeated values {r['repeated_values']}, {r['outputs_after_last_input']} "
                  f"after the last input; node CPU {r['node_cpu_percent'] or float('nan'):.0f} % of a core",
                  flush=True)
        if "switch" in parts:
            new["live_switch"] = s = measure_switch(args.domain, work, args.switch_seconds)
            lat = s["latency_ms"]
            print(f"live switch at 1 kHz: lost {s['lost']}, wrong model {s['wrong_model']} "
                  f"(worst {s['worst_error_nm']:.1e} N·m), latency p99 steady/switch "
                  f"{lat['steady'].get('p99', float('nan')):.3f}/{lat['switch'].get('p99', float('nan')):.3f}"
                  f" ms (ratio {s['latency_p99_ratio']:.2f}; 1 s windows "
                  f"{s['latency_p99_ratio_1s_window']:.2f}), max while building "
                  f"{lat['request_to_first_new_sample'].get('max', float('nan')):.3f} ms, "
                  "request -> first new sample "
                  + ", ".join(f"{x['request_to_first_new_sample_ms']:.1f}" for x in s["switches"])
                  + " ms, build " + ", ".join(f"{x['build_ms']:.1f}" for x in s["switches"]) + " ms",
                  flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    machine["loadavg_end"] = loadavg()
    print(f"load average start {machine['loadavg_start']}, end {machine['loadavg_end']} "
          f"({machine['cores']} cores)")
    for sec in new.values():
        sec["machine"] = machine
    save_sections(args.out, new, "benchmarks/torque_node_rate.py", argv, started)
    bad = [k for k, sec in new.items() for key in ("lost", "repeated", "wrong_model",
                                                    "repeated_stamps", "repeated_values")
           if sec.get(key)]
    bad += [k for k, sec in new.items() if sec["node"]["exit_code"] != 0 or sec["node"]["traceback"]]
    if bad:
        print(f"DATA: lost, repeated or wrong samples (or a node failed) in {sorted(set(bad))}")
        return DATA
    return OK


if __name__ == "__main__":
    sys.exit(main())
