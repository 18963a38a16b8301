"""Shared pieces of the fault suite (test_faults_*.py): private DDS domains, process
bookkeeping, a torque_node harness, a child JointState feeder, CDR stamp peeking.

Every process is started with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a domain of
its test's own (102..139: rosproc uses 1..101, test_bag_recorder 140..229), and stopped
by its own PID only.
"""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rosproc
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.nodes.common import stream_qos

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


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def cdr_stamp(raw: bytes) -> int:
    """header.stamp of a serialized stamped message (4-byte CDR encapsulation, then sec, nanosec)."""
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nsec


def joint_state(t_ns: int, q=POSTURE, qd=None, names=JOINT_NAMES, effort=None) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
    msg.header.frame_id = "humerus"
    msg.name = list(names)
    msg.position = [float(x) for x in q]
    msg.velocity = [0.0] * len(msg.name) if qd is None else [float(x) for x in qd]
    msg.effort = [] if effort is None else [float(x) for x in effort]
    return msg


class Procs:
    """Every process a test starts; all killed (by PID) at teardown, even on failure."""

    def __init__(self):
        self.items: list = []

    def add(self, p):
        self.items.append(p)
        return p

    def start(self, executable: str, *ros_args: str, domain: int) -> rosproc.NodeProcess:
        return self.add(rosproc.start(executable, *ros_args, domain=domain))

    def close(self) -> None:
        for p in self.items:
            proc = getattr(p, "proc", p)
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)


class Diagnostics:
    """The latest /diagnostics values of one node, and how many arrived."""

    def __init__(self, peer: rosproc.Peer, prefix: str):
        self.values: dict[str, str] = {}
        self.count = 0
        self._prefix = prefix
        self._peer = peer
        peer.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 10)

    def _on(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(self._prefix):
                self.values = {kv.key: kv.value for kv in status.values}
                self.count += 1

    def get(self, key: str) -> int:
        return int(self.values.get(key, 0))

    def fresh(self, pred=lambda d: True, timeout: float = 10.0) -> dict[str, str]:
        """The first values published from now on that satisfy pred."""
        start = self.count
        ok = self._peer.spin_until(lambda: self.count > start and pred(self.values), timeout)
        assert ok, f"diagnostics never satisfied the check: {self.values}"
        return dict(self.values)


class TorqueHarness:
    """A torque_node process on a private domain, and a peer that feeds it and listens."""

    def __init__(self, procs: Procs, *node_args: str, reply_depth: int = 20000,
                 peer_name: str = "fault_peer"):
        self.domain = private_domain()
        # the backward estimator: its outputs are exactly known, so "the next good sample is
        # exact" can be checked to 1e-8 (the default estimator: test_torque_node.py)
        self.proc = procs.start("torque_node", "-p", "diagnostics_period:=0.2",
                                "-p", "estimator:=backward", *node_args, domain=self.domain)
        self.peer = rosproc.Peer(peer_name, domain=self.domain)
        node = self.peer.node
        self.pub = node.create_publisher(JointState, "joint_states", stream_qos(1000))
        self.replies: list[JointState] = []
        node.create_subscription(JointState, "joint_torques", self.replies.append,
                                 stream_qos(reply_depth))
        self.diag = Diagnostics(self.peer, "torque_node")
        self.t_ns = (time.time_ns() // MS) * MS
        ok = self.peer.spin_until(lambda: self.pub.get_subscription_count() > 0, 30)
        assert ok, self.proc.output()
        deadline = time.monotonic() + 30
        while not self.replies:  # discovery complete both ways
            assert time.monotonic() < deadline and self.proc.running(), self.proc.output()
            self.pub.publish(joint_state(self.stamp()))
            self.peer.spin_for(0.1)

    def stamp(self, dt_ns: int = MS) -> int:
        """The next stamp: dt after the previous one, and never behind the wall clock."""
        self.t_ns = max(self.t_ns + dt_ns, time.time_ns())
        return self.t_ns

    def exchange(self, msgs: list[JointState], last: int | None = None, timeout: float = 15.0):
        """Publish msgs; every reply up to the one answering stamp `last` (default: the last msg's)."""
        self.peer.spin_for(0.0)
        self.replies.clear()
        for m in msgs:
            self.pub.publish(m)
        last = stamp_of(msgs[-1]) if last is None else last
        ok = self.peer.spin_until(lambda: any(stamp_of(r) == last for r in self.replies), timeout)
        assert ok, f"no reply to stamp {last}\n{self.proc.output()[-3000:]}"
        return list(self.replies)

    def log_since(self, mark: int) -> str:
        return self.proc.output()[mark:]

    def close(self) -> None:
        self.peer.close()


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
pub.wait_for_all_acked(Duration(seconds=cfg.get("drain", 5.0)))
node.destroy_node()
rclpy.shutdown()
"""


def start_feeder(procs: Procs, tmp: Path, domain: int, *, count: int, rate_hz: float,
                 names=JOINT_NAMES, position=POSTURE, velocity=None, step_ns: int = 0,
                 depth: int = 1000, name: str = "feeder", burst: int = 0,
                 answers_topic: str = "joint_torques") -> tuple[subprocess.Popen, Path, Path]:
    """Publish `count` JointStates at rate_hz (0 = as fast as possible); stamps go to a file.

    `burst` > 0: after every `burst` samples, wait until the last one is answered on
    `answers_topic` (a busy machine then slows the feed instead of overflowing queues)."""
    import json

    out = tmp / f"{name}_stamps.txt"
    cfg = {"names": list(names), "position": [float(x) for x in position],
           "velocity": [0.0] * len(names) if velocity is None else [float(x) for x in velocity],
           "rate_hz": rate_hz, "count": count, "step_ns": step_ns, "depth": depth, "out": str(out),
           "burst": burst, "answers_topic": answers_topic}
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
    (its default): longer than max_gap_ns AND GAP_PERIODS x the previous interval (a stalled
    publisher's slow samples are not pauses). `prev` (stamp, velocity): the sample the node
    answered before the first one of the series (its answer not in the series), else the
    first is a warm-up. Returns the number of warm-up samples."""
    from forearm_dynamics.nodes.stream_node import GAP_PERIODS

    t, pos, vel, eff = series["stamp"], series["position"], series["velocity"], series["effort"]
    assert len(t) and np.all(np.diff(t) > 0), "torques out of order or repeated"
    if prev is not None:  # the sample before, for the first difference only
        t, vel = np.concatenate([[prev[0]], t]), np.vstack([prev[1], vel])
    qdd = np.zeros_like(vel)
    dt = np.diff(t)
    cont = np.empty(len(dt), bool)
    last_dt = 0
    for k, d in enumerate(dt.tolist()):
        cont[k] = d <= max(max_gap_ns, GAP_PERIODS * last_dt)
        last_dt = d if cont[k] else 0
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
