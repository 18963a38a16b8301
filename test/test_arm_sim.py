"""arm_sim, the virtual arm, as a real process over real DDS (loopback, a leased domain).

Lockstep: every command is answered by exactly one step (one joint_states, one /clock,
stamps 1 ms apart), refused commands (NaN, unknown joint, too large) are counted and
logged once each and still advance their step with the last accepted torques, and the
trajectory is bit for bit the core's (ArmSimulator with the same commands). Real time:
with commands stopping, the torque goes to zero after command_timeout (said in the log and
/diagnostics) and comes back with the commands. A damping the solver cannot integrate
is refused at start-up with one line and exit code 2.
"""

from __future__ import annotations

import itertools
import json
import re
import signal
import time

import numpy as np
import pytest
import rosproc
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics.dynamics import build_model
from forearm_dynamics.nodes.common import latched_qos, stream_qos
from forearm_dynamics.simulation import ArmSimulator, SimSettings

pytestmark = pytest.mark.ros

MS = 1_000_000
_PEERS = itertools.count()
DRIVEN = ("wrist_flexion", "elbow_flexion", "pro_sup")  # named in this (not model) order


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def command(names, effort) -> JointState:
    msg = JointState()
    msg.name = list(names)
    msg.effort = [float(x) for x in effort]
    return msg


class Sim:
    """One arm_sim process and a peer that commands it and collects what it publishes."""

    def __init__(self, procs, *params: str):
        # a domain of its own: the module's lockstep node runs while the other tests run
        domain = rosproc.test_domain(102, 214)
        args = [a for p in ("diagnostics_period:=0.2", *params) for a in ("-p", p)]
        self.proc = procs.start("arm_sim", *args, domain=domain)  # killed even on failure
        self.peer = rosproc.Peer(f"arm_sim_test_{next(_PEERS)}", domain=domain)
        node = self.peer.node
        self.pub = node.create_publisher(JointState, "joint_commands", stream_qos(1000))
        self.states: list[JointState] = []
        self.clock: list[Clock] = []
        self.config: dict = {}
        self.diag: dict[str, str] = {}
        self.diag_message = ""
        self.diag_level = b"\x00"
        node.create_subscription(JointState, "joint_states", self.states.append, stream_qos(1000))
        node.create_subscription(Clock, "/clock", self.clock.append, 1000)
        node.create_subscription(String, "arm_sim/config", self._on_config, latched_qos())
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

    def connect(self) -> int:
        """Lockstep: zero commands until one is answered; returns how many were sent. Those
        sent before the node's reader matched this writer are lost (a writer can see a reader
        before the reader sees it: MatchLog's docstring); the answers to the others may still
        be on their way afterwards (see first_answer)."""
        self.wait(lambda: self.pub.get_subscription_count() > 0 and self.config,
                  what="discovery and config")
        zeros = 0
        while not self.states:
            self.pub.publish(command(DRIVEN, [0.0] * 3))
            zeros += 1
            self.peer.spin_for(0.1)
        self.peer.spin_for(0.5)
        return zeros

    def first_answer(self, start: int) -> int:
        """The index of the answer to the first command after connect(), in states[start:]:
        answers to connect's zero commands that came late (after its 0.5 s; a loaded machine
        gave 401 answers for 400 commands) come before it, the node taking commands in
        order, and have no torque; the caller's first command has some."""
        return next(i for i, m in enumerate(self.states[start:]) if any(m.effort))

    def _on_config(self, msg: String) -> None:
        self.config = json.loads(msg.data)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name.startswith("arm_sim"):
                self.diag = {kv.key: kv.value for kv in s.values}
                self.diag_message, self.diag_level = s.message, s.level

    def wait(self, pred, what: str = "", timeout: float = rosproc.STARTUP_S) -> None:
        """Until pred(); timeout is a hang guard (a loaded machine's answer may take seconds)."""
        ok = self.peer.spin_until(pred, timeout)
        assert ok, f"timed out waiting for {what}\n{self.proc.output()[-3000:]}"

    def close(self) -> str:
        self.peer.close()
        assert self.proc.stop(signal.SIGINT) == 0, self.proc.output()[-3000:]
        out = self.proc.output()
        assert "Traceback" not in out, out[-3000:]
        return out


