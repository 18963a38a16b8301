"""Start real node processes for tests with a clean, loopback-only ROS environment.

Each test session gets its own ROS_DOMAIN_ID (derived from the pytest process id and the
xdist worker) and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, so parallel runs never see each
other and nothing leaves loopback. Processes are stopped by their own PID only.
"""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

BIN = Path(sys.executable).parent  # the venv's console scripts sit next to its python


def domain_id() -> int:
    """1..101, stable for this test process (0 is avoided: it is everyone's default)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    seed = os.getpid() * 7 + (int(worker) if worker.isdigit() else 0)
    return 1 + seed % 101


_LOG_DIR = tempfile.mkdtemp(prefix="forearm_test_roslog_")
if not os.environ.get("KEEP_ROS_TEST_LOGS"):  # node output is read during the test itself
    atexit.register(shutil.rmtree, _LOG_DIR, ignore_errors=True)


def ros_env(domain: int | None = None) -> dict[str, str]:
    """The environment for child nodes: inherited PATH etc., ROS settings made explicit."""
    drop = ("ROS_", "RMW_", "FASTRTPS", "FASTDDS", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP")
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    env.update(
        ROS_DOMAIN_ID=str(domain if domain is not None else domain_id()),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_LOG_DIR=_LOG_DIR,
        HOME=os.environ.get("HOME") or tempfile.gettempdir(),
        PYTHONUNBUFFERED="1",
        RCUTILS_COLORIZED_OUTPUT="0",
    )
    return env


def apply_to_this_process() -> None:
    """Make the pytest process itself join the same private domain (before rclpy.init)."""
    os.environ.update({k: v for k, v in ros_env().items() if k.startswith(("ROS_", "HOME"))})


@dataclass
class NodeProcess:
    """One started executable; output goes to files so a chatty node never blocks."""

    name: str
    args: list[str]
    proc: subprocess.Popen = field(repr=False)
    out_path: Path
    err_path: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def running(self) -> bool:
        return self.proc.poll() is None

    def stdout(self) -> str:
        return self.out_path.read_text(errors="replace")

    def stderr(self) -> str:
        return self.err_path.read_text(errors="replace")

    def output(self) -> str:
        return self.stdout() + self.stderr()

    def wait_for_output(self, text: str, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output():
                return True
            if not self.running():
                return text in self.output()
            time.sleep(0.05)
        return False

    def wait(self, timeout: float = 30.0) -> int:
        return self.proc.wait(timeout=timeout)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        """Signal this process (only it), wait, escalate to SIGKILL if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                return self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
                raise
        return self.proc.returncode


def start(executable: str, *ros_args: str, domain: int | None = None) -> NodeProcess:
    """Start a console script of this venv with `--ros-args *ros_args` (if any)."""
    args = [str(BIN / executable)]
    if ros_args:
        args += ["--ros-args", *ros_args]
    out = Path(tempfile.mkstemp(prefix=f"{executable}_", suffix=".out", dir=_LOG_DIR)[1])
    err = out.with_suffix(".err")
    with out.open("wb") as fo, err.open("wb") as fe:
        proc = subprocess.Popen(args, env=ros_env(domain), stdout=fo, stderr=fe, stdin=subprocess.DEVNULL)
    return NodeProcess(executable, args, proc, out, err)


class Peer:
    """An rclpy node inside the test process, on the same private domain as the children.

    It has its own Context, so several peers (and other test files) never share state.
    """

    def __init__(self, name: str = "test_peer", domain: int | None = None):
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain if domain is not None else domain_id())
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(deadline - time.monotonic(), 0.0)))

    def spin_until(self, predicate, timeout: float = 10.0) -> bool:
        """Spin until predicate() is true; False on timeout."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def close(self) -> None:
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.context.try_shutdown()
