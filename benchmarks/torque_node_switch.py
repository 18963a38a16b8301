"""torque_node's subscription callback cost, steady and across live model changes.

In one process (no DDS between the samples and the node: what is measured is the node's
own callback, publish() included, with no subscriber): N pre-serialised JointState
samples 1 ms apart are fed to the raw callback one after another; every SWITCH_EVERY
samples a live change (body_size 50 <-> 95, then model segmented <-> solid) is requested
through rclpy's set_parameters, exactly as the parameter service would. Reports the
callback p50/p99/max in steady state and in the 50 samples after each request, the model
build time (worker thread) and how many samples after the request the new model was in use.

    python benchmarks/torque_node_switch.py [--samples 20000]

Run it with PYTHONPATH pointing at another checkout to compare the steady-state cost
(the switch part is skipped where live changes are refused).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from forearm_dynamics.processes import claim_domain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--switch-every", type=int, default=2000)
    args = ap.parse_args()
    lease = claim_domain(int(os.environ.get("ROS_DOMAIN_ID") or 83), "torque_node_switch")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # nothing leaves this machine
    os.environ["ROS_DOMAIN_ID"] = str(lease.domain)

    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    from forearm_dynamics.description import JOINT_NAMES
    from forearm_dynamics.nodes.torque_node import TorqueNode

    rclpy.init()
    node = TorqueNode()
    rng = np.random.default_rng(3)
    t0 = time.time_ns() - args.samples * 1_000_000  # live-looking stamps, all in the past
    msgs = []
    for k in range(args.samples):
        m = JointState()
        m.name = list(JOINT_NAMES)
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(t0 + k * 1_000_000, 1_000_000_000)
        m.position = rng.uniform(-0.5, 0.5, 20).tolist()
        m.velocity = rng.uniform(-1, 1, 20).tolist()
        msgs.append(serialize_message(m))
    switches = [{"body_size": 95}, {"body_size": 50}, {"model": "solid"}, {"model": "segmented"}]
    cost = np.zeros(args.samples, np.int64)
    near = np.zeros(args.samples, bool)
    asked: list[tuple[int, int]] = []  # (sample index, config id expected)
    live = True
    ids = np.zeros(args.samples, np.int64)
    cb = node._on_joint_state
    for k, data in enumerate(msgs):
        if live and k and k % args.switch_every == 0:
            change = switches[(k // args.switch_every - 1) % len(switches)]
            res = node.set_parameters([Parameter(n, value=x) for n, x in change.items()])
            if not all(r.successful for r in res):
                live = False  # a checkout without live changes: steady state only
            else:
                asked.append((k, None))
                near[k:k + 50] = True
        t = time.perf_counter_ns()
        cb(data)
        cost[k] = time.perf_counter_ns() - t
        if live and hasattr(node, "live"):
            ids[k] = node.live.in_use.config_id
        time.sleep(0.0002)  # a node sleeps between samples; so does this one
    warm = slice(1000, None)
    steady = cost[warm][~near[warm]] / 1e3
    print(f"callback (us) steady p50/p99/max: {np.percentile(steady, 50):.1f}/"
          f"{np.percentile(steady, 99):.1f}/{steady.max():.1f} over {steady.size} samples")
    if asked and hasattr(node, "live"):
        during = cost[near] / 1e3
        print(f"callback (us) in the 50 samples after each of {len(asked)} live changes "
              f"p50/p99/max: {np.percentile(during, 50):.1f}/{np.percentile(during, 99):.1f}/"
              f"{during.max():.1f}")
        lag = [int(np.argmax(ids[k:] != ids[k - 1])) for k, _ in asked]
        print(f"live changes applied: {node.live.counts()['applied']}, last build "
              f"{node.live.in_use.build_ms:.2f} ms (worker thread); the new model was in use "
              f"{lag} samples after each request (samples 0.2 ms apart in wall time here)")
    node._worker.stop() if hasattr(node, "_worker") else None
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
