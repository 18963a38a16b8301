"""Two hosts on networks that are not a plain multicast LAN (hostkit.py; docs/two-hosts.md
"Running it"): without multicast, SUBNET discovery finds nothing, ROS_STATIC_PEERS or a Fast
DDS discovery server (the wheels' `fastdds discovery`) make the torques cross
(SYSTEM_DEFAULT with static peers does not); behind a
firewall that lets only the RTPS ports of the domain through, the torques cross and B sees
A's node, and with the ports of another domain, or without the user-data ports, nothing
crosses. The discovery-server run is the whole lab pipeline (torque_node in A; publisher
and recorder in B), and B's bag checks clean with check_bag.

`make test-hosts` (root; CI runs it after `make test`).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import hostkit
import pytest
import rosproc
from support.two_host_replay import replay_in_b

from forearm_dynamics.processes import BIN, rtps_port

pytestmark = pytest.mark.hosts

_why = hostkit.can_make_hosts()
if _why:
    pytest.skip(_why, allow_module_level=True)

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
DS_PORT = 11811  # Fast DDS's default discovery server port
#: Processes per host the firewall opens ports for (participant ids 0..3)
PARTICIPANTS = 4


def host_env(domain: int, log_dir: Path, **extra: str) -> dict[str, str]:
    """ROS environment inside a namespace: SUBNET discovery, UDP only (shared memory would
    carry the data past the veth between two namespaces of one machine)."""
    env = rosproc.processes.ros_env(domain, log_dir)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", FASTDDS_BUILTIN_TRANSPORTS="UDPv4")
    env.update(extra)
    return env


def rtps_ports(domain: int, participants: int = PARTICIPANTS, user: bool = True) -> list[int]:
    """UDP ports RTPS listens on for a domain (processes.rtps_port): discovery multicast,
    and discovery and (`user`) user-data unicast of participants 0..participants-1 (one per
    ROS process)."""
    ports = [rtps_port(domain)] + [rtps_port(domain, p) for p in range(participants)]
    if user:
        ports += [rtps_port(domain, p, user=True) for p in range(participants)]
    return sorted(ports)


#: Fast DDS's "unique network flow" readers listen on the first free port of portBase - 400
#: .. portBase (7000-7399) whatever the domain: one per process of these wheels (measured,
#: `ss -uanp`: each rclpy process listens on 7000, the next one on 7001); ROS's graph topic
#: crosses there, so without them the other host's node names are not seen.
FLOW_PORTS = list(range(7000, 7000 + PARTICIPANTS))


def firewall(host: hostkit.Host, ports: list[int]) -> None:
    """Only these UDP ports come in over the veth; every other UDP packet is counted, dropped."""
    allowed = ", ".join(map(str, ports))
    host.nft("table inet fdfw {\n"
             "  chain input { type filter hook input priority 0;\n"
             f"    iifname \"{host.veth}\" udp dport {{ {allowed} }} accept\n"
             f"    iifname \"{host.veth}\" meta l4proto udp counter drop\n"
             "  }\n}\n")


def start_node(h: hostkit.TwoHosts, env: dict[str, str], tmp: Path, hang_s: float = 180.0):
    """torque_node in host A, returned once it subscribes (its first log line), so that the
    short waits of the cases that expect nothing time discovery, not a loaded start-up."""
    log = tmp / "a_node.log"
    node = h.a.start([str(BIN / "torque_node")], env, log)
    deadline = time.monotonic() + hang_s
    while "/joint_states -> /joint_torques" not in log.read_text(errors="replace"):
        assert node.poll() is None and time.monotonic() < deadline, log.read_text()[-2000:]
        time.sleep(0.1)
    return node


def ask(h: hostkit.TwoHosts, env: dict[str, str], timeout_s: float) -> subprocess.CompletedProcess:
    """examples/torque_client.py in host B: exit 0 once torque_node in A answered its posture;
    1 'no torque_node' (never matched) or 'did not answer' (matched, no torque) after timeout_s."""
    code = (f"import sys; sys.path.insert(0, {str(EXAMPLES)!r}); import torque_client; "
            f"sys.exit(torque_client.main({timeout_s}))")
    return h.b.run([sys.executable, "-c", code], env=env, timeout=timeout_s + 120)


_NAMES = ("import sys, time, rclpy\nrclpy.init()\nn = rclpy.create_node('probe')\n"
          "end = time.monotonic() + float(sys.argv[1])\n"
          "while time.monotonic() < end and 'torque_node' not in n.get_node_names():\n"
          "    rclpy.spin_once(n, timeout_sec=0.1)\nprint(sorted(n.get_node_names()))\n")


def node_names(h: hostkit.TwoHosts, env: dict[str, str], timeout_s: float) -> str:
    """The ROS node names host B sees (the graph, carried by ROS's own discovery topic)."""
    return h.b.run([sys.executable, "-c", _NAMES, str(timeout_s)], env=env,
                   timeout=timeout_s + 120).stdout.strip()


@pytest.mark.parametrize("discovery", ["SUBNET", "SYSTEM_DEFAULT"])
def test_without_multicast_automatic_discovery_finds_nothing(tmp_path, discovery):
    """The harness really has no multicast: A announces (the drop counter counts it) and
    nobody hears; SUBNET discovery is multicast only, so the client never matches. With
    SYSTEM_DEFAULT, rmw_fastrtps ignores ROS_STATIC_PEERS (it adds them for LOCALHOST and
    SUBNET only): nothing either, though both hosts name the other."""
    domain = rosproc.test_domain(102, 139)
    peers = discovery == "SYSTEM_DEFAULT"
    env_a = host_env(domain, tmp_path, ROS_AUTOMATIC_DISCOVERY_RANGE=discovery,
                     **({"ROS_STATIC_PEERS": hostkit.ADDR_B} if peers else {}))
    env_b = host_env(domain, tmp_path, ROS_AUTOMATIC_DISCOVERY_RANGE=discovery,
                     **({"ROS_STATIC_PEERS": hostkit.ADDR_A} if peers else {}))
    with hostkit.TwoHosts(multicast=False) as h:
        start_node(h, env_a, tmp_path)
        r = ask(h, env_b, 10)
        dropped = h.a.multicast_dropped()
    assert r.returncode == 1 and "no torque_node" in r.stderr, r
    assert dropped > 0, dropped


def test_static_peers_cross_without_multicast(tmp_path):
    """ROS_STATIC_PEERS (Jazzy; rmw_fastrtps adds them as unicast initial peers) on one host
    is enough: A learns B from B's unicast announcement and answers it."""
    domain = rosproc.test_domain(102, 139)
    with hostkit.TwoHosts(multicast=False) as h:
        start_node(h, host_env(domain, tmp_path), tmp_path)
        r = ask(h, host_env(domain, tmp_path, ROS_STATIC_PEERS=hostkit.ADDR_A), 60)
        dropped = h.b.multicast_dropped()
    assert r.returncode == 0 and "elbow_flexion" in r.stdout, r
    assert dropped > 0, dropped  # multicast was tried (SUBNET keeps it) and went nowhere


def test_fastdds_discovery_needs_the_venv_first_on_path(tmp_path):
    """`fastdds` (a sh script of the Fast DDS wheel) runs `python3` from PATH: the venv's
    python sets the library path the server binary needs (ros_wheels_bootstrapper; the
    discovery-server test below starts it so); another python3 leaves the binary without
    libfastrtps. Docs: activate the venv first. Run inside host A (should it start after all,
    it listens only there)."""
    other = tmp_path / "bin"  # python3 = the interpreter the venv was made from
    other.mkdir()
    (other / "python3").symlink_to(Path(sys.base_prefix) / "bin" / "python3")
    env = {**rosproc.processes.ros_env(rosproc.test_domain(102, 139), tmp_path),
           "PATH": f"{other}{os.pathsep}/usr/bin:/bin"}
    with hostkit.TwoHosts() as h:
        r = h.a.run([str(BIN / "fastdds"), "discovery", "-i", "0", "-l", hostkit.ADDR_A],
                    env=env, timeout=60)
    assert "libfastrtps" in r.stdout + r.stderr and "Server is running" not in r.stdout, r


def _pipeline(h: hostkit.TwoHosts, tmp: Path, env_a: dict, env_b: dict, movements: str) -> dict:
    """torque_node in A; trajectory_publisher + bag_recorder in B; check_bag on B's bag
    (support.two_host_replay)."""
    node = start_node(h, env_a, tmp)
    return replay_in_b(h, node, env_b, tmp, tmp / "b.mcap", movements, subscriber_timeout=60.0,
                       hang_s=240.0)


def test_discovery_server_pipeline_without_multicast_checks_clean(tmp_path):
    """The lab's deployment on a network without multicast: `fastdds discovery` (from the
    wheels) in A, every process a client (ROS_DISCOVERY_SERVER); 6 movements at 1 kHz from B,
    B records, and check_bag passes B's bag (exit 0: nothing lost, every recorded torque
    what the model gives for the recorded joint_states)."""
    domain = rosproc.test_domain(102, 139)
    ds = {"ROS_DISCOVERY_SERVER": f"{hostkit.ADDR_A}:{DS_PORT}"}
    with hostkit.TwoHosts(multicast=False) as h:
        server = start_server(h, domain, tmp_path)
        res = _pipeline(h, tmp_path, host_env(domain, tmp_path, **ds), host_env(domain, tmp_path, **ds),
                        "[1, 2, 3, 6, 7, 8]")
        server_alive = server.poll() is None
        dropped = (h.a.multicast_dropped(), h.b.multicast_dropped())
    server_log = (tmp_path / "a_server.log").read_text()
    assert "Participant Type:   SERVER" in server_log and server_alive, server_log
    assert dropped == (0, 0), dropped  # discovery-server clients never multicast
    assert res["report"] is not None, res["out"][-3000:]
    delivery = res["report"]["delivery"]
    assert delivery["joint_states"] > 0 and delivery["lost"] == 0, delivery
    assert res["code"] == 0 and res["report"]["exit_code"] == 0, res["out"][-3000:]
    assert res["report"]["failures"] == [], res["report"]["failures"]


def start_server(h: hostkit.TwoHosts, domain: int, tmp: Path):
    """`fastdds discovery` in host A as a user runs it: the venv's bin first on PATH."""
    env = {**host_env(domain, tmp), "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}"}
    return h.a.start(["fastdds", "discovery", "-i", "0", "-l", hostkit.ADDR_A, "-p",
                      str(DS_PORT)], env, tmp / "a_server.log")


def test_discovery_server_behind_the_firewall(tmp_path):
    """No multicast, a discovery server in A, and the firewall of the table: the server's
    port on A, the domain's RTPS and unique-flow ports on both; the torques cross and no
    UDP packet came in on another port."""
    domain = rosproc.test_domain(102, 139)
    ds = {"ROS_DISCOVERY_SERVER": f"{hostkit.ADDR_A}:{DS_PORT}"}
    with hostkit.TwoHosts(multicast=False) as h:
        firewall(h.a, rtps_ports(domain) + FLOW_PORTS + [DS_PORT])
        firewall(h.b, rtps_ports(domain) + FLOW_PORTS)
        start_server(h, domain, tmp_path)
        start_node(h, host_env(domain, tmp_path, **ds), tmp_path)
        r = ask(h, host_env(domain, tmp_path, **ds), 60)
        dropped = (h.a.counters("fdfw"), h.b.counters("fdfw"))
    assert r.returncode == 0 and "elbow_flexion" in r.stdout, r
    assert dropped == ([0], [0]), dropped


def test_firewall_with_only_the_rtps_ports_lets_the_torques_through(tmp_path):
    """Both hosts drop every incoming UDP packet but the domain's RTPS ports and the
    unique-flow ports: the torques cross, B sees A's node, and not one UDP packet went to
    another port (the port list is complete for these wheels)."""
    domain = rosproc.test_domain(102, 139)
    with hostkit.TwoHosts() as h:
        for host in (h.a, h.b):
            firewall(host, rtps_ports(domain) + FLOW_PORTS)
        start_node(h, host_env(domain, tmp_path), tmp_path)
        r = ask(h, host_env(domain, tmp_path), 60)
        names = node_names(h, host_env(domain, tmp_path), 30)
        dropped = (h.a.counters("fdfw"), h.b.counters("fdfw"))
    assert r.returncode == 0 and "elbow_flexion" in r.stdout, r
    assert "torque_node" in names, names
    assert dropped == ([0], [0]), dropped


def test_firewall_missing_ports_stop_what_they_carry(tmp_path):
    """The same firewall computed for another domain: no discovery at all; with the
    discovery ports only (no user unicast): the endpoints match but no torque arrives;
    without the unique-flow ports: the torques cross but B does not see A's node name."""
    domain, other = rosproc.test_domain(102, 139), rosproc.test_domain(102, 139)
    assert domain != other
    cases = {"wrong": rtps_ports(other) + FLOW_PORTS,
             "no_user": rtps_ports(domain, user=False) + FLOW_PORTS,
             "no_flows": rtps_ports(domain)}
    got = {}
    for name, ports in cases.items():
        tmp = tmp_path / name
        with hostkit.TwoHosts() as h:
            for host in (h.a, h.b):
                firewall(host, ports)
            start_node(h, host_env(domain, tmp), tmp)
            r = ask(h, host_env(domain, tmp), {"wrong": 10, "no_user": 20}.get(name, 60))
            names = node_names(h, host_env(domain, tmp), 8) if name == "no_flows" else ""
            got[name] = (r, names, h.a.counters("fdfw")[0])
    r, _, dropped = got["wrong"]
    assert r.returncode == 1 and "no torque_node" in r.stderr and dropped > 0, got["wrong"]
    r, _, dropped = got["no_user"]
    assert r.returncode == 1 and "did not answer" in r.stderr and dropped > 0, got["no_user"]
    r, names, dropped = got["no_flows"]
    assert r.returncode == 0 and "elbow_flexion" in r.stdout, r
    assert "probe" in names and "torque_node" not in names and dropped > 0, got["no_flows"]