@pytest.fixture(scope="module")
def lockstep(module_procs):
    s = Sim(module_procs, "lockstep:=true")
    yield s
    s.close()


def test_lockstep_one_step_per_command_bit_for_bit(lockstep) -> None:
    s = lockstep
    zeros = s.connect()
    cfg = s.config
    assert (cfg["model"], cfg["side"], cfg["lockstep"]) == ("segmented", "right", True)
    assert cfg["rate_hz"] == 1000.0
    sim_cfg = cfg["simulation"]
    assert sim_cfg["method"] == "rk4" and sim_cfg["dt"] == 1e-3 and sim_cfg["joint_limits"] is True
    assert set(sim_cfg["damping"].values()) == {1e-7}  # the documented default
    assert sim_cfg["limit_stiffness"]["elbow_flexion"] > 1000.0  # passive.py: ~4188 N·m/rad
    t0 = cfg["t0_ns"]
    k0 = (stamp_ns(s.states[-1]) - t0) // MS  # zero-torque steps taken so far
    assert (stamp_ns(s.states[-1]) - t0) % MS == 0
    n_before, c_before = len(s.states), len(s.clock)

    rng = np.random.default_rng(5)
    torques = rng.uniform(-0.3, 0.3, (400, 3))
    bad = {100: ("non_finite", command(DRIVEN, [0.0, float("nan"), 0.0])),
           150: ("unknown_joint", command(("elbow",), [1.0])),
           200: ("too_large", command(DRIVEN, [0.0, 1e7, 0.0])),
           250: ("no_effort", command(DRIVEN, []))}
    t_start = time.perf_counter()
    for k, tau in enumerate(torques):
        s.pub.publish(bad[k][1] if k in bad else command(DRIVEN, tau))
        want = n_before + k + 1
        s.wait(lambda want=want: len(s.states) >= want, f"the answer to command {k}")
    rate = len(torques) / (time.perf_counter() - t_start)
    late = s.first_answer(n_before)  # connect's answers that came late
    s.wait(lambda: len(s.states) >= n_before + late + len(torques), "the last answers")
    s.peer.spin_for(0.5)
    new = s.states[n_before + late:]
    assert len(new) == len(torques), "one joint_states per command, no more"
    # no more answers than connect commands (the initial state, stamp t0, answers none)
    assert sum(stamp_ns(m) > t0 for m in s.states[:n_before + late]) <= zeros
    assert len(s.clock) - c_before == late + len(torques)
    k0 += late
    stamps = np.array([stamp_ns(m) for m in new])
    assert np.all(stamps == t0 + (k0 + 1 + np.arange(len(torques))) * MS)
    clock = [c.clock.sec * 1_000_000_000 + c.clock.nanosec for c in s.clock[c_before + late:]]
    assert np.array_equal(np.array(clock), stamps)

    # the same run in the core: refused commands hold the last accepted torques
    arm = build_model("segmented", 50)
    sim = ArmSimulator(arm, SimSettings())
    for _ in range(k0):
        sim.step(np.zeros(20))
    idx = [arm.joint_names.index(n) for n in DRIVEN]
    held = np.zeros(20)
    for k, tau in enumerate(torques):
        if k not in bad:
            held = np.zeros(20)
            held[idx] = tau
        sim.step(held)
        m = new[k]
        assert np.array_equal(np.asarray(m.effort), held), k
        assert np.array_equal(np.asarray(m.position), sim.q), k
        assert np.array_equal(np.asarray(m.velocity), sim.qd), k
    s.wait(lambda: s.diag.get("commands_refused") == "4", "the refusals in /diagnostics")
    for reason, _ in bad.values():
        assert s.diag[f"refused.{reason}"] == "1"
    out = s.proc.output()
    for reason, _ in bad.values():
        assert len(re.findall(rf"command refused \({reason}\)", out)) == 1, out[-3000:]
    print(f"lockstep round trips through DDS (test peer, one at a time): {rate:.0f} steps/s")


