"""Shared pieces of the fault suite (test_faults_*.py): private DDS domains, the suite's
defaults for the shared JointState builder and torque_node harness (test/support/), a child
JointState feeder, what a bag holds.

Every process is started with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a domain of
its test's own (102..139: rosproc uses 1..101, test_bag_recorder 140..229), and stopped
by its own PID only.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import rosproc
from rosproc import Procs
from sensor_msgs.msg import JointState
from support.jointstate import cdr_stamp, stamp_of
from support.jointstate import joint_state as _joint_state
from support.torque_harness import Diagnostics
from support.torque_harness import TorqueHarness as _TorqueHarness

from forearm_dynamics import JOINT_NAMES, build_model

__all__ = [  # the shared pieces are re-exported: the fault suite imports them from here
    "GRAVITY", "MODEL", "MS", "POSTURE", "SIGNALS", "Diagnostics", "Procs", "TorqueHarness",
    "cdr_stamp", "check_torque_stream", "joint_series", "joint_state", "private_domain",
    "recorded", "stamp_of", "start_feeder",
]

MS = 1_000_000  # ns
MODEL = build_model("segmented", 50)
POSTURE = np.random.default_rng(11).uniform(-0.4, 0.7, 20)
GRAVITY = MODEL.gravity_torques(POSTURE)


def private_domain() -> int:
    """A ROS domain for one test (102..139), never 0, held by no other test or session."""
    return rosproc.test_domain(102, 139)


def recorded(path: Path, topic: str, after_ns: int = 0) -> int:
    """Messages on topic logged after after_ns in the recording at path, also while it is
    being written (its closed chunks are read as a truncated file is); 0 while unreadable.

    A recorder may match a writer that joined the graph only at Fast DDS's next participant
    announcement (~3 s, later on a loaded machine): tests wait on this, not on a fixed time."""
    from forearm_dynamics.bag import open_bag
    from forearm_dynamics.errors import BagError

    try:
        return sum(m.log_time > after_ns for _ch, m in open_bag(path).messages([topic]))
    except BagError:
        return 0


def joint_state(t_ns: int, q=POSTURE, qd=None, names=JOINT_NAMES, effort=None) -> JointState:
    """support.jointstate.joint_state with the fault suite's defaults: its posture, at rest."""
    return _joint_state(t_ns, q, np.zeros(len(names)) if qd is None else qd, effort, names=names)


class TorqueHarness(_TorqueHarness):
    """support.torque_harness.TorqueHarness on a private domain, fed at the suite's posture,
    stamps never behind the wall clock."""

    def __init__(self, procs: Procs, *node_args: str, reply_depth: int = 20000,
                 peer_name: str = "fault_peer"):
        super().__init__(procs, *node_args, domain=private_domain(), reply_depth=reply_depth,
                         peer_name=peer_name, follow_wall_clock=True, posture=POSTURE)


# -- a JointState feeder in its own process (the test's peer only listens) -----------------
FEEDER = r"""
import json, sys, time
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState

cfg = json.loads(sys.argv[1])
rclpy.init()
node = rclpy.create_node("fault_feeder")
pub = node.create_publisher(JointState, cfg.get("topic", "joint_states"),
                            QoSProfile(depth=cfg.get("depth", 1000)))
burst, answered = cfg.get("burst", 0), set()
if burst:  # pace by the answers: wait for the last one of a burst before the next burst
    import struct
    unpack = struct.Struct("<iI").unpack_from
    def on_answer(raw):
        sec, nsec = unpack(raw, 4)
        answered.add(sec * 10**9 + nsec)
    node.create_subscription(JointState, cfg["answers_topic"], on_answer,
                             QoSProfile(depth=cfg.get("depth", 1000)), raw=True)
deadline = time.monotonic() + 30
while (pub.get_subscription_count() < cfg.get("subscribers", 1)
       or (burst and node.count_publishers(cfg["answers_topic"]) < 1)) and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
time.sleep(cfg.get("settle", 1.0))  # let the reliable matches settle on both sides
n = len(cfg["position"])
msg = JointState(name=cfg["names"], position=cfg["position"], velocity=cfg["velocity"])
rate, count, step = cfg["rate_hz"], cfg["count"], cfg.get("step_ns", 0)
stamps = []
t_first = time.time_ns()
print("publishing", flush=True)
start = burst_start = time.perf_counter()
k0 = 0
for k in range(count):
    if burst and k and k % burst == 0:
        wait_until = time.monotonic() + 120
        while stamps[-1] not in answered and time.monotonic() < wait_until:
            rclpy.spin_once(node, timeout_sec=0.01)
        burst_start, k0 = time.perf_counter(), k
    if rate > 0:
        target = burst_start + (k - k0) / rate
        while (now := time.perf_counter()) < target:
            if target - now > 0.0003:
                time.sleep(target - now - 0.0002)
    ns = t_first + k * step if step else time.time_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
    pub.publish(msg)
    stamps.append(ns)
elapsed = time.perf_counter() - start
with open(cfg["out"], "w") as fh:
    fh.write("\n".join(map(str, stamps)))
if burst:  # every answer this feeder received (it paces by them, so it keeps up)
    wait_until = time.monotonic() + 30
    while stamps[-1] not in answered and time.monotonic() < wait_until:
        rclpy.spin_once(node, timeout_sec=0.01)
    with open(cfg["out"] + ".answers", "w") as fh:
        fh.write("\n".join(map(str, sorted(answered))))
print("published", len(stamps), f"{elapsed:.3f}", flush=True)
# every sample acknowledged by every reader before this process (and its writer's repairs)
# goes; `drain` is a hang guard (120 s for the 10 000-sample bursts: with 5 s, on a loaded
# machine, the writer went with samples unrepaired and the burst test never got its last answer)
acked = pub.wait_for_all_acked(Duration(seconds=cfg.get("drain", 5.0)))
print("all acknowledged" if acked else "NOT all acknowledged by the readers", flush=True)
node.destroy_node()
rclpy.shutdown()
"""


