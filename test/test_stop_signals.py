"""Stopping like a ROS node: SIGINT sent twice, 0.1 s apart, to the process group of each
node (as `ros2 launch` forwards it and a terminal or `timeout` signals the group): exit 0,
no abort ("terminate called ... error_already_set", exit -6), no traceback, and the
recorder's bag complete (read by rosbags, an independent reader) with one summary line.

Each node runs in a session of its own (its own process group) while a JointState stream
(1 kHz, from another process) and a parameter-service client keep its callbacks busy: the
abort came from a KeyboardInterrupt raised inside an rclpy service callback under the
EventsExecutor.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rosproc
from rosbags.highlevel import AnyReader

from forearm_dynamics.processes import popen

pytestmark = [pytest.mark.ros, pytest.mark.faults]

WAIT_S = rosproc.STARTUP_S  # hang guard

#: a 1 kHz JointState stream and parameter requests to one node, until killed
BUSY = r"""
import sys, time
import rclpy
from rcl_interfaces.srv import ListParameters
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from forearm_dynamics import JOINT_NAMES
target = sys.argv[1]
rclpy.init()
n = rclpy.create_node("busy_peer")
pub = n.create_publisher(JointState, "joint_states", QoSProfile(depth=1000))
cli = n.create_client(ListParameters, f"/{target}/list_parameters")
msg = JointState(name=list(JOINT_NAMES), position=[0.1] * 20, velocity=[0.0] * 20)
def tick():
    ns = time.time_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
    pub.publish(msg)
def ask():
    if cli.service_is_ready():
        cli.call_async(ListParameters.Request())
n.create_timer(0.001, tick)
n.create_timer(0.005, ask)
print("busy", flush=True)
rclpy.spin(n)
"""

NODES = {
    "torque_node": [],
    "torque_lifecycle_node": [],
    "null_echo_node": [],
    "bag_recorder": ["output"],
    "arm_sim": [],
    "arm_viz": [],
    "trajectory_publisher": ["-p", "loop:=true"],
}


def _start(argv: list[str], env: dict, log: Path) -> subprocess.Popen:
    with log.open("wb") as out:
        return popen(argv, env=env, stdout=out, stderr=subprocess.STDOUT,  # SIGINT not ignored
                     stdin=subprocess.DEVNULL, start_new_session=True)


@pytest.mark.parametrize("name", list(NODES))
def test_sigint_twice_to_the_group_exits_0(name, tmp_path) -> None:
    domain = rosproc.test_domain(102, 139)
    env = rosproc.ros_env(domain)
    args = list(NODES[name])
    bag = tmp_path / "run.mcap"
    if args == ["output"]:
        args = ["-p", f"output:={bag}"]
    log = tmp_path / f"{name}.log"
    node = _start([str(rosproc.BIN / name), *(["--ros-args", *args] if args else [])], env, log)
    busy = _start([sys.executable, "-c", BUSY, name], env, tmp_path / "busy.log")
    try:
        # up (its first log line: made, spinning) and serving: its parameter services
        # answer the busy peer, the stream flows (discovery on loopback takes ~2.5 s)
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and node.poll() is None and not (
                "[INFO]" in log.read_text(errors="replace")
                and "busy" in (tmp_path / "busy.log").read_text(errors="replace")):
            time.sleep(0.1)
        time.sleep(4.0)
        assert node.poll() is None, log.read_text(errors="replace")
        os.killpg(node.pid, signal.SIGINT)
        time.sleep(0.1)
        try:
            os.killpg(node.pid, signal.SIGINT)
        except ProcessLookupError:
            pass  # already gone: fine
        code = node.wait(timeout=WAIT_S)
    finally:
        for p in (node, busy):
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    text = log.read_text(errors="replace")
    assert code == 0, f"{name} exit {code}:\n{text[-3000:]}"
    for bad in ("terminate called", "Traceback", "[FATAL]", "KeyboardInterrupt"):
        assert bad not in text, f"{name}: {bad!r} in its output:\n{text[-3000:]}"
    if name == "bag_recorder":
        with AnyReader([bag]) as reader:  # an independent reader: the file is complete
            counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts.get("/joint_states", 0) > 0, counts
        summary = [ln for ln in text.splitlines() if "wrote " in ln and " messages to " in ln]
        assert len(summary) == 1, text[-3000:]
