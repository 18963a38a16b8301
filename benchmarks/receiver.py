"""Benchmark receiver: receive time and header stamp of every message on one stamped topic.

    python -m benchmarks.receiver --topic joint_torques --out rx.npz \
        [--diag-prefix torque_node] [--depth 1000] [--best-effort] [--also joint_states]

A raw subscription (the CDR bytes, no deserialisation): the callback reads the stamp at
bytes 4..12 (after the 4-byte encapsulation header, every std_msgs/Header-first message)
and the system clock, and appends both to array buffers, so the receiver costs the same
whichever node is measured. /diagnostics statuses whose name starts with --diag-prefix are
kept too (the node's own callback-time percentiles). Prints `receiver: matched` once a
publisher on --topic is matched; SIGINT/SIGTERM write --out (.npz: recv_ns, stamp_ns, and
also_recv_ns, also_stamp_ns for --also: a second stamped topic timed the same way, to
locate a delay between two hops) and --out with .diag.json (list of {t, values}), exit 0.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
import time
from array import array
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from forearm_dynamics.exit_codes import OK
from forearm_dynamics.nodes.common import make_executor, spin, stream_qos

from .stats import serving_period


def _timer(recv: array, stamps: array):
    """Raw callback appending (receive time, header stamp) of each message to two arrays."""
    unpack, now = struct.Struct("<iI").unpack_from, time.time_ns
    recv_append, stamp_append = recv.append, stamps.append

    def on_message(data: bytes) -> None:
        t = now()
        sec, nsec = unpack(data, 4)
        recv_append(t)
        stamp_append(sec * 1_000_000_000 + nsec)

    return on_message


class Receiver:
    def __init__(self, node, topic: str, depth: int, reliable: bool, diag_prefix: str,
                 also: str = ""):
        self.node = node
        self.recv_ns, self.stamp_ns = array("q"), array("q")
        self.also_recv_ns, self.also_stamp_ns = array("q"), array("q")
        self.diag: list[dict] = []
        self.serving = 0  # periods of self.diag in which the node answered
        self._prefix = diag_prefix
        self._matched = False
        self.sub = node.create_subscription(
            JointState, topic, _timer(self.recv_ns, self.stamp_ns), stream_qos(depth, reliable),
            raw=True)
        if also:
            node.create_subscription(JointState, also, _timer(self.also_recv_ns, self.also_stamp_ns),
                                     stream_qos(depth, reliable), raw=True)
        if diag_prefix:
            node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        node.create_timer(0.05, self._check_matched)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(self._prefix):
                values = {kv.key: kv.value for kv in status.values}
                self.diag.append({"t": time.time(), "name": status.name, "values": values})
                if serving_period(values):  # torque_path waits for this before it stops the run
                    self.serving += 1
                    print(f"receiver: serving period {self.serving}", flush=True)

    def _check_matched(self) -> None:
        if not self._matched and self.sub.get_publisher_count() > 0:
            self._matched = True
            print("receiver: matched", flush=True)

    def save(self, out: Path) -> None:
        np.savez(out, **{k: np.frombuffer(getattr(self, k), dtype=np.int64)
                         for k in ("recv_ns", "stamp_ns", "also_recv_ns", "also_stamp_ns")})
        out.with_suffix(".diag.json").write_text(json.dumps(self.diag))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="benchmarks.receiver")
    ap.add_argument("--topic", default="joint_torques")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--diag-prefix", default="")
    ap.add_argument("--depth", type=int, default=1000)
    ap.add_argument("--best-effort", action="store_true")
    ap.add_argument("--also", default="", help="a second stamped JointState topic to time")
    args, ros_args = ap.parse_known_args(argv)
    rclpy.init(args=ros_args)
    node = rclpy.create_node("bench_receiver")
    rx = Receiver(node, args.topic, args.depth, not args.best_effort, args.diag_prefix, args.also)
    try:
        spin(node, make_executor("events"))
    finally:
        rx.save(args.out)
        node.destroy_node()
        rclpy.try_shutdown()
    print(f"receiver: {len(rx.recv_ns)} messages", flush=True)
    return OK


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
