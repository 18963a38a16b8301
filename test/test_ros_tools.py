"""The package under the upstream ROS 2 tools (`make test-ros-tools`, docs/testing.md): built
with `colcon build`, started with `ros2 launch`, driven with `ros2 lifecycle`, in real
processes over loopback DDS.

Runs in the venv of the upstream ros2 command line (built by the installer named by
ROS2CLI_INSTALL: ros2cli, launch, launch_ros from source), never in `make test`: the
package's own set-up does not need those tools. Each test:
- the launch files' `--show-args` list the documented arguments; a wrong value is one line;
- torque_node.launch.py answers every JointState sample; SIGINT to `ros2 launch` stops every
  process it started (checked by PID), each exit 0 (launch says "finished cleanly");
- record.launch.py: a complete bag; demo.launch.py: the replay, check_bag exit 0;
  viz.launch.py: arm_viz's robot_description; closed_loop.launch.py: tracked movements;
- the lifecycle walk with `ros2 lifecycle set` gives torques only while active.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rosproc

from forearm_dynamics.processes import popen

pytestmark = pytest.mark.ros_tools

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
WAIT_S = rosproc.STARTUP_S  # hang guard
LAUNCH_FILES = ("torque_node", "record", "demo", "closed_loop", "viz")


def _documented_args() -> dict[str, set[str]]:
    """docs/ros.md's table: launch file -> the arguments it documents."""
    text = (REPO / "docs" / "ros.md").read_text()
    out: dict[str, set[str]] = {}
    for m in re.finditer(r"^\| `(\w+)\.launch\.py` \| ([^|]*) \|", text, re.MULTILINE):
        out[m.group(1)] = set(re.findall(r"`(\w+)`", m.group(2)))
    return out