def test_command_timeout_zeroes_the_torque(procs) -> None:
    s = Sim(procs, "command_timeout:=0.3")
    try:
        s.wait(lambda: s.pub.get_subscription_count() > 0 and len(s.states) > 10, what="states")
        push = command(("elbow_flexion",), [1.0])
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:  # ~100 Hz for 1 s
            s.pub.publish(push)
            s.peer.spin_for(0.01)
        assert any(m.effort[0] == 1.0 for m in s.states[-200:]), "the command is applied"
        s.wait(lambda: s.diag_level == DiagnosticStatus.WARN, "a WARN in /diagnostics")
        assert "zero torque" in s.diag_message
        s.peer.spin_for(0.3)
        tail = s.states[-100:]
        assert all(not any(m.effort) for m in tail), "zero torque after the timeout"
        # once timed out, zero torque for good: no 1.0 after the first zero
        efforts = np.array([m.effort[0] for m in s.states])
        last_push = int(np.flatnonzero(efforts == 1.0)[-1])
        assert np.all(efforts[last_push + 1:] == 0.0)
        found = re.findall(r"no command for (\d+\.\d+) s \(> command_timeout 0.3 s\): zero torque",
                           s.proc.output())
        assert found and float(found[-1]) >= 0.3, s.proc.output()[-2000:]
        n = len(s.states)
        for _ in range(20):  # commands back: applied again
            s.pub.publish(push)
            s.peer.spin_for(0.01)
        s.wait(lambda: any(m.effort[0] == 1.0 for m in s.states[n:]), "the torque back")
        assert "commands back" in s.proc.output()
    finally:
        s.close()


def test_unstable_damping_is_refused_with_one_line(procs) -> None:
    proc = procs.start("arm_sim", "-p", "damping:=0.01")
    code = proc.wait(30.0)
    out = proc.output()
    assert code == 2, out
    lines = [ln for ln in out.splitlines() if "invalid parameter" in ln]
    assert len(lines) == 1 and "'damping'" in lines[0] and "_dip_flexion" in lines[0], out
    assert "Traceback" not in out


def test_parameters_reach_the_simulation(procs) -> None:
    """Model parameters (torque_node's), initial_posture.<joint>, damping.<joint> and method
    are what the simulation runs with: 50 lockstep steps (after connect's zero-torque ones)
    equal the core's, bit for bit."""
    s = Sim(procs, "lockstep:=true", "model:=anatomical", "body_size:=95", "side:=left",
            "payload_mass:=0.5", "method:=semi_implicit_euler", "initial_posture.elbow_flexion:=1.0",
            "damping.elbow_flexion:=0.01", "joint_limits:=false")
    try:
        s.connect()  # a first command sent at once can be lost (see connect)
        assert s.config["model"] == "anatomical" and s.config["side"] == "left"
        assert s.config["simulation"]["damping"]["elbow_flexion"] == 0.01
        t0 = s.config["t0_ns"]
        n_before = len(s.states)
        torques = np.random.default_rng(2).uniform(-0.2, 0.2, (50, 3))
        for k, tau in enumerate(torques):
            s.pub.publish(command(DRIVEN, tau))
            s.wait(lambda k=k: len(s.states) >= n_before + k + 1, f"the answer to command {k}")
        late = s.first_answer(n_before)
        s.wait(lambda: len(s.states) >= n_before + late + len(torques), "the last answers")
        got = s.states[n_before + late:]
        k0 = (stamp_ns(got[0]) - t0) // MS - 1  # zero-torque steps before the first command
        arm = build_model("anatomical", 95, side="left", payload_mass=0.5)
        q0 = np.array(list(s.config["initial_posture"].values()))
        assert q0[0] == 1.0
        sim = ArmSimulator(arm, SimSettings(method="semi_implicit_euler", joint_limits=False,
                                            damping={"elbow_flexion": 0.01}), q0)
        for _ in range(k0):
            sim.step(np.zeros(20))
        assert [stamp_ns(m) for m in got] == [t0 + (k0 + k + 1) * MS for k in range(len(torques))]
        idx = [arm.joint_names.index(n) for n in DRIVEN]
        for k, tau in enumerate(torques):
            full = np.zeros(20)
            full[idx] = tau
            sim.step(full)
            assert np.array_equal(np.asarray(got[k].position), sim.q), k
    finally:
        s.close()
