"""Load generator for the recorder bench: N JointState topics at a stepped rate.

    python -m benchmarks.loadgen --prefix /bench/rec --topics 4 \
        --steps 1000:20,2000:5,4000:5 [--stop-below 0.9]

Every message is the pipeline's JointState (20 names, position, velocity, effort: 1 kB of
CDR), serialised once and published raw, so the generator costs little; header.stamp
carries (sec = step index, nanosec = sequence number within the step) so the reader of the
bag can count what arrived per topic and step. Each step publishes rate_hz per topic for
duration s on a 1 ms schedule (every sample that is due goes out: a late wake-up is caught
up, not skipped), waits until the recorder acknowledged everything (reliable, depth 1000)
and pauses --pause s (1 s). A step that reaches less than --stop-below of its target rate
ends the ramp (the generator, not the recorder, is then the limit). The last stdout line is
`LOADGEN <json>`: per step the target, the achieved rate and the count sent per topic.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from forearm_dynamics.description import JOINT_NAMES
from forearm_dynamics.exit_codes import DATA, OK
from forearm_dynamics.nodes.common import stream_qos


def template() -> bytearray:
    msg = JointState()
    msg.header.frame_id = "bench"
    msg.name = list(JOINT_NAMES)
    n = len(JOINT_NAMES)
    msg.position = [0.1] * n
    msg.velocity = [0.2] * n
    msg.effort = [0.3] * n
    return bytearray(serialize_message(msg))


def parse_steps(text: str) -> list[tuple[float, float]]:
    steps = []
    for part in text.split(","):
        rate, _, duration = part.partition(":")
        steps.append((float(rate), float(duration)))
    return steps


def run_step(pubs, buf: bytearray, step: int, rate: float, duration: float) -> dict:
    pack = struct.Struct("<iI").pack_into
    period_ns = 1e9 / rate
    total = round(rate * duration)
    sent = 0
    t0 = time.monotonic_ns()
    while sent < total:
        due = min(total, int((time.monotonic_ns() - t0) / period_ns) + 1)
        while sent < due:
            pack(buf, 4, step, sent)
            data = bytes(buf)
            for p in pubs:
                p.publish(data)
            sent += 1
        next_ns = t0 + sent * period_ns
        wait = (next_ns - time.monotonic_ns()) / 1e9
        if wait > 0:
            time.sleep(min(wait, 0.001))
    span = (time.monotonic_ns() - t0) / 1e9
    acked = all(p.wait_for_all_acked(Duration(seconds=10)) for p in pubs)
    return {"step": step, "target_hz_per_topic": rate, "duration_s": duration,
            "sent_per_topic": sent, "span_s": span,
            "achieved_msgs_per_s": sent * len(pubs) / span if span > 0 else None,
            "achieved_fraction": (sent / span) / rate if span > 0 else None, "acked": acked}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.loadgen")
    ap.add_argument("--prefix", default="/bench/rec")
    ap.add_argument("--topics", type=int, default=4)
    ap.add_argument("--steps", default="1000:20")
    ap.add_argument("--stop-below", type=float, default=0.9)
    ap.add_argument("--wait", type=float, default=30.0, help="s to wait for the recorder")
    ap.add_argument("--pause", type=float, default=1.0, help="s of silence before and between steps")
    args, ros_args = ap.parse_known_args(argv)
    rclpy.init(args=ros_args)
    node = rclpy.create_node("bench_loadgen")
    try:
        pubs = [node.create_publisher(JointState, f"{args.prefix}{i}", stream_qos(1000))
                for i in range(args.topics)]
        deadline = time.monotonic() + args.wait
        while any(p.get_subscription_count() == 0 for p in pubs):
            if time.monotonic() > deadline:
                print("LOADGEN " + json.dumps({"error": "no subscriber"}), flush=True)
                return DATA
            time.sleep(0.05)
        time.sleep(args.pause)  # discovery settles both ways
        buf = template()
        steps = []
        for i, (rate, duration) in enumerate(parse_steps(args.steps)):
            r = run_step(pubs, buf, i, rate, duration)
            steps.append(r)
            print(f"step {i}: {rate:g} Hz x {args.topics} topics, achieved "
                  f"{r['achieved_msgs_per_s']:.0f} msgs/s", flush=True)
            if r["achieved_fraction"] is None or r["achieved_fraction"] < args.stop_below:
                break
            time.sleep(args.pause)
        print("LOADGEN " + json.dumps({"topics": [p.topic_name for p in pubs], "steps": steps}),
              flush=True)
        return OK
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
