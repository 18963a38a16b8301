"""Torque path: the movement replay at 1 kHz through a real node process, timed at a receiver.

One variant = three (or four) processes on loopback DDS in the bench's domain:

    trajectory_publisher --joint_states--> <node under test> --joint_torques--> receiver
                                                       (bag_recorder too, if asked)

The node under test is torque_node or null_echo_node (same subscription, QoS, validation
and message build, no dynamics), so their ratio is the cost of our node against pure rclpy
overhead measured in the same run. Figures per variant:

- latency: receive time of joint_torques at the receiver (system clock) - its header stamp
  (= the stamp the publisher put on the joint_states it answers; taken just before the
  sample is evaluated and published), one-way, ms;
- rate: received messages / (last - first receive time); loss: samples the publisher sent
  (its own count) that never came back (unique stamps);
- callback: the node's own compute time (callback entry -> publish() returned), from its
  /diagnostics: per-period p50/p99 (1 s periods); reported as the median over the periods
  of the replay and the worst period; `publish_p50/p99`: the part spent in publish()
  (the DDS write), `own_p50/p99`: the rest (per sample: callback - publish);
- CPU % of one core: utime + stime of the node process (/proc/<pid>/stat) between the
  first and the last receive; peak RSS: VmHWM (/proc/<pid>/status); RSS at the first and
  last sample of the replay (growth over the run).
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.procstat import Sampler
from forearm_dynamics.movements import get_movement
from forearm_dynamics.processes import Child, ros_env

from . import module_env
from .stats import percentiles, serving_period

NODE_READY = "joint_torques ("  # stream_node logs "<in> -> <out> (depth ..., executor)"
STALL_GAP_MS = 100.0  # a receive gap this long counts as a delivery stall


@dataclass
class Variant:
    """One configuration of the torque path."""

    name: str
    node: str = "torque_node"  # console script: torque_node | null_echo_node
    node_args: list[str] = field(default_factory=list)  # extra -p name:=value pairs
    env: dict[str, str] = field(default_factory=dict)  # e.g. Fast DDS transport profile
    recorder: bool = False  # run bag_recorder on the default topics as well
    best_effort: bool = False  # receiver QoS (must match the node's output QoS)
    pin: bool = False  # node alone on the last CPU, every other process on the others
    also_input: bool = False  # the receiver also times joint_states (locates a delay's hop)
    others_fifo: int = 0  # SCHED_FIFO priority of publisher, receiver, recorder (0: normal)
    pub_args: list[str] = field(default_factory=list)  # extra trajectory_publisher -p pairs
    also_topic: str = ""  # ... or this topic (e.g. joint_torques_std: its delivery is reported)
    viewer: bool = False  # run arm_viz (markers from joint_torques) as well

    def cpus(self) -> tuple[set[int] | None, set[int] | None]:
        """(node CPUs, other processes' CPUs) for a pinned variant; (None, None) if not."""
        allowed = sorted(os.sched_getaffinity(0))
        if not self.pin:
            return None, None
        if len(allowed) < 2:
            raise RuntimeError("pinning needs at least 2 CPUs")
        return {allowed[-1]}, set(allowed[:-1])


#: s to wait after the stream for the node's /diagnostics of a period in which it answered
DIAG_WAIT_S = 15.0


def _expected(movements: list[int]) -> int:
    return sum(max(1, round(get_movement(i).duration * 1000.0)) for i in movements)


def _sent_by_publisher(text: str) -> tuple[int | None, int | None]:
    m = re.search(r"done: (\d+) samples, (\d+) skipped", text)
    return (int(m.group(1)), int(m.group(2))) if m else (None, None)


def _callback_stats(diag: list[dict], t0: float) -> dict:
    """Median over the 1 s periods of the node's own percentiles: the periods received from
    the first answer (t0) on in which the node answered (it has no other input; a period
    that ends after the stream still holds it, however late its message came)."""
    rows = [d["values"] for d in diag if t0 <= d["t"] and serving_period(d["values"])]
    if not rows:
        return {"periods": 0}
    p50 = np.array([float(r["compute_us_p50"]) for r in rows])
    p99 = np.array([float(r["compute_us_p99"]) for r in rows])
    cmax = np.array([float(r["compute_us_max"]) for r in rows])
    out = {"periods": len(rows), "p50": float(np.median(p50)), "p99": float(np.median(p99)),
           "p99_worst_period": float(p99.max()), "max": float(cmax.max())}
    if all("publish_us_p50" in r for r in rows):  # the DDS write's share of the callback
        out["publish_p50"] = float(np.median([float(r["publish_us_p50"]) for r in rows]))
        out["publish_p99"] = float(np.median([float(r["publish_us_p99"]) for r in rows]))
    if all("own_us_p50" in r for r in rows):  # the callback without the DDS write
        out["own_p50"] = float(np.median([float(r["own_us_p50"]) for r in rows]))
        out["own_p99"] = float(np.median([float(r["own_us_p99"]) for r in rows]))
    return out


def run_variant(v: Variant, movements: list[int], domain: int, work: Path,
                start_delay: float = 5.0, timeout_pad: float = 60.0) -> dict:
    """Replay `movements` through variant `v`; the figures listed in the module docstring."""
    logs = work / v.name
    logs.mkdir(parents=True, exist_ok=True)
    env = ros_env(domain, logs, v.env)
    rx_path = logs / "rx.npz"
    children: list[Child] = []
    node_cpus, other_cpus = v.cpus()
    result: dict = {"node": v.node, "movements": len(movements), "node_args": v.node_args,
                    "env": v.env, "with_recorder": v.recorder,
                    "node_cpus": sorted(node_cpus) if node_cpus else None}
    try:
        node = Child.script(v.node, ["-p", "diagnostics_period:=1.0", *v.node_args], env, logs,
                            cpus=node_cpus)
        children.append(node)
        rx_args = ["--topic", "joint_torques", "--out", str(rx_path), "--diag-prefix", v.node]
        if v.best_effort:
            rx_args.append("--best-effort")
        if v.also_input or v.also_topic:
            rx_args += ["--also", v.also_topic or "joint_states"]
        rx = Child.module("receiver", "benchmarks.receiver", rx_args, module_env(env), logs,
                          cpus=other_cpus, fifo=v.others_fifo)
        children.append(rx)
        subscribers = 1
        if v.recorder:
            bag = logs / "run.mcap"
            children.append(Child.script("bag_recorder", ["-p", f"output:={bag}"], env, logs,
                                         cpus=other_cpus, fifo=v.others_fifo))
            subscribers = 2
        viewer = None
        if v.viewer:
            viewer = Child.script("arm_viz", [], env, logs, cpus=other_cpus)
            children.append(viewer)
        if not node.wait_for(NODE_READY, 60):
            raise RuntimeError(f"{v.node} did not start:\n{node.text()[-2000:]}")
        if not rx.wait_for("receiver: matched", 60):
            raise RuntimeError(f"receiver never matched {v.node}:\n{rx.text()[-2000:]}")
        if viewer is not None and not viewer.wait_for("arm_viz: joint_torques ->", 60):
            raise RuntimeError(f"arm_viz did not start:\n{viewer.text()[-2000:]}")
        with Sampler({"node": node.pid, "receiver": rx.pid}) as sampler:
            for c in children[2:]:
                sampler.add(c.name, c.pid)
            pub_args = ["-p", f"movements:={movements}", "-p", f"start_delay:={start_delay}",
                        "-p", f"min_subscribers:={subscribers}", "-p", "subscriber_timeout:=60.0"]
            if v.best_effort:
                pub_args += ["-p", "qos_reliable:=false"]
            pub_args += v.pub_args
            pub_started = time.time()
            pub = Child.script("trajectory_publisher", pub_args, env, logs, cpus=other_cpus,
                               fifo=v.others_fifo)
            children.append(pub)
            sampler.add("publisher", pub.pid)
            duration = 1.5 * len(movements)
            code = pub.wait(start_delay + duration * 3 + timeout_pad)
            if code != 0:
                raise RuntimeError(f"trajectory_publisher exited {code}:\n{pub.text()[-2000:]}")
            time.sleep(0.5)  # the last answers in flight
            # the node's /diagnostics period that holds the stream's end comes up to 1 s after
            # it, later on a loaded machine (a quick run beside a second suite stopped before
            # any serving period arrived: callback figures of 0 periods)
            rx.wait_for("receiver: serving period", DIAG_WAIT_S)
            sampler.sample()
        codes = {c.name: c.stop() for c in reversed(children)}
    finally:
        for c in children:
            c.stop()
    sent, skipped = _sent_by_publisher(pub.text())
    data = np.load(rx_path)
    recv, stamp = data["recv_ns"], data["stamp_ns"]
    diag = json.loads(rx_path.with_suffix(".diag.json").read_text())
    expected = _expected(movements)
    result.update(_figures(recv, stamp, sent if sent is not None else expected, sampler, diag,
                           pub_started))
    result.update({"expected": expected, "sent": sent, "skipped_by_publisher": skipped,
                   "exit_codes": codes})
    if v.also_topic:  # its delivery: every torque stamp answered there too
        also = np.unique(data["also_stamp_ns"])
        result["also"] = {"topic": v.also_topic, "received": int(data["also_stamp_ns"].size),
                          "unique": int(also.size),
                          "missing_vs_torques": int(np.setdiff1d(np.unique(stamp), also).size)}
    return result


def _figures(recv: np.ndarray, stamp: np.ndarray, sent: int, sampler: Sampler,
             diag: list[dict], pub_started: float) -> dict:
    n = int(recv.size)
    unique = int(np.unique(stamp).size)
    out: dict = {"received": n, "unique": unique, "duplicates": n - unique,
                 "lost": max(sent - unique, 0),
                 "loss_fraction": max(sent - unique, 0) / sent if sent else None}
    if n < 2:
        return out
    t0, t1 = recv[0] / 1e9, recv[-1] / 1e9
    lat_ms = (recv - stamp) / 1e6
    gaps_ms = np.diff(recv) / 1e6
    worst = int(np.argmax(lat_ms))
    out.update({
        "rate_hz": (n - 1) / (t1 - t0),
        "input_rate_hz": (unique - 1) / ((stamp.max() - stamp.min()) / 1e9),
        "replay_s": t1 - t0,
        "latency_ms": percentiles(lat_ms),
        "first_latency_ms": float(lat_ms[0]),  # a delivery stall at stream start shows here
        "latency_worst_at_s": float(recv[worst] / 1e9 - pub_started),  # after publisher start
        "receive_gap_ms_max": float(gaps_ms.max()),
        "stalls_over_100ms": int((gaps_ms > STALL_GAP_MS).sum()),
        "late_over_1ms_fraction": float((lat_ms > 1.0).mean()),
        "callback_us": _callback_stats(diag, t0),
        "foreign_cpu_percent": sampler.foreign_cpu_percent(t0, t1),
    })
    for name, s in sampler.series.items():
        rss = s.rss_between(t0, t1)
        out[f"{name}_process"] = {
            "cpu_percent": s.cpu_percent(t0, t1),
            "peak_rss_mb": (s.peak_hwm_kb() or 0) / 1024,
            "rss_start_mb": rss[0] / 1024 if rss else None,
            "rss_end_mb": rss[-1] / 1024 if rss else None,
        }
    return out
