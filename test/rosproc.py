"""Start real node processes for tests with a clean, loopback-only ROS environment.

Each test session gets its own ROS_DOMAIN_ID (derived from the pytest process id and the
xdist worker) and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, so parallel runs never see each
other and nothing leaves loopback. Processes are stopped by their own PID only.
"""

from __future__ import annotations

import atexit
import functools
import itertools
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from importlib.metadata import entry_points
from pathlib import Path

from forearm_dynamics import processes
from forearm_dynamics.nodes.peer import Peer as _Peer
from forearm_dynamics.processes import BIN, Child, DomainLease, lease_domain

__all__ = [
    "BIN",
    "NodeProcess",
    "Peer",
    "Procs",
    "apply_to_this_process",
    "domain_id",
    "release_test_domains",
    "ros_env",
    "start",
    "test_domain",
]


_session_lease: DomainLease | None = None
_test_leases: list[DomainLease] = []
#: Peers not yet closed: release_test_domains() closes those on the domains it frees
_open_peers: list[Peer] = []
_counter = itertools.count()


def domain_id() -> int:
    """1..101, stable for this test process (0 is avoided: it is everyone's default); leased
    (processes.lease_domain), so a second test session on the machine gets another one."""
    global _session_lease
    if _session_lease is None:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
        seed = os.getpid() * 7 + (int(worker) if worker.isdigit() else 0)
        _session_lease = lease_domain(1, 101, seed)
    return _session_lease.domain


def test_domain(lo: int, hi: int) -> int:
    """A domain of lo..hi, leased until release_test_domains() (conftest: the end of the test
    module), so concurrent sessions never share it. Not sooner: a module's fixture may keep a
    node on its domain while a test takes another (test_faults_input's module harness and
    its 5 kHz test did; released at the second call, the first domain went to a concurrent
    session whose nodes then answered in it). Never shared: lease_domain shares an id when
    every one of the range is held (a demo can live with that, a test cannot), so this waits
    for a free one instead (a hang guard of STARTUP_S)."""
    deadline = time.monotonic() + STARTUP_S
    while True:  # never a shared one: another session's nodes would answer in it
        lease = lease_domain(lo, hi, os.getpid() * 7 + next(_counter))
        if lease.exclusive:
            break
        if time.monotonic() > deadline:
            raise RuntimeError(f"no ROS domain of {lo}..{hi} free for {STARTUP_S:g} s: every "
                               "one is leased by another test or run on this machine")
        time.sleep(1.0)
    _test_leases.append(lease)
    return lease.domain


def release_test_domains() -> None:
    """Free every test_domain() lease; call once no process started on them runs. A Peer
    still open on one of them (a harness whose start failed before its test could close
    it) is closed first: else it stays in the graph, and the next holder of the domain (a
    later module, another session) finds a node it did not start (test_units_live saw a
    `/fault_peer` publishing joint_states in its own leased domain)."""
    freed = {lease.domain for lease in _test_leases}
    for peer in [p for p in _open_peers if p.domain in freed]:
        peer.close()
    while _test_leases:
        _test_leases.pop().release()


#: How long a test waits for a node it started to come up (discovered, subscribed, its
#: config out). A hang guard, not a timing claim: the wait ends as soon as the node is
#: there, and a node took 19 s to start at load 27 (a 20 s guard then fails a correct node).
STARTUP_S = 180.0

_LOG_DIR = Path(tempfile.mkdtemp(prefix="forearm_test_roslog_"))
if not os.environ.get("KEEP_ROS_TEST_LOGS"):  # node output is read during the test itself
    atexit.register(shutil.rmtree, _LOG_DIR, ignore_errors=True)


#: A line Fast DDS's shared-memory transport logs on its own, in colour: "[RTPS_TRANSPORT_SHM
#: Error] Failed init_port fastrtps_port7003: open_and_lock_file failed". Its per-process
#: ports of 7000 and up (one per process, as the "unique network flow" UDP ports of
#: test_two_hosts_discovery.FLOW_PORTS) are numbered machine-wide, not per domain, so
#: processes of two sessions can race for one; the loser takes the next (a refused-parameter
#: test beside a second suite found this line before the node's one).
_FASTDDS_SHM_LOG = re.compile(r"\[RTPS_TRANSPORT_SHM (Error|Warning)\]")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def own_lines(text: str) -> list[str]:
    """The non-empty lines of a process's output, without Fast DDS's shared-memory log."""
    return [ln for ln in text.splitlines()
            if ln.strip() and not _FASTDDS_SHM_LOG.search(_ANSI.sub("", ln))]


def ros_env(domain: int | None = None) -> dict[str, str]:
    """The environment for child nodes: inherited PATH etc., ROS settings made explicit."""
    return processes.ros_env(domain if domain is not None else domain_id(), _LOG_DIR)


def apply_to_this_process() -> None:
    """Make the pytest process itself join the same private domain (before rclpy.init)."""
    os.environ.update({k: v for k, v in ros_env().items() if k.startswith(("ROS_", "HOME"))})


