"""Two hosts (network namespaces joined by a veth pair, hostkit.py): the harness is torn
down after a failing test, nothing but the other host is reachable, and torques cross the
link (and do not with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: the hosts are really apart).

`make test-hosts` (root; CI runs it after `make test`, which leaves this tier out).
"""

from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
from pathlib import Path

import hostkit
import pytest
import rosproc
from support.two_host_replay import replay_in_b

from forearm_dynamics.processes import BIN

pytestmark = pytest.mark.hosts

_why = hostkit.can_make_hosts()
if _why:
    pytest.skip(_why, allow_module_level=True)


def host_env(domain: int, log_dir: Path, discovery: str = "SUBNET") -> dict[str, str]:
    """ROS environment for a process inside a namespace: UDP only (shared memory would
    carry the data past the veth between two namespaces of one machine)."""
    env = rosproc.processes.ros_env(domain, log_dir)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    return env


def _veth_rx_packets(host: hostkit.Host) -> int:
    out = host.run(["cat", f"/sys/class/net/{host.veth}/statistics/rx_packets"]).stdout
    return int(out.strip() or 0)


def test_teardown_after_a_failing_test_leaves_nothing():
    names = None
    sleeper = None
    with pytest.raises(RuntimeError, match="the test failed"), hostkit.TwoHosts() as h:
        names = (h.a.ns, h.b.ns, h.a.veth, h.b.veth)
        sleeper = h.a.start(["sleep", "600"], dict(os.environ), Path("/tmp") / f"{h.a.ns}.log")
        assert h.exists() and sleeper.poll() is None
        raise RuntimeError("the test failed")
    left = hostkit.our_namespaces()
    assert names[0] not in left and names[1] not in left, left
    assert not any(hostkit.veth_exists(n) for n in names[2:])
    assert sleeper.wait(timeout=10) is not None  # the process inside was ended


def test_teardown_after_an_interrupt_leaves_nothing():
    with pytest.raises(KeyboardInterrupt), hostkit.TwoHosts() as h:
        ns = (h.a.ns, h.b.ns)
        raise KeyboardInterrupt
    assert not set(ns) & set(hostkit.our_namespaces())


def test_stale_namespaces_of_a_killed_session_are_removed():
    """A session killed with SIGKILL cannot tear down; the next harness removes what it left."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    ns = f"{hostkit.PREFIX}{dead.pid}a"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    try:
        with hostkit.TwoHosts():
            assert ns not in hostkit.our_namespaces()
    finally:
        subprocess.run(["ip", "netns", "del", ns], check=False, capture_output=True)


def test_only_the_other_host_is_reachable():
    with hostkit.TwoHosts() as h:
        for host in (h.a, h.b):
            links = host.run(["ip", "-o", "link"]).stdout.splitlines()
            assert len(links) == 2 and ": lo:" in links[0] and host.veth in links[1], links
            routes = sorted(host.run(["ip", "route"]).stdout.split("\n"))
            routes = [r.split()[0] for r in routes if r.strip()]
            assert routes == ["192.0.2.0/30", "224.0.0.0/4"], routes  # no default route
        # connect() of a UDP socket sends nothing; it fails without a route
        code = ("import socket, sys\ns = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
                "try:\n    s.connect(('198.51.100.1', 9))\nexcept OSError as e:\n"
                "    print(e.errno)\n    sys.exit(0)\nprint('routed')\n")
        r = h.a.run([sys.executable, "-c", code])
        assert r.stdout.strip() == str(errno.ENETUNREACH), r
        # and the other host is there
        reach = ("import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); "
                 f"s.connect(('{hostkit.ADDR_B}', 9)); print('ok')")
        r = h.a.run([sys.executable, "-c", reach])
        assert r.stdout.strip() == "ok", r
    assert socket.gethostname()  # the root namespace is untouched (nothing to restore)


def _replay(h: hostkit.TwoHosts, tmp: Path, node_discovery: str, movements: str = "[1]") -> dict:
    """torque_node in A; trajectory_publisher + bag_recorder in B; B's bag as check_bag reads it.

    (support.two_host_replay)"""
    domain = rosproc.test_domain(102, 139)
    bag = tmp / f"b_{node_discovery}.mcap"
    node = h.a.start([str(BIN / "torque_node")], host_env(domain, tmp, node_discovery), tmp / "a_node.log")
    env_b = host_env(domain, tmp)
    rx0 = _veth_rx_packets(h.a)
    out = replay_in_b(h, node, env_b, tmp, bag, movements, subscriber_timeout=20.0)
    out["veth_rx"] = _veth_rx_packets(h.a) - rx0
    return out


def test_torques_cross_the_hosts_and_localhost_keeps_them_apart(tmp_path):
    with hostkit.TwoHosts() as h:
        ok = _replay(h, tmp_path / "subnet", "SUBNET")
    # check_bag's delivery count: every joint_states sample B sent has its torque in B's bag
    # (its torque accuracy verdict is the loopback pipeline's business: test_pipeline.py)
    assert ok["report"] is not None, ok["out"][-3000:]
    assert ok["report"]["delivery"]["lost"] == 0, ok["out"][-3000:]
    assert "received 1500, processed 1500" in ok["node_log"], ok["node_log"][-2000:]
    assert ok["veth_rx"] >= 1500, ok["veth_rx"]  # the samples came in over the veth
    with hostkit.TwoHosts() as h:
        apart = _replay(h, tmp_path / "localhost", "LOCALHOST")
    assert "received 0," in apart["node_log"], apart["node_log"][-2000:]
    assert apart["code"] != 0, apart["out"][-2000:]  # no torques recorded in B

