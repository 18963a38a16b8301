"""A torque_node killed (SIGKILL) and restarted, again and again: does each new one serve?

    python benchmarks/restart_after_kill.py [--cycles 30] [--fresh-id] [--domain 93]

trajectory_publisher loops at 1 kHz into torque_node (backward estimator, depth 10000); a
peer in this process counts joint_torques. Each cycle waits (a hang guard of WAIT_S) for
500 new torques, then kills the node and starts another. Prints each cycle: the torques,
and how long after its launch a shared-memory data port of the domain was made (its mutex
file; nan: none, the new node took over a port it found); at the end, the count of
restarted nodes that served nothing within WAIT_S (numbers, not pass/fail: exit 0).

`--fresh-id`: before each restart a placeholder participant (a peer in this process, kept
to the end) takes the lowest free participant id, so the new node never gets the killed
one's id, nor its ports (at most 30 cycles: ids past 31 are beyond the localhost
discovery range). Why it exists: docs/reliability.md ("A restart that comes back deaf").
Run it beside load to see that (e.g. a second make test).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from forearm_dynamics.nodes.common import stream_qos  # noqa: E402
from forearm_dynamics.nodes.peer import Peer  # noqa: E402
from forearm_dynamics.processes import Child, claim_domain, ros_env, rtps_port  # noqa: E402

WAIT_S = 60.0
SHM_DIR = Path("/dev/shm")  # noqa: S108 - Fast DDS's files there, only read
NEW = 500
NODE_ARGS = ["-p", "estimator:=backward", "-p", "qos_depth:=10000"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=30)
    ap.add_argument("--fresh-id", action="store_true",
                    help="a placeholder participant takes the killed node's id first")
    ap.add_argument("--domain", type=int, default=93)
    args = ap.parse_args(argv)
    if args.fresh_id and args.cycles > 30:
        ap.error("--fresh-id: at most 30 cycles (participant ids past 31 are not discovered)")
    from sensor_msgs.msg import JointState

    lease = claim_domain(args.domain, "restart_after_kill")
    logs = Path(tempfile.mkdtemp(prefix="restart_after_kill_"))
    env = ros_env(lease.domain, logs)
    os.environ.update({k: v for k, v in env.items() if k.startswith("ROS_")})
    peer = Peer("restart_watch", lease.domain)
    got = [0]
    peer.node.create_subscription(JointState, "joint_torques",
                                  lambda _raw: got.__setitem__(0, got[0] + 1),
                                  stream_qos(10000), raw=True)
    node = Child.script("torque_node", NODE_ARGS, env, logs)
    pub = Child.script("trajectory_publisher", ["-p", "movements:=[1, 28, 53]", "-p", "loop:=true",
                                                "-p", "min_subscribers:=2"], env, logs)
    # restarts: (cycle, s from launch to the making of a data port), deaf or served
    deaf: list[tuple[int, float]] = []
    served: list[tuple[int, float]] = []
    placeholders: list[Peer] = []
    launched = time.time()
    try:
        for cycle in range(args.cycles + 1):  # cycle 0: the first node; then each restart
            start = got[0]
            heard = peer.spin_until(lambda start=start: got[0] >= start + NEW, WAIT_S)
            made = _data_port_made_after(lease.domain, launched)
            print(f"node {cycle} ({'first' if cycle == 0 else 'restarted'}): "
                  f"{got[0] - start} torques{'' if heard else f' in {WAIT_S:g} s: DEAF'}; "
                  f"a data port made {made:.1f} s after its launch", flush=True)
            if cycle > 0:
                (served if heard else deaf).append((cycle, round(made, 1)))
            if cycle == args.cycles:
                break
            node.proc.send_signal(signal.SIGKILL)
            node.proc.wait(10)
            if args.fresh_id:
                placeholders.append(Peer(f"placeholder_{cycle}", lease.domain))
            peer.spin_for(1.0)
            launched = time.time()
            node = Child.script("torque_node", NODE_ARGS, env, logs)
    finally:
        node.stop()
        pub.stop()
        for p in placeholders:
            p.close()
        peer.close()
        lease.release()
    made = [d for _, d in served if not math.isnan(d)]
    print(f"{'fresh ids' if args.fresh_id else 'ids as Fast DDS picks them'}: {len(deaf)} of "
          f"{args.cycles} restarted nodes served nothing in {WAIT_S:g} s ((node, s to its data "
          f"port) {deaf}); of those that served, {len(made)} made their data port "
          f"{min(made, default=math.nan):.1f}-{max(made, default=math.nan):.1f} s after launch "
          f"and {len(served) - len(made)} made none (took one over); logs in {logs}; load "
          f"average {os.getloadavg()[0]:.1f} (2 cores)")
    return 0


def _data_port_made_after(domain: int, t: float) -> float:
    """Seconds from `t` to the newest making of a user-data shared-memory port of this
    domain (Fast DDS names its mutex sem.fastrtps_port<N>_mutex in /dev/shm, N the
    participant's user-data port: processes.rtps_port); NaN if none was made after `t`. A
    participant makes its port as it starts, unless it takes over one it finds in use
    (every deaf restart measured did: docs/reliability.md)."""
    data_ports, newest = {rtps_port(domain, p, user=True) for p in range(32)}, float("nan")
    for path in SHM_DIR.glob("sem.fastrtps_port*_mutex"):
        port = int(path.name.removeprefix("sem.fastrtps_port").removesuffix("_mutex"))
        if port in data_ports:
            try:
                made = path.stat().st_ctime - t
            except FileNotFoundError:  # removed since the glob (a port closed)
                continue
            if made > 0 and not made <= newest:
                newest = made
    return newest


if __name__ == "__main__":
    sys.exit(main())
