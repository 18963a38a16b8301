"""The one torque_node harness: a real torque_node process and an rclpy peer on its domain
that feeds it JointStates and collects its torques and diagnostics."""

from __future__ import annotations

import time

import numpy as np
import rosproc
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from forearm_dynamics.nodes.common import stream_qos

from .jointstate import joint_state, stamp_of

MS = 1_000_000  # ns


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

    def get(self, key: str, default: int = 0) -> int:
        return int(self.values.get(key, default))

    def fresh(self, pred=lambda d: True, timeout: float = rosproc.STARTUP_S) -> dict[str, str]:
        """The first values published from now on that satisfy pred. timeout is a hang guard:
        a node catching up a backlog on a loaded machine published none for over 10 s (a
        restarted node 2.8 s behind, load 10)."""
        start = self.count
        ok = self._peer.spin_until(lambda: self.count > start and pred(self.values), timeout)
        assert ok, f"diagnostics never satisfied the check: {self.values}"
        return dict(self.values)


class TorqueHarness:
    """A torque_node process (started through `procs`, so it is killed at teardown whatever
    happens) and a peer that feeds it and listens, on `domain` (None: the session's).

    The backward estimator unless node_args say otherwise: its outputs are exactly known, so
    the pipeline can be checked to 1e-8 (the estimators themselves: test_estimation.py).
    `follow_wall_clock`: stamp() never falls behind the wall clock (for nodes or tests that
    judge stamps against it); else stamps advance by exactly the step asked for, whatever
    the machine's speed (a loaded machine's pause is then never a stamp gap).
    """

    def __init__(self, procs: rosproc.Procs, *node_args: str, domain: int | None = None,
                 reply_depth: int = 1000, peer_name: str = "torque_test",
                 follow_wall_clock: bool = False, posture=None):
        self.domain = rosproc.domain_id() if domain is None else domain
        self.follow_wall_clock = follow_wall_clock
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
        self._connect(np.zeros(20) if posture is None else np.asarray(posture, float))

    def _connect(self, posture: np.ndarray) -> None:
        """Send static samples until one is answered: discovery is complete both ways."""
        ok = self.peer.spin_until(lambda: self.pub.get_subscription_count() > 0, 30)
        assert ok, self.proc.output()
        deadline = time.monotonic() + 30
        while not self.replies:
            assert time.monotonic() < deadline and self.proc.running(), self.proc.output()
            self.pub.publish(joint_state(self.stamp(), posture, np.zeros(20)))
            self.peer.spin_for(0.1)
        # then one more 1 ms after the last one sent (not wall-clock spaced, as the samples
        # above are with follow_wall_clock): the node knows the stream's interval (1 ms), as a
        # real stream gives it. Else a test's first pause is the stream's first step (or 5 x a
        # ~0.1 s connect step), which the stamp rule lets continue (estimation/stamps.py).
        self.t_ns += MS  # 1 ms after the last sent (after discovery: received, in order)
        self.pub.publish(joint_state(self.t_ns, posture, np.zeros(20)))
        ok = self.peer.spin_until(lambda: any(stamp_of(r) == self.t_ns for r in self.replies), 30)
        assert ok, self.proc.output()

    def stamp(self, dt_ns: int = MS) -> int:
        """The next stamp: dt after the previous one (and never behind the wall clock if
        follow_wall_clock)."""
        self.t_ns += dt_ns
        if self.follow_wall_clock:
            self.t_ns = max(self.t_ns, time.time_ns())
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
