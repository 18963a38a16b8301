"""One two-host run (benchmark and test support): torque_node in host A, trajectory_publisher
and bag_recorder in host B, a share of A's UDP dropped; what arrived, from B's bag.

Used by benchmarks/two_hosts.py (timing, the figures in docs/two-hosts.md) and by
test/test_two_hosts_loss.py (correctness only). Hosts: test/hostkit.py (two network
namespaces joined by a veth pair, nothing else reachable, torn down after each run). Every
process uses UDPv4 only (shared memory would carry the data past the veth) and
ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET, in its own ROS_DOMAIN_ID.

What a run counts, and where a sample can be lost on its way:
- `packets_dropped`: the nftables rule's counter (`numgen random mod 100 < N drop`);
- `udp`: each namespace's kernel UDP counters (/proc/net/snmp); `RcvbufErrors` = datagrams
  the kernel dropped because a socket's receive buffer was full: the receiving process did
  not read in time (best effort cannot get them back; reliable repairs them);
- `node_received`: samples the torque node's callback got (its shutdown summary);
- `sent` / `lost`: joint_states B's publisher sent (B's own recording of them) and those
  without a joint_torques of the same stamp in B's bag.
Optional disturbances of the receiver, to reproduce a loaded machine without loading it:
`stall_ms` (SIGSTOP the node that long every second) and `node_cpu` (a cgroup's CPU quota).
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from forearm_dynamics.paths import config_file
from forearm_dynamics.processes import BIN, ros_env

from .procstat import proc_stat
from .stats import loadavg, percentiles

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
import hostkit  # the test support's harness
from support.cpushare import CpuShare

#: The shipped lossy-link profile (docs/two-hosts.md "QoS on a lossy link").
LOSSY_PROFILE = config_file("fastdds_lossy_link.xml")


@dataclass(frozen=True)
class Case:
    """One run's set-up: `loss` % of A's incoming UDP dropped (and outgoing, `both`)."""

    name: str
    loss: int
    both: bool = False
    profile: bool = False  # the lossy-link profile on every process of both hosts
    best_effort: bool = False  # torque_node -p qos_reliability_input:=best_effort


def host_env(domain: int, logs: Path, profile: Path | None = None) -> dict[str, str]:
    """ROS environment of a process inside a namespace; `profile`: a Fast DDS XML profile."""
    env = ros_env(domain, logs)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    if profile is not None:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    return env


def udp_counters(host: hostkit.Host) -> dict[str, int]:
    """The namespace's kernel UDP counters (/proc/net/snmp, its own per namespace)."""
    lines = [ln.split() for ln in host.run(["cat", "/proc/net/snmp"]).stdout.splitlines()
             if ln.startswith("Udp:")]
    return dict(zip(lines[0][1:], map(int, lines[1][1:]), strict=True)) if len(lines) >= 2 else {}


def _delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    keep = ("InDatagrams", "OutDatagrams", "RcvbufErrors", "SndbufErrors")
    return {k: after[k] - before.get(k, 0) for k in keep if k in after}


def socket_buffers(host: hostkit.Host) -> list[int]:
    """Receive buffer sizes (bytes, `ss -m` skmem rb: the kernel doubles what was asked) of
    the namespace's UDP sockets: shows whether a profile's socket size was applied."""
    out = host.run(["ss", "-uamn"]).stdout
    return sorted({int(p.split(",")[0]) for p in out.split("rb")[1:] if p.split(",")[0].isdigit()})


class Stalls(threading.Thread):
    """SIGSTOP a process (every thread, the middleware's receive threads too) for `ms` every
    second, then SIGCONT: a receiver descheduled as on a loaded machine, reproducibly."""

    def __init__(self, pid: int, ms: float) -> None:
        super().__init__(daemon=True)
        self.pid, self.ms, self.count = pid, ms, 0
        self._done = threading.Event()

    def run(self) -> None:
        while not self._done.wait(1.0 - self.ms / 1000):
            os.kill(self.pid, signal.SIGSTOP)
            try:
                time.sleep(self.ms / 1000)
            finally:
                os.kill(self.pid, signal.SIGCONT)
            self.count += 1

    def stop(self) -> None:
        self._done.set()
        self.join()


