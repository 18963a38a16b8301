"""The process toolkit (forearm_dynamics/processes.py) on plain Python children: the ROS
environment it hands out, logs that never collide, waiting, and stopping by PID only
(SIGINT, then SIGKILL for a child that ignores it)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from sensor_msgs.msg import JointState

from benchmarks.procstat import Sampler, proc_stat
from forearm_dynamics.processes import Child, claim_domain, lease_domain, ros_env

pytestmark = pytest.mark.cli

#: Prints "ready", then sleeps; with "stubborn" it ignores SIGINT; with "usr1" it prints on SIGUSR1
#: (as our nodes print their stacks).
SLEEPER = (
    "import signal, sys, time\n"
    "if 'stubborn' in sys.argv: signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "if 'usr1' in sys.argv: signal.signal(signal.SIGUSR1, lambda *a: print('usr1 seen', flush=True))\n"
    "print('ready', flush=True); print('to stderr', file=sys.stderr, flush=True)\n"
    "time.sleep(60)\n"
)


def sleeper(tmp_path, *args: str, split: bool = False) -> Child:
    return Child("sleeper", [sys.executable, "-c", SLEEPER, *args], ros_env(42, tmp_path), tmp_path,
                 split_stderr=split)


def test_ros_env_is_loopback_in_its_own_domain(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", "0")
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", "/elsewhere.xml")
    env = ros_env(42, tmp_path, {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"})
    assert env["ROS_DOMAIN_ID"] == "42" and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env["ROS_LOG_DIR"] == str(tmp_path) and env["PATH"] == os.environ["PATH"]
    assert "RMW_IMPLEMENTATION" not in env and "FASTRTPS_DEFAULT_PROFILES_FILE" not in env
    assert env["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"  # only what the caller passes
    for bad in (0, 233, -1):
        with pytest.raises(ValueError, match="1..232"):
            ros_env(bad, tmp_path)


HOLDER = (  # leases a domain of 225..226 from a given start, prints it, holds it
    "import sys, time\n"
    "from pathlib import Path\n"
    "from forearm_dynamics.processes import lease_domain\n"
    "lease = lease_domain(225, 226, int(sys.argv[1]), Path(sys.argv[2]))\n"
    "print(lease.domain, lease.exclusive, flush=True); time.sleep(60)\n"
)


def test_lease_domain_is_exclusive_across_processes_until_released(tmp_path) -> None:
    """A second session never gets a domain another process holds; a dead holder's domain
    is free again (the kernel drops its lock); all held: shared, and said so."""
    locks = tmp_path / "locks"  # this test's own lock files: another session may run it too
    holder = Child("holder", [sys.executable, "-c", HOLDER, "0", str(locks)], ros_env(42, tmp_path),
                   tmp_path)
    try:
        assert holder.wait_for("True", 30), holder.text()
        held = int(holder.stdout().split()[0])
        mine = lease_domain(225, 226, held - 225, locks)  # asks for the held one first
        assert mine.exclusive and mine.domain != held and mine.domain in (225, 226)
        full = lease_domain(225, 226, None, locks)
        assert not full.exclusive and full.domain in (225, 226)
        mine.release()
        again = lease_domain(225, 226, held - 225, locks)
        assert again.exclusive and again.domain == mine.domain
        again.release()
    finally:
        holder.stop(signal.SIGKILL)
    after = lease_domain(225, 226, held - 225, locks)
    assert after.exclusive and after.domain == held
    after.release()


def test_claim_domain_moves_off_a_held_domain_and_says_so(tmp_path, capsys) -> None:
    """The demo's and benchmarks' domain: the one asked for when free; when another run
    holds it, the next free one of its range, in one line; 0 and 233+ refused."""
    locks = tmp_path / "locks"
    free = claim_domain(73, "demo", locks)
    assert free.domain == 73 and free.exclusive and capsys.readouterr().err == ""
    moved = claim_domain(73, "demo", locks)  # 73 is held (by `free`)
    assert moved.exclusive and moved.domain == 74
    assert capsys.readouterr().err == ("demo: ROS domain 73 is in use by another forearm_dynamics "
                                       "run on this machine; using 74\n")
    edge = claim_domain(232, "bench", locks)
    again = claim_domain(232, "bench", locks)  # wraps within 215..232, never into 233+
    assert edge.domain == 232 and again.domain == 215
    for lease in (free, moved, edge, again):
        lease.release()
    for bad in (0, 233, -1):
        with pytest.raises(ValueError, match="1..232"):
            claim_domain(bad, "demo", locks)


def test_test_domains_stay_leased_until_released() -> None:
    """A test's second domain does not free its first (a module's harness may still run on
    it): both stay held, in this process and for any other, until release_test_domains()."""
    import rosproc

    first, second = rosproc.test_domain(102, 139), rosproc.test_domain(102, 139)
    assert first != second
    for domain in (first, second):
        other = lease_domain(domain, domain)  # the only id of its range: held, so shared
        assert not other.exclusive, domain
    rosproc.release_test_domains()
    assert rosproc._test_leases == []


#: another process's lease of one free id of the tests' range, held for 3 s
TEST_DOMAIN_HOLDER = """
import sys, time
from forearm_dynamics.processes import lease_domain
lease = lease_domain(102, 139)
print(lease.domain, lease.exclusive, flush=True)
time.sleep(3.0)
"""


def test_a_test_domain_is_never_shared_it_waits_for_a_free_one() -> None:
    """When every id of its range is held, lease_domain shares one (a demo can live with
    that); a test's domain must not be shared (another session's nodes would answer in it):
    test_domain waits until the holder lets go."""
    import rosproc

    holder = subprocess.Popen([sys.executable, "-c", TEST_DOMAIN_HOLDER], stdout=subprocess.PIPE,
                              text=True)
    try:
        domain, exclusive = holder.stdout.readline().split()
        assert exclusive == "True"
        t0 = time.monotonic()
        got = rosproc.test_domain(int(domain), int(domain))  # its only id: held by the holder
        waited = time.monotonic() - t0
        assert got == int(domain) and rosproc._test_leases[-1].exclusive
        assert holder.poll() is not None and waited > 1.0, waited  # after the holder ended
    finally:
        holder.kill()
        holder.wait()
        rosproc.release_test_domains()


def _node_names(peer) -> list[str]:
    return [name for name, _ in peer.node.get_node_names_and_namespaces()]


def test_a_closed_peer_leaves_the_graph_and_a_released_domain_closes_its_peers() -> None:
    """A closed Peer's node is gone from the graph as another participant sees it, and
    release_test_domains() closes a peer its test never closed (a harness whose start
    failed): else the next holder of the lease finds a node it did not start. Before
    Peer.close shut its executor down, the node stayed for the life of the process."""
    import rosproc

    domain = rosproc.test_domain(102, 139)
    try:
        closed = rosproc.Peer("closed_peer", domain=domain)
        left = rosproc.Peer("left_open_peer", domain=domain)
        for peer in (closed, left):
            peer.node.create_publisher(JointState, "joint_states", 10)
        view = rosproc.Peer("view_peer", domain=domain)
        names = lambda: _node_names(view)
        assert view.spin_until(lambda: {"closed_peer", "left_open_peer"} <= set(names()),
                               rosproc.STARTUP_S), names()
        for peer in (closed, left):  # as a harness's peer does: then its executor holds it
            peer.spin_for(0.2)
        closed.close()
        # hang guards, not timings: a node that stays, stays for good
        assert view.spin_until(lambda: "closed_peer" not in names(), 30.0), names()
        assert "left_open_peer" in names()
        view.domain = -1  # not on a released domain to release_test_domains(): it watches
        rosproc.release_test_domains()
        assert left not in rosproc._open_peers and view in rosproc._open_peers
        assert view.spin_until(lambda: "left_open_peer" not in names(), 30.0), names()
        view.close()
    finally:
        rosproc.release_test_domains()


def test_a_peer_spun_in_the_background_receives_and_its_close_ends_the_thread() -> None:
    """forearm_dynamics.nodes.peer.Peer.spin_in_background (the benchmarks' way): a message
    reaches its callback while the caller does nothing but wait, and close() ends the spin
    thread and leaves the graph (the base class of the tests' Peer above)."""
    import rosproc

    from forearm_dynamics.nodes.peer import Peer

    domain = rosproc.test_domain(102, 139)
    got: list[JointState] = []
    sender = rosproc.Peer("sender_peer", domain=domain)
    background = Peer("background_peer", domain)
    try:
        background.node.create_subscription(JointState, "joint_states", got.append, 10)
        background.spin_in_background()
        pub = sender.node.create_publisher(JointState, "joint_states", 10)
        assert sender.spin_until(lambda: pub.get_subscription_count() == 1, rosproc.STARTUP_S)
        deadline = time.monotonic() + rosproc.STARTUP_S  # a hang guard
        while not got and time.monotonic() < deadline:
            pub.publish(JointState(name=["a"], position=[1.0]))
            time.sleep(0.1)  # this thread never spins the background peer
        assert got and list(got[0].name) == ["a"]
        thread = background._thread
        background.close()
        assert not thread.is_alive() and background.closed
        background.close()  # a second close does nothing
        assert sender.spin_until(lambda: "background_peer" not in _node_names(sender), 30.0)
    finally:
        background.close()
        sender.close()
        rosproc.release_test_domains()


def test_start_wait_for_and_stop(tmp_path) -> None:
    a, b = sleeper(tmp_path), sleeper(tmp_path, split=True)
    try:
        assert a.log != b.log and a.log.name == "sleeper.log" and b.log.name == "sleeper-2.log"
        assert a.wait_for("ready", 30) and b.wait_for("to stderr", 30)
        assert "to stderr" in a.stdout() and a.stderr() == ""  # together unless split
        assert "to stderr" not in b.stdout() and b.stderr().strip() == "to stderr"
        assert a.running() and a.wait(0.1) is None and not a.wait_for("never printed", 0.3)
        assert a.wait_for(r"rea[d]y", 1, regex=True) and not a.wait_for(r"rea[d]y", 0.3)
        assert not a.wait_for(r"ready\d", 0.3, regex=True)
        assert proc_stat(a.pid) is not None and proc_stat(a.pid).rss_kb > 0
    finally:
        assert a.stop() == -signal.SIGINT or a.returncode == 1  # KeyboardInterrupt in sleep
        b.stop()
    assert not a.running() and proc_stat(a.pid) is None
    assert a.stop() == a.returncode  # stopping twice is harmless


#: Ignores SIGINT as a command started with `&` by a non-interactive shell does (POSIX), then
#: starts a sleeper from its main thread and one from another thread, and stops each by SIGINT.
IGNORING_PARENT = (
    "import signal, sys, threading\n"
    "from pathlib import Path\n"
    "from forearm_dynamics.processes import Child, ros_env\n"
    "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "d = Path(sys.argv[1])\n"
    "def run(name):\n"
    "    c = Child(name, [sys.executable, '-c', sys.argv[2]], ros_env(42, d), d)\n"
    "    assert c.wait_for('ready', 60), c.text()\n"
    "    print(name, c.stop(timeout=30), flush=True)\n"
    "run('main')\n"
    "t = threading.Thread(target=run, args=('thread',)); t.start(); t.join()\n"
    "print('parent still ignores:', signal.getsignal(signal.SIGINT) == signal.SIG_IGN)\n"
)


def test_children_of_a_parent_ignoring_sigint_still_stop_on_it(tmp_path) -> None:
    """`make test &` from a script ran every test with SIGINT ignored, and children inherit
    an ignored signal: the sleeper of test_start_wait_for_and_stop ignored stop()'s SIGINT
    and was killed (-9) at the timeout, which looked like a loaded machine. Child starts its
    process with SIGINT at its default action whatever the parent's; the parent's own
    disposition is left as it was."""
    res = subprocess.run([sys.executable, "-c", IGNORING_PARENT, str(tmp_path), SLEEPER],
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines() == [f"main {-signal.SIGINT}", f"thread {-signal.SIGINT}",
                                       "parent still ignores: True"], res.stdout + res.stderr


def test_stubborn_child_is_killed_and_strict_raises(tmp_path) -> None:
    c = sleeper(tmp_path, "stubborn")
    assert c.wait_for("ready", 30)
    assert c.stop(timeout=0.5) == -signal.SIGKILL
    d = sleeper(tmp_path, "stubborn")
    assert d.wait_for("ready", 30)
    with pytest.raises(subprocess.TimeoutExpired):
        d.stop(timeout=0.5, strict=True)
    assert not d.running() and d.returncode == -signal.SIGKILL


def test_a_hang_names_its_native_stacks(tmp_path) -> None:
    """stop(dump=True, strict=True) on a process that ignores SIGINT: the raised message holds
    its output (what it printed on SIGUSR1) and every thread's native stack from gdb (part of
    these machines: /work/.library/env), the main thread first, blocked in its sleep."""
    assert shutil.which("gdb"), "gdb: a hang's native stacks need it"
    c = sleeper(tmp_path, "stubborn", "usr1")
    assert c.wait_for("ready", 30)
    with pytest.raises(subprocess.TimeoutExpired) as info:
        c.stop(timeout=0.5, strict=True, dump=True)
    out = info.value.output
    assert "usr1 seen" in out, out
    native = out.split("native stacks (gdb, ", 1)[1]
    assert native.split("\n")[1].startswith("Thread 1 "), native[:400]
    assert "sleep" in native.split("\nThread ")[1], native[:2000]  # the main thread's frames
    assert not c.running() and c.returncode == -signal.SIGKILL


def test_a_test_wait_past_its_timeout_names_native_stacks(tmp_path) -> None:
    """rosproc.NodeProcess.wait() on a process still running: Hang, whose message holds its
    output and its threads' native stacks, as stop()'s does; the process is left running."""
    import rosproc

    node = rosproc.NodeProcess("sleeper", [sys.executable, "-c", SLEEPER], ros_env(42, tmp_path),
                               tmp_path)
    try:
        assert node.wait_for("ready", 30)
        # the venv's python is no node of ours: SIGUSR1 would have ended it, stacks untaken
        assert not node.is_node and {"torque_node", "muscle_node"} <= rosproc.node_executables()
        with pytest.raises(rosproc.Hang) as info:
            node.wait(timeout=0.2)
        native = str(info.value).split("native stacks (gdb, ", 1)[1]
        assert "ready" in str(info.value)
        assert "sleep" in native.split("\nThread ")[1], native[:2000]
        assert node.running()
    finally:
        node.stop(signal.SIGKILL)


def test_sampler_reads_cpu_and_memory(tmp_path) -> None:
    burn = "import time\nt = time.time() + 1.5\nwhile time.time() < t: pass\n"
    burner = Child("burner", [sys.executable, "-c", burn], ros_env(42, tmp_path), tmp_path)
    with Sampler({"burner": burner.pid}, period=0.1) as sampler:
        burner.wait(30)  # exited, not yet reaped: a zombie, which has no memory to sample
    s = sampler.series["burner"]
    assert len(s.t) >= 5 and all(r > 0 for r in s.rss)
    busy = s.cpu_percent(s.t[0], s.t[-1])
    assert busy is not None and busy > 20  # a busy loop, even on a loaded machine
    assert s.peak_hwm_kb() >= max(s.rss) and len(sampler.load) >= 5


def test_an_exited_unreaped_child_is_not_sampled(tmp_path) -> None:
    """A zombie keeps its /proc/<pid>/stat but has no memory lines: no sample, not zeros."""
    quick = Child("quick", [sys.executable, "-c", "pass"], ros_env(42, tmp_path), tmp_path)
    for _ in range(200):  # poll() would reap it: watch /proc instead
        with open(f"/proc/{quick.pid}/stat", encoding="ascii") as fh:
            if fh.read().rsplit(")", 1)[1].split()[0] == "Z":
                break
        time.sleep(0.05)
    else:
        pytest.fail("the child never exited")
    assert proc_stat(quick.pid) is None
    assert quick.wait(10) == 0
