"""A torque_node killed (SIGKILL) and restarted, again and again: does each new one serve?

    python benchmarks/restart_after_kill.py [--cycles 40] [--transport default|UDPv4|SHM]
                                            [--domain 93]

trajectory_publisher loops at 1 kHz into torque_node (backward estimator, depth 10000); a
peer in this process counts joint_torques. Each cycle waits (a hang guard of WAIT_S) for
500 new torques, then kills the node and starts another. Prints each cycle and the count
of restarted nodes that served nothing within WAIT_S (numbers, not pass/fail: exit 0).
`--transport` sets FASTDDS_BUILTIN_TRANSPORTS for the child processes (default: Fast DDS's
own, shared memory and UDPv4). Why it exists: docs/reliability.md (a restarted node that
comes back matched but deaf). Run it beside load to see that (e.g. a second make test).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from forearm_dynamics.nodes.common import stream_qos  # noqa: E402
from forearm_dynamics.nodes.peer import Peer  # noqa: E402
from forearm_dynamics.processes import Child, claim_domain, ros_env  # noqa: E402

WAIT_S = 60.0
NEW = 500
NODE_ARGS = ["-p", "estimator:=backward", "-p", "qos_depth:=10000"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=40)
    ap.add_argument("--transport", default="default", choices=("default", "UDPv4", "SHM"))
    ap.add_argument("--domain", type=int, default=93)
    args = ap.parse_args(argv)
    from sensor_msgs.msg import JointState

    lease = claim_domain(args.domain, "restart_after_kill")
    logs = Path(tempfile.mkdtemp(prefix="restart_after_kill_"))
    extra = {} if args.transport == "default" else {"FASTDDS_BUILTIN_TRANSPORTS": args.transport}
    env = ros_env(lease.domain, logs, extra)
    os.environ.update({k: v for k, v in env.items() if k.startswith("ROS_")})
    peer = Peer("restart_watch", lease.domain)
    got = [0]
    peer.node.create_subscription(JointState, "joint_torques",
                                  lambda _raw: got.__setitem__(0, got[0] + 1),
                                  stream_qos(10000), raw=True)
    node = Child.script("torque_node", NODE_ARGS, env, logs)
    pub = Child.script("trajectory_publisher", ["-p", "movements:=[1, 28, 53]", "-p", "loop:=true",
                                                "-p", "min_subscribers:=2"], env, logs)
    deaf = []
    try:
        for cycle in range(args.cycles + 1):  # cycle 0: the first node; then each restart
            start = got[0]
            served = peer.spin_until(lambda start=start: got[0] >= start + NEW, WAIT_S)
            print(f"node {cycle} ({'first' if cycle == 0 else 'restarted'}): "
                  f"{got[0] - start} torques{'' if served else f' in {WAIT_S:g} s: DEAF'}",
                  flush=True)
            if not served:
                deaf.append(cycle)
            if cycle == args.cycles:
                break
            node.proc.send_signal(signal.SIGKILL)
            node.proc.wait(10)
            peer.spin_for(1.0)
            node = Child.script("torque_node", NODE_ARGS, env, logs)
    finally:
        node.stop()
        pub.stop()
        peer.close()
        lease.release()
    print(f"transport {args.transport}: {len(deaf)} of {args.cycles} restarted nodes served "
          f"nothing in {WAIT_S:g} s (nodes {deaf}); logs in {logs}; load average "
          f"{os.getloadavg()[0]:.1f} (2 cores)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