class Hang(subprocess.TimeoutExpired):
    """A process past its wait: the message carries its output (pytest shows str(exc))."""

    def __str__(self) -> str:
        return f"{super().__str__()}; its output:\n{self.output or '(none)'}"


@functools.cache
def node_executables() -> frozenset[str]:
    """Our nodes' executables, as the installed package declares them (setup.py's
    EXECUTABLES): they print every thread's stack on SIGUSR1 (nodes/common.run), which would
    end any other process, the venv's python among them, before its stacks were taken."""
    return frozenset(ep.name for ep in entry_points(group="console_scripts")
                     if ep.value.startswith("forearm_dynamics.nodes."))


class NodeProcess(Child):
    """One started executable (processes.Child, stdout and stderr in files of their own),
    with the test-friendly names and strictness: wait() raises on timeout, stop() raises
    after killing a node that ignored the signal."""

    @property
    def args(self) -> list[str]:
        return self.argv

    @property
    def out_path(self) -> Path:
        return self.log

    @property
    def err_path(self) -> Path:
        return self.err_log or self.log

    def output(self) -> str:
        return self.text()

    @property
    def is_node(self) -> bool:
        exe = Path(self.argv[0])
        return exe.parent == BIN and exe.name in node_executables()

    def wait_for_output(self, text: str, timeout: float = 10.0) -> bool:
        return self.wait_for(text, timeout)

    def wait(self, timeout: float = 30.0) -> int:
        """The exit code; a process still running after `timeout` s raises TimeoutExpired
        with its output, after one of our nodes printed its threads' stacks (SIGUSR1,
        nodes/common.run), and with every thread's native stack (a wait inside C code, as
        stop()'s message has it): a hang says where it hangs."""
        code = super().wait(timeout)
        if code is None:
            native = self.stacks(python=self.is_node)
            raise Hang(self.argv, timeout, output=self.text()[-6000:] + native)
        return code

    def stop(self, sig: int = signal.SIGINT, timeout: float = 60.0) -> int:
        """Signal this process (only it), wait, escalate to SIGKILL if it hangs (and raise).

        60 s is a hang guard (the wait ends when the process does): a node took 19 s to
        exit at load 27, and a SIGKILL after 10 s would fail a correct node. A hang raises Hang,
        whose message carries the output with the stacks the node printed on SIGUSR1
        (subprocess.TimeoutExpired's message leaves the output out: a CI run beside a second
        suite lost the stacks of a torque_node that did not stop within 60 s of SIGINT)."""
        try:
            return super().stop(sig, timeout, strict=True, dump=self.is_node)
        except subprocess.TimeoutExpired as exc:
            raise Hang(exc.cmd, exc.timeout, output=exc.output) from None


def start(executable: str, *ros_args: str, domain: int | None = None) -> NodeProcess:
    """Start a console script of this venv with `--ros-args *ros_args` (if any)."""
    return NodeProcess.script(executable, list(ros_args), ros_env(domain), _LOG_DIR,
                              split_stderr=True)


class Procs:
    """Every process a test starts; all killed (by PID) at teardown, even on failure.

    conftest's `procs` (one per test) and `module_procs` (one per module) fixtures hand one
    out and close it; start processes through it, never bare, so a failed test leaves none."""

    def __init__(self):
        self.items: list = []

    def add(self, p):
        self.items.append(p)
        return p

    def start(self, executable: str, *ros_args: str, domain: int | None = None) -> NodeProcess:
        return self.add(start(executable, *ros_args, domain=domain))

    def close(self) -> None:
        for p in self.items:
            proc = getattr(p, "proc", p)
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)


class Peer(_Peer):
    """An rclpy node inside the test process, on the same private domain as the children
    (forearm_dynamics.nodes.peer.Peer: its own Context, closed for good by close()); open
    ones are closed by release_test_domains() at the latest."""

    def __init__(self, name: str = "test_peer", domain: int | None = None):
        super().__init__(name, domain if domain is not None else domain_id())
        _open_peers.append(self)

    def endpoints(self, topic: str) -> str:
        """Who publishes and subscribes `topic` as this peer sees the graph, and whether its
        domain is this process's alone: said when a test finds an endpoint it did not make."""
        node = self.node
        held = [x for x in _test_leases + [_session_lease] if x is not None and x.domain == self.domain]
        lease = ("leased here" if any(x.exclusive for x in held) else
                 "shared: every id of its range was held" if held else "not leased here")

        def full(namespace: str, name: str) -> str:
            return f"{namespace.rstrip('/')}/{name}"

        def names(infos) -> str:
            return ", ".join(f"{full(i.node_namespace, i.node_name)} "
                             f"({i.qos_profile.reliability.name.lower()})" for i in infos) or "none"
        return (f"domain {self.domain} ({lease}); {topic} publishers: "
                f"{names(node.get_publishers_info_by_topic(topic))}; subscribers: "
                f"{names(node.get_subscriptions_info_by_topic(topic))}; nodes: "
                f"{sorted(full(ns, n) for n, ns in node.get_node_names_and_namespaces())}")

    def close(self) -> None:
        if self in _open_peers:
            _open_peers.remove(self)
        super().close()