def start_feeder(procs: Procs, tmp: Path, domain: int, *, count: int, rate_hz: float,
                 names=JOINT_NAMES, position=POSTURE, velocity=None, step_ns: int = 0,
                 depth: int = 1000, name: str = "feeder", burst: int = 0,
                 answers_topic: str = "joint_torques", drain: float = 5.0,
                 ) -> tuple[subprocess.Popen, Path, Path]:
    """Publish `count` JointStates at rate_hz (0 = as fast as possible); stamps go to a file.

    `burst` > 0: after every `burst` samples, wait until the last one is answered on
    `answers_topic` (a busy machine then slows the feed instead of overflowing queues).
    `drain`: at most this long (s) for every reader to acknowledge every sample before the
    feeder exits; its log says "all acknowledged" or not."""
    import json

    out = tmp / f"{name}_stamps.txt"
    cfg = {"names": list(names), "position": [float(x) for x in position],
           "velocity": [0.0] * len(names) if velocity is None else [float(x) for x in velocity],
           "rate_hz": rate_hz, "count": count, "step_ns": step_ns, "depth": depth, "out": str(out),
           "burst": burst, "answers_topic": answers_topic, "drain": drain}
    feeder = procs.add(rosproc.NodeProcess(name, [sys.executable, "-c", FEEDER, json.dumps(cfg)],
                                           rosproc.ros_env(domain), tmp))
    return feeder.proc, out, feeder.log








SIGNALS = {"SIGKILL": signal.SIGKILL, "SIGTERM": signal.SIGTERM, "SIGINT": signal.SIGINT}


# -- what a bag holds -------------------------------------------------------------------------
def joint_series(bag, topic: str) -> dict[str, np.ndarray]:
    """stamp, log time, position, velocity, effort (model order) of a JointState topic."""
    from rclpy.serialization import deserialize_message

    rows = {"stamp": [], "log": [], "position": [], "velocity": [], "effort": []}
    for _ch, m in bag.messages([topic]):
        js = deserialize_message(m.data, JointState)
        rows["stamp"].append(stamp_of(js))
        rows["log"].append(m.log_time)
        for f in ("position", "velocity", "effort"):
            vals = np.asarray(getattr(js, f), float)
            rows[f].append(vals if len(vals) == 20 else np.full(20, np.nan))
    out = {k: np.array(rows[k], dtype=np.int64) for k in ("stamp", "log")}
    for f in ("position", "velocity", "effort"):
        out[f] = np.array(rows[f], dtype=float).reshape(len(rows[f]), 20)
    return out


def check_torque_stream(series: dict[str, np.ndarray], max_gap_ns: int = 100 * MS,
                        prev: tuple[int, np.ndarray] | None = None) -> int:
    """Every recorded torque is exactly what torque_node (backward estimator) must compute
    from the sample it carries and the one before it: qdd = backward difference of velocity
    over the stamps, 0 after a pause (warm-up). A pause is the node's adaptive stamp gap
    (its default; estimation/stamps.py): longer than 0.1 s AND 5 x the previous step (a
    stalled publisher's slow samples are not pauses). `prev` (stamp, velocity): the sample the node
    answered before the first one of the series (its answer not in the series), else the
    first is a warm-up. Returns the number of warm-up samples."""
    from forearm_dynamics.estimation.stamps import CONTINUE, StampRule

    t, pos, vel, eff = series["stamp"], series["position"], series["velocity"], series["effort"]
    assert len(t) and np.all(np.diff(t) > 0), "torques out of order or repeated"
    if prev is not None:  # the sample before, for the first difference only
        t, vel = np.concatenate([[prev[0]], t]), np.vstack([prev[1], vel])
    qdd = np.zeros_like(vel)
    dt = np.diff(t)
    cont = np.empty(len(dt), bool)
    rule = StampRule(0.0 if max_gap_ns == 100 * MS else max_gap_ns * 1e-9)  # the node's
    for k, d in enumerate(dt.tolist()):
        cont[k] = rule.step(d) == CONTINUE
    step = (vel[1:] - vel[:-1]) * (1.0 / (dt * 1e-9))[:, None]
    qdd[1:][cont] = step[cont]
    if prev is not None:
        t, vel, qdd = t[1:], vel[1:], qdd[1:]
        cont = cont[1:]
    expected = MODEL.inverse_dynamics(pos, vel, qdd)
    err = np.abs(eff - expected).max(axis=1)
    bad = np.flatnonzero(~(err < 1e-8))
    assert not len(bad), (f"{len(bad)} torques differ from the model, first at stamp {t[bad[0]]}: "
                          f"{err[bad[0]]}")
    return int((~cont).sum()) + 1
