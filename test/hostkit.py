"""Two hosts on one machine: two network namespaces joined by a veth pair (make test-hosts).

    with TwoHosts() as hosts:
        a = hosts.a.start(["torque_node", ...], env)       # a process inside host A
        hosts.a.loss(1)                                     # drop 1 % of A's incoming UDP
    with TwoHosts(multicast=False) as hosts:                # a network without multicast
        hosts.b.nft("table inet fw { ... }")                # any rule set (a firewall)

The pair has addresses in 192.0.2.0/30 (RFC 5737 TEST-NET-1: documentation only, never
routed anywhere) and a multicast route (224.0.0.0/4) on the veth; each namespace has its
own loopback and no other interface or route, so nothing but the other host is reachable
from inside, and nothing from outside reaches in. Needs root (CAP_NET_ADMIN) and `ip`;
`nft` (nftables, for the loss, multicast and firewall rules) is installed with apt-get when missing.

Teardown always runs: the context manager's exit (also after a failing test or a
KeyboardInterrupt) kills every process inside the namespaces (by PID, from `ip netns pids`:
only processes that live in namespaces this harness made) and deletes both namespaces,
which deletes the veth pair with them. Namespaces left by a killed session (the name holds
the owning PID) are removed by the next harness whose owner is gone.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

PREFIX = "fdh"  # fdh<pid>a / fdh<pid>b: <= 15 characters for the veth names too
SUBNET = "192.0.2.0/30"
ADDR_A, ADDR_B = "192.0.2.1", "192.0.2.2"


def _run(*argv: str, check: bool = True, timeout: float = 30.0) -> subprocess.CompletedProcess:
    return subprocess.run(argv, check=check, capture_output=True, text=True, timeout=timeout)


def can_make_hosts() -> str | None:
    """None if this process can make namespaces; else why not (for a skip reason)."""
    if os.geteuid() != 0:
        return "needs root (CAP_NET_ADMIN) to make network namespaces"
    if shutil.which("ip") is None:
        return "needs iproute2 (`ip`)"
    return None


def ensure_nft() -> str:
    """The nft binary; installs Debian's nftables when missing (root, as CI is)."""
    path = shutil.which("nft")
    if path:
        return path
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    # a concurrent make setup installing chromium holds apt's locks for minutes: wait for it
    # (the Makefile's flock file), and for any other apt's lock
    locked = ["flock", "-w", "900", "/tmp/forearm_dynamics-apt.lock", "apt-get", "-o",
              "DPkg::Lock::Timeout=600"]
    subprocess.run([*locked, "update", "-q"], check=False, capture_output=True, env=env, timeout=1800)
    subprocess.run([*locked, "install", "-y", "-q", "nftables"], check=True, capture_output=True,
                   env=env, timeout=1800)
    path = shutil.which("nft") or "/usr/sbin/nft"
    if not Path(path).exists():
        raise RuntimeError("nftables installed but nft not found")
    return path


def our_namespaces() -> list[str]:
    out = _run("ip", "netns", "list", check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.startswith(PREFIX)]


def _owner(ns: str) -> int | None:
    digits = ns[len(PREFIX):-1]
    return int(digits) if digits.isdigit() else None


def remove_stale() -> list[str]:
    """Namespaces of ours whose owning process is gone (a killed session): removed."""
    removed = []
    for ns in our_namespaces():
        pid = _owner(ns)
        if pid is None or pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
            continue  # its owner runs: not ours to remove
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        _kill_inside(ns)
        _run("ip", "netns", "del", ns, check=False)
        removed.append(ns)
    return removed


def _kill_inside(ns: str) -> None:
    pids = [int(p) for p in _run("ip", "netns", "pids", ns, check=False).stdout.split()]
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


