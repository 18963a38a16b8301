"""The README's first hour, run as printed: the Python API snippet and the examples/ folder,
the examples as real processes against a real torque_node over loopback DDS."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosproc import STARTUP_S, ros_env, start

from forearm_dynamics import JOINT_NAMES, build_model, get_movement
from forearm_dynamics.processes import popen

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def _readme_python_snippet() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Quick start: Python", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert len(blocks) == 1, "the Python API section has one python block"
    return blocks[0]


def test_readme_python_snippet_runs_as_printed():
    scope: dict = {}
    exec(compile(_readme_python_snippet(), "README.md (Python API)", "exec"), scope)  # noqa: S102
    m = scope["m"]
    assert m.joint_names == JOINT_NAMES
    tau = scope["tau"]
    assert tau.shape == (20,) and np.isfinite(tau).all()
    # the snippet's tau: the elbow at 90° at rest, i.e. that posture's gravity torques
    q = np.zeros(20)
    q[JOINT_NAMES.index("elbow_flexion")] = np.pi / 2
    np.testing.assert_allclose(tau, build_model("segmented", 50).gravity_torques(q), atol=1e-12)
    assert tau[0] > 1  # the elbow holds the forearm
    # the loop at the end ran to the last movement: (N, 20) arrays
    assert scope["mv"].id == 65 and scope["qdd"].shape == (len(scope["mv"].sample_times(1000)), 20)
    assert scope["urdf"].lstrip().startswith("<?xml") and "<visual>" in scope["urdf"]


def _run_example(name: str, *args: str, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(EXAMPLES / name), *args], env=ros_env(),
                          capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture
def torque_node():
    node = start("torque_node")
    try:
        assert node.wait_for_output("config on", STARTUP_S), node.output()
        yield node
    finally:
        assert node.stop() == 0, node.output()


def test_client_prints_the_gravity_torques_of_its_posture(torque_node):
    res = _run_example("torque_client.py")
    assert res.returncode == 0, res.stdout + res.stderr
    printed = dict(re.findall(r"^  (\w+)\s+([-+]\d+\.\d+) N·m$", res.stdout, flags=re.MULTILINE))
    assert list(printed) == list(JOINT_NAMES)
    q = np.zeros(20)
    q[JOINT_NAMES.index("elbow_flexion")] = np.pi / 2
    # at rest the answer is the gravity torque (the node's first sample has qdd = 0 too)
    expected = build_model("segmented").gravity_torques(q)
    np.testing.assert_allclose([float(v) for v in printed.values()], expected, atol=1e-6)
    assert abs(expected[0]) > 1  # the elbow holds the forearm: the check is not of zeros


def test_listener_follows_a_replayed_movement(torque_node):
    """torque_node <- trajectory_publisher (movement 3), the listener on joint_torques."""
    listener = popen(  # SIGINT at its default action, whatever this process's (processes.popen)
        [sys.executable, str(EXAMPLES / "torque_listener.py"), "--seconds", "60"], env=ros_env(),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    pub = None
    try:
        # start the replay once the listener's subscription has matched torque_node's
        # publisher (it says so every second while waiting), so no sample goes before it
        first = ""
        while "(1 publisher(s) matched)" not in first:
            line = listener.stdout.readline()
            assert line.startswith("waiting for /joint_torques"), first + line
            first += line
        pub = start("trajectory_publisher", "-p", "movements:=[3]", "-p", "start_delay:=3.0",
                    "-p", "min_subscribers:=1", "-p", "subscriber_timeout:=30.0")
        assert pub.wait(timeout=90) == 0, pub.output()
    finally:
        if pub is not None and pub.running():
            pub.stop()
        listener.send_signal(2)  # SIGINT, this process only
        out, _ = listener.communicate(timeout=30)
    out = first + out
    assert listener.returncode == 0, out
    final = re.search(r"received (\d+) joint_torques; stamps out of order (\d+), gaps (\d+); "
                      r"the last:\n  .* \(N·m\)\n", out)
    assert final, out
    assert int(final.group(1)) == 1500, out  # every sample of the movement, reliable QoS
    assert int(final.group(2)) == 0, out
    # once a second while the stream runs (how many seconds depends on the machine's speed)
    reports = re.findall(r"^(\d+) msgs in the last second, (\d+) in all", out, flags=re.MULTILINE)
    assert reports and all(int(a) <= int(b) <= 1500 for a, b in reports), out
    # the last per-joint line (printed at exit): the movement's final posture, at rest ->
    # its gravity torques
    values = re.findall(r"^  (.+) \(N·m\)$", out, flags=re.MULTILINE)[-1]
    pairs = [p.split() for p in values.split(", ")]
    assert [n for n, _ in pairs] == list(JOINT_NAMES)
    mv = get_movement(3)
    q, _, _ = mv.evaluate(mv.sample_times(1000)[-1:])
    expected = build_model("segmented").gravity_torques(q[0])
    np.testing.assert_allclose([float(v) for _, v in pairs], expected, atol=2e-4)

