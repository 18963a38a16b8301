"""A controller-style subscriber: read the torque stream, watch its stamps and rate, print
every joint's torque once a second.

    python examples/torque_listener.py [--seconds N]   # Ctrl-C to stop

What a prosthesis controller downstream of torque_node should check before trusting a
torque: the stamps increase (an equal or older stamp is a replay or a restart), the stream
keeps its rate (a gap means samples are missing or late), and the age of each message
(receive time - header stamp, when the publisher stamps with the same clock).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState


class TorqueListener:
    def __init__(self, node, topic: str = "joint_torques", expected_hz: float = 1000.0):
        self.node = node
        self.period_ns = 1e9 / expected_hz
        # reliable with 1 s of depth: a late callback finds its messages still queued
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.sub = node.create_subscription(JointState, topic, self.on_torques, qos)
        self.total = self.count = self.out_of_order = self.gaps = 0
        self.last_stamp = None
        self.last: JointState | None = None
        self.ages_ms: list[float] = []
        node.create_timer(1.0, self.report)

    def on_torques(self, msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self.last_stamp is not None:
            if stamp <= self.last_stamp:
                self.out_of_order += 1  # a restart or a replayed bag: reset your own filters
            elif stamp - self.last_stamp > 2.5 * self.period_ns:
                self.gaps += 1  # samples missing, or the publisher paused
        self.last_stamp = stamp
        self.ages_ms.append((time.time_ns() - stamp) / 1e6)
        self.count += 1
        self.total += 1
        self.last = msg

    def report(self) -> None:
        if self.last is None:
            print(f"waiting for {self.sub.topic_name} ({self.sub.get_publisher_count()} "
                  "publisher(s) matched)", flush=True)
            return
        age = np.percentile(self.ages_ms, [50, 99]) if self.ages_ms else (float("nan"),) * 2
        print(f"{self.count} msgs in the last second, {self.total} in all; stamps: "
              f"{self.out_of_order} out of order, {self.gaps} gaps; age p50 {age[0]:.2f} ms, "
              f"p99 {age[1]:.2f} ms", flush=True)
        self.print_last()
        self.count, self.ages_ms = 0, []

    def print_last(self) -> None:
        """Every joint's torque in the newest message, in its name order."""
        if self.last is not None:
            print("  " + ", ".join(f"{n} {t:+.4f}" for n, t in
                                   zip(self.last.name, self.last.effort, strict=True)) + " (N·m)",
                  flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=0.0, help="stop after this long (0: never)")
    ap.add_argument("--topic", default="joint_torques")
    args = ap.parse_args(argv)
    rclpy.init()
    node = rclpy.create_node("torque_listener")
    listener = TorqueListener(node, args.topic)
    executor = EventsExecutor()
    executor.add_node(node)
    end = time.monotonic() + args.seconds if args.seconds > 0 else float("inf")
    try:
        while rclpy.ok() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        print(f"received {listener.total} joint_torques; stamps out of order "
              f"{listener.out_of_order}, gaps {listener.gaps}; the last:", flush=True)
        listener.print_last()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
