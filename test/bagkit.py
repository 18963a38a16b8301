"""Synthetic bags for the replay tests: JointState streams with known stamps and log times."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from rclpy.serialization import serialize_message
from rosproc import _LOG_DIR, BIN, NodeProcess, ros_env
from std_msgs.msg import String
from support.jointstate import joint_state_bytes

from forearm_dynamics.bag import BagWriter, TopicQos
from forearm_dynamics.processes import lease_domain

#: A namespace of this test session: other sessions on the machine may share the ROS domain
#: (rosproc.domain_id() is derived from the pid), never this namespace.
NS = f"/replay_test_{os.getpid()}"

#: The ROS domain of the replay tests: 230..232, which no other test file uses (rosproc
#: 1..101, faultkit 102..139, test_bag_recorder 140..229), leased for the session. Sessions
#: of other test files on the same domain were seen to stall these 1 kHz streams (joint runs
#: of the suite on this shared machine), even in other namespaces.
_LEASE = lease_domain(230, 232)  # held for the session
DOMAIN = _LEASE.domain

MS = 1_000_000
T0 = 1_700_000_000_000_000_000


def joint_state(stamp_ns: int, q, qd=None, effort=None) -> bytes:
    """A bag's JointState payload (support.jointstate)."""
    return joint_state_bytes(stamp_ns, q, qd, effort)


def smooth_motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q, qd (N, 20): every joint a different slow sine, inside its range."""
    j = np.arange(20)
    w = 2 * np.pi * (0.3 + 0.05 * j)
    q = 0.3 + 0.25 * np.sin(np.outer(t, w) + j)
    qd = 0.25 * w * np.cos(np.outer(t, w) + j)
    return q, qd


def write_stream_bag(path: Path, n: int, *, period_ns: int = MS, t0_ns: int = T0,
                     latency_ns: int = 300_000, jitter_ns: int = 0, gap_after: int | None = None,
                     gap_ns: int = 0, extra_topic: bool = False, seed: int = 3, ns: str = "",
                     chunk_size: int = 1024 * 1024) -> dict:
    """joint_states at 1/period with log time = stamp + latency (+ jitter); optionally a
    silent gap after sample `gap_after`, and a best-effort header-less `status` String
    topic every 10th sample, all under namespace `ns`. Returns what was written."""
    rng = np.random.default_rng(seed)
    stamps = t0_ns + np.arange(n, dtype=np.int64) * period_ns
    if gap_after is not None:
        stamps[gap_after + 1:] += gap_ns
    logs = stamps + latency_ns + (rng.integers(0, jitter_ns, n) if jitter_ns else 0)
    q, qd = smooth_motion((stamps - t0_ns) / 1e9)
    payloads, status = [], []
    with BagWriter(path, chunk_size=chunk_size, flush_period_s=3600) as w:
        js = w.add_topic(f"{ns}/joint_states", "sensor_msgs/msg/JointState", TopicQos(depth=1000))
        st = w.add_topic(f"{ns}/status", "std_msgs/msg/String",
                         TopicQos(depth=10, reliability="best_effort")) if extra_topic else None
        for k in range(n):
            data = joint_state(int(stamps[k]), q[k], qd[k])
            payloads.append(data)
            w.write(js, data, int(logs[k]))
            if st is not None and k % 10 == 0:
                s = serialize_message(String(data=f"sample {k}"))
                status.append(s)
                w.write(st, s, int(logs[k]) + 1000)
    return {"stamps": stamps, "logs": logs, "payloads": payloads, "status": status, "q": q, "qd": qd}


def start_player(bag, *ros_args: str) -> NodeProcess:
    """`bag_player BAG --ros-args ...` (the bag path comes before --ros-args), as rosproc.start,
    on the replay tests' DOMAIN."""
    args = [str(BIN / "bag_player"), str(bag), "--ros-args", *ros_args]
    return NodeProcess("bag_player", args, ros_env(DOMAIN), Path(_LOG_DIR), split_stderr=True)
