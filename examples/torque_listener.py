"""A controller-style subscriber: read the torque stream, watch its stamps and rate, print
every joint's torque once a second.

    python examples/torque_listener.py [--seconds N] [--expected-hz HZ]   # Ctrl-C to stop

What a prosthesis controller downstream of torque_node should check before trusting a
torque: the stamps increase (an equal or older stamp is a replay or a restart), the stream
keeps its rate (a gap means samples are missing or late), and the age of each message
(receive time - header stamp, when the publisher stamps with the same clock).

The rate is the stream's own (the median of its recent stamp steps; torque_node answers
each input, so a 100 Hz sensor gives 100 Hz torques), unless --expected-hz says it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import deque

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState


class StampWatch:
    """Counts stamps out of order and gaps: a step over GAP x the stream's period, which is
    `expected_hz`'s, or (0) the median of the last WINDOW steps once MIN_STEPS are seen."""

    GAP, WINDOW, MIN_STEPS = 2.5, 101, 10

    def __init__(self, expected_hz: float = 0.0):
        self.fixed_period_ns = 1e9 / expected_hz if expected_hz > 0 else None
        self.steps: deque[int] = deque(maxlen=self.WINDOW)
        self.last_stamp: int | None = None
        self.out_of_order = self.gaps = 0

    def period_ns(self) -> float | None:
        if self.fixed_period_ns is not None:
            return self.fixed_period_ns
        return float(np.median(self.steps)) if len(self.steps) >= self.MIN_STEPS else None

    def add(self, stamp: int) -> None:
        if self.last_stamp is not None:
            step = stamp - self.last_stamp
            if step <= 0:
                self.out_of_order += 1  # a restart or a replayed bag: reset your own filters
            else:
                period = self.period_ns()
                if period is not None and step > self.GAP * period:
                    self.gaps += 1  # samples missing, or the publisher paused
                else:
                    self.steps.append(step)  # a gap does not stretch the period
        self.last_stamp = stamp


class TorqueListener:
    def __init__(self, node, topic: str = "joint_torques", expected_hz: float = 0.0):
        self.node = node
        self.watch = StampWatch(expected_hz)
        # reliable with 1 s of depth: a late callback finds its messages still queued
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.sub = node.create_subscription(JointState, topic, self.on_torques, qos)
        self.total = self.count = 0
        self.last: JointState | None = None
        self.ages_ms: list[float] = []
        node.create_timer(1.0, self.report)

    def on_torques(self, msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.watch.add(stamp)
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
              f"{self.watch.out_of_order} out of order, {self.watch.gaps} gaps; age p50 {age[0]:.2f} ms, "
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
    ap.add_argument("--expected-hz", type=float, default=0.0,
                    help="the stream's rate, for the gap count (0: learnt from its stamps)")
    args = ap.parse_args(argv)
    rclpy.init()
    node = rclpy.create_node("torque_listener")
    listener = TorqueListener(node, args.topic, args.expected_hz)
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
              f"{listener.watch.out_of_order}, gaps {listener.watch.gaps}; the last:", flush=True)
        listener.print_last()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