def answers_recorded(bag: Path) -> tuple[int, int | None, int]:
    """In the recording being written (its closed chunks): the unique stamps on
    /joint_torques, the torque node's processed_total in its last /diagnostics, and that
    message's log time (ns; 0 without one)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    from forearm_dynamics.bag import open_bag
    from forearm_dynamics.errors import BagError

    stamps: set[bytes] = set()
    processed, at = None, 0
    try:
        for ch, msg in open_bag(bag).messages(["/joint_torques", "/diagnostics"]):
            if ch.topic == "/joint_torques":
                stamps.add(bytes(msg.data[4:12]))
                continue
            for status in deserialize_message(msg.data, DiagnosticArray).status:
                if "torque_node" in status.name:
                    for kv in status.values:
                        if kv.key == "processed_total":
                            processed, at = int(kv.value), msg.log_time
    except BagError:
        pass
    return len(stamps), processed, at


def _drain(bag: Path, after_ns: int, hang_s: float = 90.0) -> bool:
    """Wait until B's recording holds an answer for every sample the node processed (its
    /diagnostics after `after_ns`, when the input has stopped: the final count). The node's
    output is reliable: an answer lost near the end of the stream is repaired after the
    writer's next heartbeat (Fast DDS's default: every 3 s), so a fixed grace cut some off
    (15 of 15 000 at 5 % loss both ways: counted as lost). False after hang_s (a guard)."""
    deadline = time.monotonic() + hang_s
    while time.monotonic() < deadline:
        n, processed, at = answers_recorded(bag)
        if processed is not None and at > after_ns + 1_000_000_000 and n >= processed:
            return True
        time.sleep(0.5)
    return False


def bag_figures(bag: Path) -> dict:
    """From B's bag: torques recorded (and unique stamps), joint_states sent (B's own
    recording: every sample its publisher sent), the stamps without an answer, latency."""
    from forearm_dynamics.bag import open_bag

    stamps, logs, inputs = [], [], []
    unpack = struct.Struct("<iI").unpack_from
    for ch, msg in open_bag(bag).messages(["/joint_torques", "/joint_states"]):
        sec, nsec = unpack(msg.data, 4)
        t = sec * 1_000_000_000 + nsec
        if ch.topic == "/joint_states":
            inputs.append(t)
            continue
        stamps.append(t)
        logs.append(msg.log_time)
    s, lg = np.array(stamps, np.int64), np.array(logs, np.int64)
    sent = np.unique(np.array(inputs, np.int64))
    missing = np.setdiff1d(sent, s)
    idx = np.searchsorted(sent, missing)
    bursts = np.split(idx, np.where(np.diff(idx) != 1)[0] + 1) if idx.size else []
    first = s.min() if s.size else np.iinfo(np.int64).max
    return {"torques": int(s.size), "unique": int(np.unique(s).size),
            "inputs_recorded": int(sent.size), "first_input_ns": int(sent[0]) if sent.size else None,
            "missing": int(missing.size),
            "missing_before_first_answer": int((missing < first).sum()),
            "longest_missing_run": max((len(b) for b in bursts), default=0),
            "latency_ms": percentiles((lg - s) / 1e6) if s.size else {"n": 0}}


def _input_matched_ns(node_log: str) -> int | None:
    """When the torque node first logged its input matched ("receiving from N publisher(s)",
    N > 0; ROS time in the log line, the clock the stamps use): at or after the match."""
    for line in node_log.splitlines():
        if ": receiving from " in line and " receiving from 0 " not in line:
            stamp = line.split("] [", 1)[1].split("]", 1)[0]  # "[INFO] [sec.nsec] [name]: ..."
            sec, _, frac = stamp.partition(".")
            return int(sec) * 1_000_000_000 + int(frac.ljust(9, "0")[:9])
    return None


def _summary(node_log: str) -> tuple[int | None, int | None]:
    """(received, processed) from the torque node's shutdown summary line."""
    for line in node_log.splitlines():
        if "summary: received " in line:
            rest = line.split("summary: received ")[1]
            return int(rest.split(",")[0]), int(rest.split("processed ")[1].split()[0])
    return None, None


def _wait_streaming(pub: subprocess.Popen, log: Path, timeout: float = 120.0) -> bool:
    """Until the publisher logs its first movement (the stream starts), or exits."""
    deadline = time.monotonic() + timeout
    while pub.poll() is None and time.monotonic() < deadline:
        if log.exists() and "movement 1 (" in log.read_text(errors="replace"):
            return True
        time.sleep(0.05)
    return False