@dataclass
class Host:
    """One namespace: run commands in it, drop a share of its incoming UDP."""

    ns: str
    addr: str
    veth: str
    procs: list[subprocess.Popen] = field(default_factory=list)

    def argv(self, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.ns, *argv]

    def run(self, argv: list[str], timeout: float = 30.0, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(self.argv(argv), check=False, capture_output=True, text=True,
                              timeout=timeout, **kw)

    def start(self, argv: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("wb") as out:
            p = subprocess.Popen(self.argv(argv), env=env, stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL)
        self.procs.append(p)
        return p

    def loss(self, percent: float, directions: tuple[str, ...] = ("input",)) -> None:
        """Drop `percent` % of this host's UDP packets at random (nftables numgen), on
        input and/or output; 0 removes the rules."""
        nft = ensure_nft()
        table = "fdloss"
        self.run([nft, "delete", "table", "inet", table])  # none yet: fails, fine
        if percent <= 0:
            return
        n = round(percent)
        if abs(n - percent) > 1e-9 or not 0 < n <= 100:
            raise ValueError(f"loss must be an integer percentage, got {percent}")
        cmds = [["add", "table", "inet", table]]
        for d in directions:
            if d not in ("input", "output"):
                raise ValueError(f"direction must be input or output, got {d!r}")
            cmds += [["add", "chain", "inet", table, d,
                      "{", "type", "filter", "hook", d, "priority", "0", ";", "}"],
                     ["add", "rule", "inet", table, d, "meta", "l4proto", "udp",
                      "numgen", "random", "mod", "100", "<", str(n), "counter", "drop"]]
        for cmd in cmds:
            r = self.run([nft, *cmd])
            if r.returncode:
                raise RuntimeError(f"nft {' '.join(cmd)}: {r.stderr.strip()}")

    def nft(self, ruleset: str) -> None:
        """Load an nftables rule set (`nft -f` syntax) into this host's namespace; it goes
        with the namespace at teardown."""
        r = self.run([ensure_nft(), "-f", "/dev/stdin"], input=ruleset)
        if r.returncode:
            raise RuntimeError(f"{self.ns}: nft -f: {r.stderr.strip()}\n{ruleset}")

    def counters(self, table: str) -> list[int]:
        """Packets counted by each `counter` of an inet table, in rule order."""
        out = self.run([ensure_nft(), "list", "table", "inet", table]).stdout
        return [int(part.split()[0]) for part in out.split("counter packets ")[1:]]

    def block_multicast(self) -> None:
        """Drop every IPv4 multicast packet this host sends or receives: a network without
        multicast (many Wi-Fi, cloud and VPN networks). The multicast route stays, so DDS
        still sends its announcements and the counters show them dropped."""
        self.nft("table inet fdnomcast {\n"
                 "  chain output { type filter hook output priority 0; ip daddr 224.0.0.0/4 counter drop; }\n"
                 "  chain input { type filter hook input priority 0; ip daddr 224.0.0.0/4 counter drop; }\n"
                 "}\n")

    def multicast_dropped(self) -> int:
        """Multicast packets block_multicast's rules dropped so far."""
        return sum(self.counters("fdnomcast"))

    def dropped(self) -> int:
        """Packets the loss rules dropped so far (0 without rules)."""
        nft = ensure_nft()
        out = self.run([nft, "list", "table", "inet", "fdloss"]).stdout
        return sum(int(part.split()[0]) for part in out.split("counter packets ")[1:])


class TwoHosts:
    """Two namespaces A and B joined by a veth pair in SUBNET; always torn down.
    multicast=False: both hosts drop all multicast (Host.block_multicast)."""

    def __init__(self, multicast: bool = True) -> None:
        self.multicast = multicast
        why = can_make_hosts()
        if why:
            raise RuntimeError(why)
        base = f"{PREFIX}{os.getpid()}"
        self.a = Host(f"{base}a", ADDR_A, f"{base}a")
        self.b = Host(f"{base}b", ADDR_B, f"{base}b")

    def __enter__(self) -> Self:
        remove_stale()
        try:
            self._make()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _make(self) -> None:
        a, b = self.a, self.b
        for h in (a, b):
            _run("ip", "netns", "add", h.ns)
        _run("ip", "link", "add", a.veth, "netns", a.ns, "type", "veth", "peer", "name", b.veth,
             "netns", b.ns)
        for h in (a, b):
            for cmd in (["ip", "link", "set", "lo", "up"],
                        ["ip", "addr", "add", f"{h.addr}/30", "dev", h.veth],
                        ["ip", "link", "set", h.veth, "up", "multicast", "on"],
                        ["ip", "route", "add", "224.0.0.0/4", "dev", h.veth]):
                r = h.run(cmd)
                if r.returncode:
                    raise RuntimeError(f"{h.ns}: {' '.join(cmd)}: {r.stderr.strip()}")
            if not self.multicast:
                h.block_multicast()

    def close(self) -> None:
        """Kill every process inside, delete both namespaces (the veth pair goes with them)."""
        for h in (self.a, self.b):
            for p in h.procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            deadline = time.monotonic() + 10
            for p in h.procs:
                try:
                    p.wait(timeout=max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(timeout=10)
        for h in (self.a, self.b):
            if h.ns in our_namespaces():
                _kill_inside(h.ns)
                _run("ip", "netns", "del", h.ns, check=False)

    def exists(self) -> bool:
        names = our_namespaces()
        return self.a.ns in names or self.b.ns in names


def veth_exists(name: str) -> bool:
    """Is there an interface of that name in this (the root) namespace?"""
    return Path(f"/sys/class/net/{name}").exists()
