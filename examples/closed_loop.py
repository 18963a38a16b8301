"""Closed loop through ROS: a computed-torque controller drives the virtual arm (arm_sim).

    python examples/closed_loop.py --movements 1,26,51 [--lockstep] [--out DIR] [--plot]

Starts three nodes as child processes (loopback DDS, its own ROS domain, stopped by PID):
  trajectory_publisher  the reference motion: library movements at 1 kHz on
                        reference/joint_states (0.3 s of silence between movements)
  torque_node           the feed-forward: inverse dynamics of the reference, on
                        reference/joint_torques (with the reference q, qd it used;
                        estimator backward: exact input)
  arm_sim               the virtual arm at 1 kHz from the first movement's start posture
and runs the controller here:

    tau = tau_ff + g(q) - g(q_ref) + M(q) [w^2 (q_ref - q) + 2 zeta w (qd_ref - qd)]

with the newest reference message (q_ref, qd_ref, tau_ff) and the newest arm_sim state
(q, qd); M(q) the model's mass matrix (Pinocchio's CRBA), g the gravity torques, zeta = 1,
w = 2 pi x 2 Hz (real time) or 5 Hz (lockstep): every joint gets the same critically
damped error dynamics whatever its inertia (the elbow's is ~1e5 x a fingertip's), the
finger chains decoupled. Why each part (measured, this example's first versions):
- a PD scaled per joint by its effective inertia (diagonal) left the fingers coupled and
  missed finger movements by 0.1-0.8 rad;
- without g(q) - g(q_ref) the gravity torque is the reference posture's: a fingertip's
  gravity stiffness (~5e-4 N·m/rad) is as large as its 5 Hz PD stiffness (M w^2), so
  after the jump between two movements' postures the fingers settled 0.6 rad off;
- 5 Hz in real time went unstable after arm_sim stalls on the loaded machine (a stall is a
  burst of steps under one held command: tens of ms of loop delay; 2 cores at load 12);
  2 Hz has the phase margin. In lockstep the delay is always one step, and 5 Hz settles
  the jump between two movements within their 0.5 s hold (2 Hz left 0.05 rad there).
Before the first reference sample the controller holds the first start posture with its
gravity torques (the core's ArmModel.gravity_torques: what torque_node answers at rest).

Modes. Real time (default): arm_sim steps on its own timer; one command per state it
publishes. --lockstep: arm_sim steps once per command and publishes /clock, which
trajectory_publisher and torque_node run on (use_sim_time): the controller steps when the
reference of the current simulated time has come (or at once in the start delay and the
gaps, whose end it knows from the previous movement's marker), so the loop runs in
simulated time whatever the machine's load and however late a marker comes (a reference
that does not come within WAIT_S is stepped over, counted). Per movement it also prints
how late its marker came and how many steps after the hold went without the reference of
their time (0: the tracking error is the loop's own).

Prints, per movement, the tracking error: RMS and max per joint of q_sim(t) - q_movement(t)
(the library movement evaluated at arm_sim's stamp, from the movement's marker t0), over
the part after its 0.5 s hold_before (the arm settles there from the jump between two
movements' postures); and the loop's latency: command published -> first arm_sim state
that applied it (a round trip controller -> arm_sim -> controller), and in real time
reference stamp -> feed-forward received (trajectory_publisher -> torque_node -> here).
Exit code 0 when it ran (whatever the error: the caller judges it), 2 when it could not.
--no-feedforward runs PD only (for comparison).
--attach: start no node (closed_loop.launch.py starts them: `ros2 launch forearm_dynamics
closed_loop.launch.py`): wait for arm_sim and torque_node, print "closed_loop: ready" (the
launch file starts trajectory_publisher on that line), and end once the reference has
been silent for ATTACH_END_S.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
import rclpy
from closed_loop_report import report  # beside this file (installed with it)
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics import JOINT_NAMES, build_model, get_movement
from forearm_dynamics.nodes.common import hold_stop_signals
from forearm_dynamics.processes import Child, claim_domain, ros_env

GAP_S = 0.3
ATTACH_END_S = 2.0  # --attach: the reference silent this long (gaps are GAP_S) = the end
#: lockstep: the longest wait (wall clock) for a reference before stepping without it. A
#: hang guard, not a deadline: the loop runs in simulated time, so waiting costs nothing
#: but wall time, and the reference (reliable) always comes unless the movement ended.
#: It was 0.05 s: at load 7.6 (CI) references delayed that long were stepped over and
#: movement 1's pro/sup missed by 0.046 rad RMS (0 stale steps at load 3).
WAIT_S = 2.0
#: PD bandwidth (rad/s): 5 Hz in lockstep (the loop delay is one step, always), 2 Hz in
#: real time (arm_sim stalls on a loaded machine are tens of ms of loop delay)
OMEGA = {True: 2 * math.pi * 5.0, False: 2 * math.pi * 2.0}
ZETA = 1.0


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class Controller:
    """Computed torque: feed-forward from torque_node + PD on arm_sim's state."""

    def __init__(self, node, arm, start_posture: np.ndarray, feedforward: bool = True,
                 lockstep: bool = False, movement_count: int = 1, gap_s: float | None = GAP_S):
        self.model, self.data = arm.model, arm.model.createData()
        self.lockstep = lockstep
        self.q = start_posture.copy()  # the newest state
        self.qd = np.zeros(arm.nv)
        self.t = 0  # stamp of the newest state
        self.ref_t = 0  # stamp of the newest reference
        self.outstanding = False  # lockstep: a command sent, its state not yet back
        self.waiting_since: float | None = None  # lockstep: waiting for the reference
        self.stale_steps = 0  # lockstep: steps taken without the reference of their time
        #: the playlist's length and gap, to predict the next start (None: not known)
        self.movement_count = movement_count
        self.gap_ns = None if gap_s is None else round(gap_s * 1e9)
        self.next_start: int | None = None  # lockstep: when the next movement is due (sim ns)
        #: lockstep, per step: state stamp, reference stamp, 1 if it waited out WAIT_S
        self.steps_ref: list[tuple[int, int, int]] = []
        self.sim_t0_ns: int | None = None
        w = OMEGA[lockstep]
        self.kp, self.kd = w**2, 2 * ZETA * w
        self.feedforward = feedforward
        self.q_ref = start_posture.copy()
        self.qd_ref = np.zeros(arm.nv)
        self.tau_ff = arm.gravity_torques(start_posture) if feedforward else np.zeros(arm.nv)
        self.states: list[tuple[int, np.ndarray]] = []  # (stamp, q)
        self.markers: list[dict] = []
        self.sent: dict[bytes, int] = {}  # command effort bytes -> publish time
        self.loop_ns: list[int] = []
        self.ff_ns: list[int] = []
        self.pub = node.create_publisher(JointState, "joint_commands", 10)
        self.cmd = JointState(name=list(JOINT_NAMES))
        # depth 1: a controller wants the newest state and reference, never a queue of old
        # ones (lockstep: every state answers a command, keep them all)
        depth = 1000 if lockstep else 1
        node.create_subscription(JointState, "reference/joint_torques", self.on_reference, depth)
        node.create_subscription(JointState, "joint_states", self.on_state, depth)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(String, "arm_sim/config", self.on_sim_config, latched)
        node.create_subscription(String, "movement", self.on_marker,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        if lockstep:
            node.create_timer(0.002, self.on_wait_timer)

    def on_reference(self, msg: JointState) -> None:
        self.ff_ns.append(time.time_ns() - stamp_ns(msg))
        self.q_ref = np.asarray(msg.position)
        self.qd_ref = np.asarray(msg.velocity)
        if self.feedforward:
            self.tau_ff = np.asarray(msg.effort)
        self.ref_t = stamp_ns(msg)
        if self.lockstep:
            self.try_step()

    def on_sim_config(self, msg: String) -> None:
        self.sim_t0_ns = json.loads(msg.data)["t0_ns"]

    def on_marker(self, msg: String) -> None:
        """A movement started; in lockstep also: when the next one is due. trajectory_publisher
        starts it gap s after this one's last sample, at the first clock tick not earlier:
        the controller stops there until its reference comes, so the arm never runs into a
        movement whose marker is late. (Before, it stepped at once until the marker came:
        a CI run tracked movement 26's fingers 0.17 rad off, as a reference ~0.1 s old
        would, and nothing counted those steps; a marker held back 3 s reproduces the
        mechanism.) --attach: the gap is the launch file's, not predicted."""
        m = json.loads(msg.data)
        m["seen_at_ns"] = self.t  # the simulated time it arrived at (lockstep: how late)
        self.markers.append(m)
        if m["index"] + 1 < self.movement_count and self.gap_ns is not None:
            self.next_start = (m["t0_ns"] + m["samples"] * round(1e9 / m["rate_hz"])
                               + self.gap_ns)
        else:
            self.next_start = None

    def on_state(self, msg: JointState) -> None:
        now = time.time_ns()
        applied = self.sent.pop(np.asarray(msg.effort).tobytes(), None)
        if applied is not None:
            self.loop_ns.append(now - applied)
        self.q, self.qd = np.asarray(msg.position), np.asarray(msg.velocity)
        self.t = stamp_ns(msg)
        self.states.append((self.t, self.q))
        if not self.lockstep:  # real time: one command per simulated state
            self.command()
            return
        self.outstanding = False
        self.try_step()

    # -- lockstep: the simulated time is everyone's clock (/clock from arm_sim) ----------
    def playing(self, t: int) -> bool:
        """A movement is being replayed at simulated time t (its marker seen)."""
        return any(m["t0_ns"] <= t < _end_ns(m) for m in self.markers)

    def needs_reference(self, t: int) -> bool:
        """The step from simulated time t must wait for the reference of t: a movement plays
        (its marker), or references come from one whose marker is not here yet, or the next
        one is due (its start predicted from the previous marker). Otherwise (start delay,
        gaps) no reference is coming and the arm holds."""
        if self.ref_t >= t:
            return False
        if self.playing(t) or t >= (self.next_start or math.inf):
            return True
        return self.ref_t > max((_end_ns(m) for m in self.markers), default=0)  # (0: none yet)

    def try_step(self) -> None:
        """Step when the reference of the current simulated time is here (trajectory_publisher
        publishes it when /clock reaches that time, torque_node forwards it), or at once
        when none is coming."""
        if self.outstanding:
            return
        if self.needs_reference(self.t):
            if self.waiting_since is None:
                self.waiting_since = time.monotonic()
            return
        self.step()

    def step(self, stale: bool = False) -> None:
        self.waiting_since = None
        self.outstanding = True
        self.steps_ref.append((self.t, self.ref_t, int(stale)))
        self.command()

    def on_wait_timer(self) -> None:
        """A reference that never comes (lost, or the movement ended early) must not stop the
        loop: after WAIT_S, step with the newest reference (counted)."""
        if (self.lockstep and not self.outstanding and self.waiting_since is not None
                and time.monotonic() - self.waiting_since > WAIT_S):
            self.stale_steps += 1
            self.step(stale=True)

    def command(self) -> None:
        q, qd = self.q, self.qd
        model, data = self.model, self.data
        m = pin.crba(model, data, q)  # upper triangle filled
        m = np.triu(m) + np.triu(m, 1).T
        gravity = pin.computeGeneralizedGravity(model, data, q).copy()
        gravity -= pin.computeGeneralizedGravity(model, data, self.q_ref)
        tau = self.tau_ff + gravity + m @ (self.kp * (self.q_ref - q) + self.kd * (self.qd_ref - qd))
        self.cmd.effort = tau.tolist()
        self.pub.publish(self.cmd)
        if len(self.sent) > 5000:  # commands overtaken by newer ones are never applied
            self.sent.clear()
        self.sent[np.asarray(self.cmd.effort).tobytes()] = time.time_ns()


def _end_ns(marker: dict) -> int:
    return marker["t0_ns"] + round(marker["duration"] * 1e9)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--movements", default="1,26,51", help="comma-separated library ids")
    ap.add_argument("--out", type=Path, default=None, help="write results.json (and the plot) here")
    ap.add_argument("--plot", action="store_true", help="draw reference vs simulated angles")
    ap.add_argument("--domain", type=int, default=91)
    ap.add_argument("--no-feedforward", action="store_true", help="PD only, for comparison")
    ap.add_argument("--attach", action="store_true",
                    help="start no node: run beside closed_loop.launch.py's nodes")
    ap.add_argument("--lockstep", action="store_true",
                    help="arm_sim in lockstep: one step per reference sample (load-independent)")
    args = ap.parse_args(argv)
    ids = [int(x) for x in args.movements.split(",") if x.strip()]
    try:
        movements = [get_movement(i) for i in ids]
    except ValueError as exc:
        print(f"closed_loop: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="closed_loop_"))
    (out / "logs").mkdir(parents=True, exist_ok=True)
    if args.attach:  # the launch file's nodes, in the caller's ROS environment
        env = dict(os.environ)
    else:
        try:
            lease = claim_domain(args.domain, "closed_loop")
        except ValueError as exc:  # a domain out of range: one line, no traceback
            print(f"closed_loop: {exc}", file=sys.stderr)
            return 2
        env = ros_env(lease.domain, out / "logs")
    start = movements[0].start
    posture = [a for n, x in zip(JOINT_NAMES, start, strict=True)
               for a in ("-p", f"initial_posture.{n}:={float(x)!r}")]
    # lockstep: arm_sim's /clock is everyone's time (trajectory_publisher's timer ticks on it)
    sim_time = ["-p", "use_sim_time:=true"] if args.lockstep else []
    children = [] if args.attach else [
        Child.script("arm_sim", [*posture, "-p", "command_timeout:=0.5",
                                 "-p", f"lockstep:={'true' if args.lockstep else 'false'}"],
                     env, out / "logs"),
        Child.script("torque_node", ["-p", "input_topic:=reference/joint_states",
                                     "-p", "output_topic:=reference/joint_torques",
                                     "-p", "estimator:=backward", *sim_time],
                     env, out / "logs"),
    ]
    os.environ.update({k: v for k, v in env.items() if k.startswith("ROS_")})
    if args.attach:  # under ros2 launch: SIGINT (maybe twice) ends the run, never a traceback
        hold_stop_signals()
    rclpy.init()
    node = rclpy.create_node("closed_loop_controller")
    ctrl = Controller(node, build_model("segmented", 50), start, not args.no_feedforward,
                      args.lockstep, len(movements),
                      None if args.attach else GAP_S)  # --attach: the launch file's gap
    executor = EventsExecutor()
    executor.add_node(node)

    def spin_for(seconds: float) -> None:
        try:
            executor.spin_until_future_complete(Future(), timeout_sec=seconds)
        except ExternalShutdownException:  # --attach: stopped by a signal (rclpy.ok() says so)
            pass

    try:
        deadline = time.monotonic() + 60
        while rclpy.ok() and time.monotonic() < deadline and all(c.running() for c in children) and not (
                ctrl.pub.get_subscription_count() and ctrl.sim_t0_ns is not None
                and (args.lockstep or len(ctrl.states) > 100)
                and node.count_publishers("reference/joint_torques")):
            spin_for(0.05)
        if not rclpy.ok():
            print("closed_loop: stopped before the nodes came up", flush=True)
            return 0
        if time.monotonic() >= deadline or not all(c.running() for c in children):
            dead = [c for c in children if not c.running()]
            why = f": {dead[0].text().strip().splitlines()[-1]}" if dead else ""
            print(f"closed_loop: arm_sim/torque_node did not come up{why}; logs in {out / 'logs'}",
                  file=sys.stderr)
            return 2
        if args.attach:
            print("closed_loop: ready", flush=True)
            last = time.monotonic()
            end = last + 60 + sum(m.duration + GAP_S for m in movements) * 3
            seen = 0
            while rclpy.ok() and time.monotonic() < min(end, last + (ATTACH_END_S if seen else 120)):
                spin_for(0.1)
                if len(ctrl.ff_ns) != seen:
                    seen, last = len(ctrl.ff_ns), time.monotonic()
            return report(ctrl, args, movements, out, WAIT_S)
        pub = Child.script("trajectory_publisher", [
            "-p", f"movements:={ids}", "-p", "output_topic:=reference/joint_states",
            "-p", "start_delay:=0.5", "-p", f"gap:={GAP_S}", "-p", "min_subscribers:=1",
            *sim_time], env, out / "logs")
        children.append(pub)
        if args.lockstep:  # the first step: from then on every state answers a command
            ctrl.step()
        end = time.monotonic() + 30 + sum(m.duration + GAP_S for m in movements) * 3
        while pub.running() and time.monotonic() < end:
            spin_for(0.1)
        spin_for(0.3)
    finally:
        executor.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()
        for c in reversed(children):
            c.stop()
    return report(ctrl, args, movements, out, WAIT_S)


if __name__ == "__main__":
    sys.exit(main())
