"""How many samples a best-effort reader keeps while its node is busy: `python -m benchmarks.reader_depth`.

Why: muscle_node's input (best effort) must hold the backlog of a CPU stall; its depth is only
worth what the middleware keeps. A writer sends N JointStates to a reader of history depth D
that is not spun (a node busy elsewhere); then the reader is spun and counts what it got.
Fast DDS caps a reader at its default resource limit (max_samples 5000) whatever the depth.

    python -m benchmarks.reader_depth [--depth 10000] [--send 8000] [--domain 97]
"""

from __future__ import annotations

import argparse
import json
import os
import time

from forearm_dynamics.processes import claim_domain


def run(depth: int, send: int) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from forearm_dynamics.nodes.common import stream_qos

    rclpy.init()
    try:
        writer, reader = Node("reader_depth_writer"), Node("reader_depth_reader")
        got = []
        reader.create_subscription(JointState, "reader_depth_probe", lambda _data: got.append(1),
                                   stream_qos(depth, False), raw=True)
        pub = writer.create_publisher(JointState, "reader_depth_probe", stream_qos(depth, True))
        deadline = time.monotonic() + 30  # hang guard for discovery
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        msg = JointState(name=[f"j{i}" for i in range(20)], position=[0.0] * 20,
                         velocity=[0.0] * 20, effort=[0.0] * 20)
        for i in range(send):
            pub.publish(msg)
            if i % 500 == 499:
                time.sleep(0.01)  # the transport delivers; the reader is not spun
        time.sleep(1.0)
        ex = SingleThreadedExecutor()
        ex.add_node(reader)
        end = time.monotonic() + 5
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        return {"depth": depth, "sent": send, "received": len(got),
                "rmw": os.environ.get("RMW_IMPLEMENTATION") or "default (rmw_fastrtps_cpp)",
                "loadavg": os.getloadavg()}
    finally:
        rclpy.shutdown()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--depth", type=int, default=10000)
    ap.add_argument("--send", type=int, default=8000)
    ap.add_argument("--domain", type=int, default=97)
    args = ap.parse_args(argv)
    lease = claim_domain(args.domain, "benchmarks.reader_depth")
    os.environ["ROS_DOMAIN_ID"] = str(lease.domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    print(json.dumps(run(args.depth, args.send)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