def run_case(case: Case, movements: int, domain: int, work: Path, *, node_args: tuple[str, ...] = (),
             recorder_args: tuple[str, ...] = (), profile: Path = LOSSY_PROFILE,
             stall_ms: float = 0.0, node_cpu: float | None = None, start_delay: float = 8.0) -> dict:
    """Run one case; every figure of it (see the module docstring), check_bag's verdict on
    B's bag (a best-effort case allows loss: it is counted) and its JSON report.

    The publisher stays reliable also when the node's input is best effort (a reliable
    writer serves a best-effort reader best effort): B's own recording of joint_states is
    then complete, the count every loss is measured against. start_delay 8 s: B's recorder
    matched A's joint_torques ~0.3 s after the publisher saw its subscribers in a loaded
    run (296 first answers unrecorded with 2 s)."""
    logs = work / case.name
    logs.mkdir(parents=True)
    bag = logs / "b.mcap"
    env = host_env(domain, logs, profile if case.profile else None)
    args = (["-p", "qos_reliability_input:=best_effort"] if case.best_effort else []) + list(node_args)
    load0 = loadavg()
    stalls = None
    with hostkit.TwoHosts() as h, CpuShare(node_cpu) as share:
        h.a.loss(case.loss, ("input", "output") if case.both else ("input",))
        node = h.a.start([str(BIN / "torque_node"), *(["--ros-args", *args] if args else [])], env,
                         logs / "a_node.log")
        share.add(node.pid)  # `ip netns exec` execs the node: the same pid
        udp0 = {"a": udp_counters(h.a), "b": udp_counters(h.b)}
        rec = h.b.start([str(BIN / "bag_recorder"), "--ros-args", "-p", f"output:={bag}",
                         *recorder_args], env, logs / "b_rec.log")
        pub = h.b.start([str(BIN / "trajectory_publisher"), "--ros-args", "-p",
                         f"movements:={list(range(1, movements + 1))}", "-p",
                         f"start_delay:={start_delay}", "-p", "min_subscribers:=2", "-p",
                         "subscriber_timeout:=30.0", "-p", "drain:=5.0"], env, logs / "b_pub.log")
        streaming = _wait_streaming(pub, logs / "b_pub.log")
        st0, t0 = proc_stat(node.pid), time.monotonic()
        buffers = socket_buffers(h.a)
        if stall_ms > 0:
            stalls = Stalls(node.pid, stall_ms)
            stalls.start()
        try:
            code = pub.wait(timeout=600)
        finally:
            if stalls:
                stalls.stop()
        drained = _drain(bag, time.time_ns())  # the last answers (and their repairs) recorded
        st = proc_stat(node.pid)
        node_cpu_s = st.cpu_s - st0.cpu_s if st and st0 and streaming else None
        stream_s = time.monotonic() - t0
        dropped = h.a.dropped()
        udp = {k: _delta(udp_counters(getattr(h, k)), udp0[k]) for k in ("a", "b")}
        for p in (rec, node):
            p.send_signal(signal.SIGINT)
            p.wait(timeout=60)
        exits = {"publisher": code, "recorder": rec.returncode, "node": node.returncode}
    sent = None
    for line in (logs / "b_pub.log").read_text(errors="replace").splitlines():
        if "done: " in line and " samples" in line:
            sent = int(line.split("done: ")[1].split()[0])
    th = []
    if case.best_effort:  # loss is expected and counted; a wrong torque is not allowed
        (logs / "thresholds.yaml").write_text("loss_max: 1000000000\n")
        th = ["--thresholds", str(logs / "thresholds.yaml")]
    report = logs / "check.json"
    check = subprocess.run([str(BIN / "check_bag"), str(bag), "--json", str(report), *th],
                           check=False, capture_output=True, text=True, timeout=600)
    fig = bag_figures(bag) if bag.exists() else {"torques": 0, "unique": 0}
    node_log = (logs / "a_node.log").read_text(errors="replace")
    received, processed = _summary(node_log)
    return {"case": case.name, **{k: v for k, v in asdict(case).items() if k != "name"},
            "profile_file": str(profile) if case.profile else None, "node_args": list(node_args),
            "recorder_args": list(recorder_args),
            "stall_ms": stall_ms, "stalls": stalls.count if stalls else 0, "node_cpu_limit": node_cpu,
            "loadavg_start": load0, "loadavg_end": loadavg(), "exits": exits, "sent": sent,
            "node_received": received, "node_processed": processed,
            "node_input_matched_ns": _input_matched_ns(node_log),
            "input_loss_percent": 100 * (1 - received / sent) if received is not None and sent else None,
            "lost": sent - fig["unique"] if sent is not None else None,
            "packets_dropped": dropped, "udp": udp, "node_socket_rcvbuf": buffers,
            "node_cpu_s": node_cpu_s, "stream_s": stream_s, **fig,
            "drained": drained, "check_bag_exit": check.returncode,
            "check_bag_tail": (check.stdout + check.stderr)[-600:],
            "check": json.loads(report.read_text()) if report.exists() else None,
            "node_log_tail": node_log[-1500:],
            "scheduling": {k: _scheduling_line(logs / f) for k, f in (("node", "a_node.log"),
                                                                      ("recorder", "b_rec.log"))}}


def _scheduling_line(log: Path) -> str | None:
    """What a node's realtime_priority got, in its own words ("scheduling: fifo 50 (...)";
    read back from /proc by realtime.apply), or None where it asked for nothing."""
    text = log.read_text(errors="replace") if log.exists() else ""
    return next((ln.split("]: ", 1)[-1] for ln in text.splitlines() if "]: scheduling: " in ln), None)
