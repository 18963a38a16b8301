"""Benchmark: the one JointState reader (codec/jointstate.py) against rclpy's deserialiser.

    .venv/bin/python benchmarks/jointstate_reader.py [--samples 50000] [--repeats 5]

A synthetic 1 kHz joint_states bag (bagkit.write_stream_bag: 20 joints, positions and
velocities) is read into (N, 20) arrays three ways, each `--repeats` times, same process:
the codec's reader (CDR layout parsed once per shape, numpy views), the baseline
`rclpy.serialization.deserialize_message` per message with columns matched by name (what
check_bag's decoder did before the two readers were merged), and the container alone
(`Bag.messages`, no decoding), which bounds what any decoder can reach. Prints median and
max seconds and messages/s, the ratio to the baseline, and the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "test"))


def _rclpy_baseline(bag, topic: str, names: tuple[str, ...]) -> np.ndarray:
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    rows = []
    maps: dict[tuple[str, ...], np.ndarray] = {}
    for _ch, msg in bag.messages([topic]):
        m = deserialize_message(msg.data, JointState)
        key = tuple(m.name)
        idx = maps.get(key)
        if idx is None:
            pos = {n: i for i, n in enumerate(key)}
            idx = maps[key] = np.array([pos[n] for n in names])
        rows.append(np.frombuffer(m.position, np.float64)[idx])
    return np.array(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=50_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from bagkit import write_stream_bag

    from forearm_dynamics.bag import open_bag
    from forearm_dynamics.codec.jointstate import read_joint_series
    from forearm_dynamics.description import JOINT_NAMES

    src = Path(tempfile.mkdtemp(prefix="bench_jointstate_")) / "src.mcap"
    write_stream_bag(src, args.samples)
    bag = open_bag(src)
    topic = bag.info.find_topic("joint_states").topic
    ways = {
        "codec": lambda: read_joint_series(bag, topic, JOINT_NAMES).position,
        "rclpy_baseline": lambda: _rclpy_baseline(bag, topic, JOINT_NAMES),
        "container_only": lambda: sum(1 for _ in bag.messages([topic])),
    }
    load = os.getloadavg()
    times: dict[str, list[float]] = {k: [] for k in ways}
    results = {}
    for _ in range(args.repeats):
        for k, f in ways.items():
            t = time.perf_counter()
            results[k] = f()
            times[k].append(time.perf_counter() - t)
    if not np.array_equal(results["codec"], results["rclpy_baseline"]):
        print("the readers disagree", file=sys.stderr)
        return 1
    base = float(np.median(times["rclpy_baseline"]))
    print(f"{args.samples} messages, {args.repeats} repeats, load average {load[0]:.2f} "
          f"{load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs")
    for k, ts in times.items():
        med = float(np.median(ts))
        print(f"{k:15s} median {med:.3f} s  max {max(ts):.3f} s  {args.samples / med:>10,.0f} msg/s  "
              f"ratio to baseline {med / base:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