@pytest.fixture(scope="module")
def ros_env_base(tmp_path_factory) -> dict[str, str]:
    """colcon build of a clean copy of the checkout; the environment its setup.bash makes."""
    if shutil.which("ros2", path=str(VENV_BIN)) is None:
        pytest.fail("no ros2 CLI in this venv: run `make test-ros-tools ROS2CLI_INSTALL=...`")
    ws = tmp_path_factory.mktemp("ws")
    files = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split()
    for f in files:
        (ws / "src" / "forearm_dynamics" / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / f, ws / "src" / "forearm_dynamics" / f)
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ.get('PATH', '')}"}
    t0 = time.monotonic()
    r = subprocess.run([str(VENV_BIN / "colcon"), "build", "--base-paths", "src"], cwd=ws, env=env,
                       capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    print(f"colcon build: {time.monotonic() - t0:.1f} s")
    dump = subprocess.run(["bash", "-c", f"source {ws}/install/setup.bash && env -0"], env=env,
                          capture_output=True, check=True, timeout=60).stdout
    sourced = dict(kv.split("=", 1) for kv in dump.decode().split("\0") if "=" in kv)
    sourced["AMENT_PREFIX_PATH"] += f":{VENV_BIN.parent}"
    return sourced


def env_for(base: dict[str, str], domain: int) -> dict[str, str]:
    env = dict(base)
    env.update({k: v for k, v in rosproc.ros_env(domain).items()
                if k.startswith(("ROS_", "HOME", "PYTHONUNBUFFERED", "RCUTILS"))})
    return env


def ros2(env: dict, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([str(VENV_BIN / "ros2"), *args], env=env, capture_output=True, text=True,
                          timeout=timeout, check=False)


def lifecycle(env: dict, verb: str, *args: str) -> subprocess.CompletedProcess:
    """`ros2 lifecycle <verb>` without the ros2 daemon (it would outlive the test).

    Each call is a new process that must discover the graph again within its spin time
    (~2.5 s on loopback when idle). Under load that window can close before the node is
    seen: the CLI then prints "Node not found" on stderr and nothing was asked of the
    node, so asking again is safe (CI once got an empty `get` that way at load 15). Up to
    WAIT_S, with a longer window each time."""
    deadline = time.monotonic() + WAIT_S
    spin = 3.0
    while True:
        r = ros2(env, "lifecycle", verb, "--no-daemon", "--spin-time", f"{spin:g}", *args)
        if "Node not found" not in r.stdout + r.stderr or time.monotonic() > deadline:
            return r
        spin = min(2 * spin, 20.0)


class Launch:
    """`ros2 launch forearm_dynamics <file>` in a session of its own, output in a file."""

    def __init__(self, env: dict, tmp: Path, file: str, *args: str):
        self.log = tmp / f"launch_{file}_{time.monotonic_ns()}.log"
        with self.log.open("wb") as out:
            # processes.popen: SIGINT at its default action even where this run ignores it
            # (a `make ... &` in a script): `ros2 launch` then ignored the test's Ctrl-C
            self.proc = popen(
                [str(VENV_BIN / "ros2"), "launch", "forearm_dynamics", f"{file}.launch.py", *args],
                env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                start_new_session=True)

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_for(self, text: str, timeout: float = WAIT_S) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            if text in self.text():
                return True
            time.sleep(0.1)
        return text in self.text()

    def children(self) -> dict[int, str]:
        """PID -> executable name of every process launch started (from its own lines)."""
        return {int(pid): name for name, pid in
                re.findall(r"\[INFO\] \[([\w.-]+)-\d+\]: process started with pid \[(\d+)\]", self.text())}

    def stop(self) -> int:
        """SIGINT to `ros2 launch` only (its PID), as a user's Ctrl-C reaches it."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        return self.wait()

    def wait(self, timeout: float = WAIT_S) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=10)
            raise

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=10)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is gone for our purpose (its parent has not reaped it yet)
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def assert_no_orphans(launch: Launch, pids: dict[int, str]) -> None:
    assert pids, launch.text()[-3000:]
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.2)
    left = {p: n for p, n in pids.items() if alive(p)}
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"still running after ros2 launch exited: {left}"
    text = launch.text()
    for bad in ("terminate called", "Traceback", "[FATAL]", "process has died"):
        assert bad not in text, f"{bad!r}:\n{text[-4000:]}"


# -- arguments -----------------------------------------------------------------------------
def test_show_args_lists_the_documented_arguments(ros_env_base) -> None:
    documented = _documented_args()
    assert set(documented) == set(LAUNCH_FILES), documented
    env = env_for(ros_env_base, rosproc.test_domain(140, 160))
    for file in LAUNCH_FILES:
        r = ros2(env, "launch", "forearm_dynamics", f"{file}.launch.py", "--show-args")
        assert r.returncode == 0, r.stdout + r.stderr
        shown = dict(re.findall(r"^    '(\w+)':\n        (.+)$", r.stdout, re.MULTILINE))
        assert documented[file] <= set(shown), (file, documented[file] - set(shown), r.stdout)
        assert all(desc.strip() and "no description" not in desc for desc in shown.values()), r.stdout


@pytest.mark.parametrize(("args", "names"), [(("side:=up",), "side"),
                                             (("body_size:=200",), "body_size"),
                                             (("managed:=maybe",), "managed")])
def test_a_wrong_argument_value_is_one_line(ros_env_base, tmp_path, args, names) -> None:
    env = env_for(ros_env_base, rosproc.test_domain(140, 160))
    launch = Launch(env, tmp_path, "torque_node", *args)
    try:
        code = launch.wait()
    finally:
        launch.kill()
    text = launch.text()
    errors = [ln for ln in text.splitlines() if "ERROR" in ln]
    assert len(errors) >= 1 and names in errors[0], text
    assert "Traceback" not in text, text
    if names == "body_size":  # the node's own line; the node exits 2, launch says so
        assert "exit code 2" in text, text
    else:
        assert code != 0, text


# -- the launch files run ---------------------------------------------------------------------
def _peer(domain: int):
    return rosproc.Peer("ros_tools_peer", domain=domain)


def _feed_and_listen(peer, count: int, topic_out: str = "joint_torques") -> tuple[list[int], set[int]]:
    """Publish `count` JointStates (~500 Hz) once the node listens; the stamps sent and answered."""
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    from forearm_dynamics import JOINT_NAMES

    answered: set[int] = set()
    n = peer.node
    n.create_subscription(JointState, topic_out, lambda m: answered.add(
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), QoSProfile(depth=10000))
    pub = n.create_publisher(JointState, "joint_states", QoSProfile(depth=10000))
    assert peer.spin_until(lambda: pub.get_subscription_count() >= 1
                           and n.count_publishers(topic_out) >= 1, WAIT_S)
    peer.spin_for(1.0)  # the node's reader matched this writer too (discovery both ways)
    msg = JointState(name=list(JOINT_NAMES), position=[0.2] * 20, velocity=[0.0] * 20)
    sent = []
    for k in range(count):
        ns = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
        pub.publish(msg)
        sent.append(ns)
        peer.spin_for(0.002)
        if k % 100 == 99:  # paced by the answers: a node stalled by load never falls a
            # whole queue (qos_depth 1000) behind, which would drop samples by design
            peer.spin_until(lambda t=ns: t in answered, WAIT_S)
    peer.spin_until(lambda: set(sent) <= answered, WAIT_S)
    return sent, answered


def test_torque_launch_answers_every_sample_and_sigint_stops_all(ros_env_base, tmp_path) -> None:
    domain = rosproc.test_domain(140, 160)
    env = env_for(ros_env_base, domain)
    launch = Launch(env, tmp_path, "torque_node", "estimator:=backward", "body_size:=95")
    peer = _peer(domain)
    try:
        assert launch.wait_for("config on"), launch.text()
        sent, answered = _feed_and_listen(peer, 2000)
        missing = set(sent) - answered
        assert not missing, f"{len(missing)} of {len(sent)} samples unanswered"
        pids = launch.children()
        assert list(pids.values()) == ["torque_node"], pids
        assert launch.stop() == 0, launch.text()[-3000:]
    finally:
        peer.close()
        launch.kill()
    assert_no_orphans(launch, pids)
    assert "process has finished cleanly" in launch.text()


def test_record_launch_writes_a_complete_bag(ros_env_base, tmp_path) -> None:
    from rosbags.highlevel import AnyReader

    domain = rosproc.test_domain(140, 160)
    env = env_for(ros_env_base, domain)
    bag = tmp_path / "rec.mcap"
    launch = Launch(env, tmp_path, "record", f"output:={bag}", "estimator:=backward")
    peer = _peer(domain)
    try:
        assert launch.wait_for("recording") and launch.wait_for("config on"), launch.text()
        peer.spin_for(3.0)  # the recorder's readers match the node's writers too
        sent, answered = _feed_and_listen(peer, 1000)
        assert set(sent) <= answered
        peer.spin_for(1.0)
        pids = launch.children()
        assert sorted(pids.values()) == ["bag_recorder", "torque_node"], pids
        assert launch.stop() == 0, launch.text()[-3000:]
    finally:
        peer.close()
        launch.kill()
    assert_no_orphans(launch, pids)
    with AnyReader([bag]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/joint_states"] >= len(sent) and counts["/joint_torques"] >= len(sent), counts
    assert len(re.findall(r"wrote \d+ messages to", launch.text())) == 1


def test_demo_launch_replays_and_checks(ros_env_base, tmp_path) -> None:
    env = env_for(ros_env_base, rosproc.test_domain(140, 160))
    launch = Launch(env, tmp_path, "demo", "movements:=1,26", f"out:={tmp_path}")
    try:
        code = launch.wait(timeout=WAIT_S + 120)
    finally:
        launch.kill()
    text = launch.text()
    assert code == 0, text[-4000:]
    assert re.search(r"\[check_bag-\d+\]: process has finished cleanly", text), text[-4000:]
    bag = next(tmp_path.glob("launch_*/run.mcap"))
    r = subprocess.run([str(VENV_BIN / "check_bag"), str(bag)], env=env, capture_output=True,
                       text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert_no_orphans(launch, launch.children())


def test_viz_launch_publishes_the_arm(ros_env_base, tmp_path) -> None:
    """arm_viz answers torques with markers; it offers robot_description."""
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    from visualization_msgs.msg import MarkerArray

    from forearm_dynamics import JOINT_NAMES

    domain = rosproc.test_domain(140, 160)
    env = env_for(ros_env_base, domain)
    launch = Launch(env, tmp_path, "viz")
    peer = _peer(domain)
    got: list[int] = []
    try:
        n = peer.node
        n.create_subscription(MarkerArray, "arm_markers", lambda m: got.append(len(m.markers)),
                              QoSProfile(depth=10))
        pub = n.create_publisher(JointState, "joint_torques", QoSProfile(depth=10))
        msg = JointState(name=list(JOINT_NAMES), position=[0.2] * 20, velocity=[0.0] * 20,
                         effort=[0.1] * 20)

        def send():
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(time.time_ns(), 10**9)
            pub.publish(msg)

        n.create_timer(0.05, send)
        assert peer.spin_until(lambda: got and max(got) > 0, WAIT_S), launch.text()
        assert n.count_publishers("robot_description") == 1
        pids = launch.children()
        assert launch.stop() == 0, launch.text()[-3000:]
    finally:
        peer.close()
        launch.kill()
    assert_no_orphans(launch, pids)


def test_closed_loop_launch_tracks(ros_env_base, tmp_path) -> None:
    env = env_for(ros_env_base, rosproc.test_domain(140, 160))
    launch = Launch(env, tmp_path, "closed_loop", "movements:=1", f"out:={tmp_path}")
    try:
        code = launch.wait(timeout=WAIT_S + 120)
    finally:
        launch.kill()
    text = launch.text()
    assert code == 0, text[-4000:]
    assert "movement  1" in text and "tracking RMS" in text, text[-4000:]
    assert (tmp_path / "results.json").is_file()
    assert_no_orphans(launch, launch.children())


# -- the lifecycle walk with `ros2 lifecycle` ----------------------------------------------------
def test_lifecycle_walk_with_ros2_lifecycle(ros_env_base, tmp_path) -> None:
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    from forearm_dynamics import JOINT_NAMES

    domain = rosproc.test_domain(140, 160)
    env = env_for(ros_env_base, domain)
    # a queue of 100 s at this feed: a node stalled by load (seconds at load 15 on 2 cores)
    # catches up instead of dropping samples by design (KEEP_LAST, qos_depth)
    params = tmp_path / "deep.yaml"
    params.write_text("/**:\n  ros__parameters:\n    qos_depth: 25000\n")
    launch = Launch(env, tmp_path, "torque_node", "managed:=true", "estimator:=backward",
                    f"params_file:={params}")
    peer = _peer(domain)
    torques: list[tuple[int, int]] = []  # (stamp, receive time)
    try:
        assert launch.wait_for("unconfigured"), launch.text()
        n = peer.node
        n.create_subscription(JointState, "joint_torques", lambda m: torques.append(
            (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, time.time_ns())), QoSProfile(depth=10000))
        pub = n.create_publisher(JointState, "joint_states", QoSProfile(depth=10000))
        msg = JointState(name=list(JOINT_NAMES), position=[0.2] * 20, velocity=[0.0] * 20)
        sent: list[int] = []
        feeding = [True]

        def feed():
            if feeding[0]:
                ns = time.time_ns()
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
                pub.publish(msg)
                sent.append(ns)

        n.create_timer(0.004, feed)
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline and "/torque_node" not in lifecycle(env, "nodes").stdout:
            peer.spin_for(0.5)
        assert lifecycle(env, "get", "/torque_node").stdout.startswith("unconfigured")
        listing = lifecycle(env, "list", "/torque_node").stdout
        assert "configure [1]" in listing, listing

        windows: list[tuple[str, int, int]] = []  # (state, from, to): wall clock ns

        def walk(transition: str, state: str, seconds: float) -> None:
            t_start = time.time_ns()
            r = lifecycle(env, "set", "/torque_node", transition)
            assert r.returncode == 0 and "Transitioning successful" in r.stdout, r.stdout + r.stderr
            t_done = time.time_ns()
            if windows:
                windows[-1] = (windows[-1][0], windows[-1][1], t_start)
            windows.append((state, t_done, 0))
            peer.spin_for(seconds)
            got = lifecycle(env, "get", "/torque_node").stdout
            assert got.startswith(state), got

        walk("configure", "inactive", 3.0)
        walk("activate", "active", 3.0)
        walk("deactivate", "inactive", 3.0)
        walk("activate", "active", 3.0)
        feeding[0] = False
        peer.spin_for(2.0)
        windows[-1] = (windows[-1][0], windows[-1][1], time.time_ns())
        r = lifecycle(env, "set", "/torque_node", "shutdown")
        assert r.returncode == 0, r.stdout + r.stderr
        pids = launch.children()
        assert launch.wait() == 0, launch.text()[-3000:]  # the node exits 0, launch with it
    finally:
        peer.close()
        launch.kill()
    stamps = {s for s, _ in torques}
    for state, t0, t1 in windows:
        inside = [t for t in sent if t0 < t < t1]
        answered = [t for t in inside if t in stamps]
        assert inside, windows
        if state == "active":
            assert len(answered) == len(inside), f"active: {len(inside) - len(answered)} unanswered"
        else:
            assert not answered, f"{state}: {len(answered)} torques"
    assert_no_orphans(launch, pids)
