"""Recorder bench: bag_recorder under N JointState topics at stepped rates, counted in the bag.

bag_recorder (its defaults: reliable, depth 1000, zstd chunks) records `topics` JointState
topics fed by benchmarks.loadgen. The steps are given per topic (Hz) with a duration each; the
first one is the nominal load (1 kHz x 4 topics) and gives the sustained figure. After the
recorder has closed the file, the bag is read back with the mcap library: per step, the
messages written (unique (topic, sequence) pairs), the drops (sent - written), and the
written rate (written / span of their log times). `max_rate_kept_up_msgs_per_s` is the
highest offered total rate with no drop, every message acknowledged and a written rate
within 2 % of the offered one; if the generator itself fell short of a step's target, the
figure is a lower bound (`generator_limited`: true).
"""

from __future__ import annotations

import json
import struct
import time
from collections import defaultdict
from pathlib import Path

from mcap.reader import make_reader

from benchmarks.procstat import Sampler
from forearm_dynamics.processes import Child, ros_env

from . import module_env

PREFIX = "/bench/rec"


def _bag_counts(path: Path) -> tuple[dict, dict]:
    """{(topic, step): set(seq)}, {step: [first, last] log time ns}."""
    seqs: dict[tuple[str, int], set[int]] = defaultdict(set)
    times: dict[int, list[int]] = {}
    unpack = struct.Struct("<iI").unpack_from
    with path.open("rb") as fh:
        for _schema, channel, message in make_reader(fh).iter_messages():
            if not channel.topic.startswith(PREFIX):
                continue
            step, seq = unpack(message.data, 4)
            seqs[(channel.topic, step)].add(seq)
            span = times.setdefault(step, [message.log_time, message.log_time])
            span[0] = min(span[0], message.log_time)
            span[1] = max(span[1], message.log_time)
    return seqs, times


def run(domain: int, work: Path, topics: int = 4,
        steps: tuple[tuple[float, float], ...] = ((1000, 20), (2000, 5), (4000, 5), (8000, 5)),
        env_extra: dict[str, str] | None = None, pause: float = 1.0) -> dict:
    logs = work / "recorder"
    logs.mkdir(parents=True, exist_ok=True)
    env = ros_env(domain, logs, env_extra)
    bag = logs / "load.mcap"
    names = [f"{PREFIX}{i}" for i in range(topics)]
    rec_topics = "[" + ", ".join(f"'{n}:sensor_msgs/msg/JointState'" for n in names) + "]"
    rec = Child.script("bag_recorder", ["-p", f"topics:={rec_topics}",
                                        "-p", "latched_topics:=['/bench/none']",
                                        "-p", f"output:={bag}"], env, logs)
    gen = None
    try:
        if not rec.wait_for("recording ", 60):
            raise RuntimeError(f"bag_recorder did not start:\n{rec.text()[-2000:]}")
        with Sampler({"recorder": rec.pid}) as sampler:
            steps_arg = ",".join(f"{r:g}:{d:g}" for r, d in steps)
            gen = Child.module("loadgen", "benchmarks.loadgen",
                               ["--prefix", PREFIX, "--topics", str(topics), "--steps", steps_arg,
                                "--pause", str(pause)],
                               module_env(env), logs)
            sampler.add("loadgen", gen.pid)
            total = sum(d for _, d in steps) + 3 * len(steps) + 60
            code = gen.wait(total)
            time.sleep(0.5)
            sampler.sample()
        if code != 0:
            raise RuntimeError(f"loadgen exited {code}:\n{gen.text()[-2000:]}")
        rec_code = rec.stop()
    finally:
        if gen is not None:
            gen.stop()
        rec.stop()
    line = next(x for x in reversed(gen.text().splitlines()) if x.startswith("LOADGEN "))
    sent = json.loads(line.removeprefix("LOADGEN "))
    seqs, times = _bag_counts(bag)
    out_steps = []
    for s in sent["steps"]:
        i = s["step"]
        written = sum(len(seqs.get((n, i), ())) for n in names)
        offered = s["sent_per_topic"] * topics
        t0, t1 = times.get(i, (0, 0))
        span = (t1 - t0) / 1e9
        written_rate = (written - 1) / span if span > 0 else None
        t_from, t_to = t0 / 1e9, t1 / 1e9
        rec_series = sampler.series["recorder"]
        out_steps.append({
            "target_msgs_per_s": s["target_hz_per_topic"] * topics,
            "offered_msgs_per_s": s["achieved_msgs_per_s"],
            "generator_fraction": s["achieved_fraction"],
            "sent": offered, "written": written, "dropped": offered - written,
            "written_msgs_per_s": written_rate, "acked": s["acked"],
            "recorder_cpu_percent": rec_series.cpu_percent(t_from, t_to),
        })
    nominal = out_steps[0]
    kept = [s for s in out_steps if s["dropped"] == 0 and s["acked"] and s["written_msgs_per_s"]
            and s["written_msgs_per_s"] >= 0.98 * s["offered_msgs_per_s"]]
    limited = any(s["generator_fraction"] < 0.95 for s in out_steps)
    all_kept = len(kept) == len(out_steps)
    rec_series = sampler.series["recorder"]
    return {
        "topics": topics,
        "bag_bytes": bag.stat().st_size,
        "sustained_msgs_per_s": nominal["written_msgs_per_s"],
        "nominal_target_msgs_per_s": nominal["target_msgs_per_s"],
        "nominal_dropped": nominal["dropped"],
        "max_rate_kept_up_msgs_per_s": max((s["offered_msgs_per_s"] for s in kept), default=0.0),
        "max_rate_is_lower_bound": all_kept,
        "generator_limited": limited,
        "recorder_peak_rss_mb": (rec_series.peak_hwm_kb() or 0) / 1024,
        "steps": out_steps,
        "exit_code": rec_code,
    }
