"""Process faults with real processes over loopback DDS: kill -9 and restart the publisher
or the torque node; the recorder stopped by SIGKILL, SIGTERM or SIGINT at random points.

The pipeline (trajectory_publisher -> torque_node -> bag_recorder) is recorded, and the
recording is the evidence: every recorded torque is checked to be exactly what the node
must compute from the sample it carries (faultkit.check_torque_stream), every joint_states
is matched with its joint_torques, and the bags are read by check_bag and by rosbags.
"""

from __future__ import annotations

import itertools
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rosproc
import yaml
from faultkit import (
    SIGNALS,
    Diagnostics,
    Procs,
    cdr_stamp,
    check_torque_stream,
    joint_series,
    private_domain,
    recorded,
)
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics.bag import open_bag
from forearm_dynamics.errors import BagError
from forearm_dynamics.nodes.common import stream_qos
from forearm_dynamics.paths import config_file
from forearm_dynamics.processes import rtps_port

pytestmark = [pytest.mark.faults, pytest.mark.ros]

#: The backward estimator: these tests check every recorded torque against the model at the
#: recorded state (check_torque_stream), which its exactly known outputs allow.
EXACT = ("-p", "estimator:=backward")
#: 10 s of history in the node's and the recorders' readers (default 1000: 1 s at 1 kHz). On
#: a loaded machine (two test suites on 2 cores) a restarted node answered its first sample
#: 1 s after it matched and then ran ~1 s behind for its whole life (latency p50 0.9-1.07 s):
#: its reader, full at 1000, evicted the oldest unread sample on every hiccup (361 samples
#: in runs of 1-20 after its first answer); a recorder joining a running stream fell 1.016 s
#: behind and lost 2 samples. That is the documented capacity limit (a reader that falls
#: more than its depth behind loses what passes it, reliable or not: docs/two-hosts.md),
#: not what these tests are about: process faults.
DEPTH = ("-p", "qos_depth:=10000")
NODE_ARGS = ("-p", "diagnostics_period:=0.5", *DEPTH, *EXACT)
#: min_subscribers 3: torque_node, the recorder and the Watch all read joint_states (with 2
#: the publisher streamed once the recorder and the watch matched, 1.2 s before the node did)
#: drain 30 s: stopped, the publisher waits (at most that) until its last samples are
#: acknowledged, also by a node a loaded machine starves at that moment (under the 60 s of
#: NodeProcess.stop's hang guard)
PUBLISHER_ARGS = ("-p", "movements:=[1, 28, 53]", "-p", "loop:=true", "-p", "start_delay:=0.5",
                  "-p", "subscriber_timeout:=30.0", "-p", "min_subscribers:=3", "-p", "drain:=30.0")


class Watch:
    """A peer counting joint_torques and joint_states (their stamps, raw) and reading
    torque_node's diagnostics."""

    def __init__(self, domain: int):
        self.peer = rosproc.Peer("process_fault_watch", domain=domain)
        self.torques: list[int] = []
        self.states: list[int] = []
        for topic, into in (("joint_torques", self.torques), ("joint_states", self.states)):
            self.peer.node.create_subscription(JointState, topic,
                                               lambda raw, into=into: into.append(cdr_stamp(raw)),
                                               stream_qos(10000), raw=True)
        self.diag = Diagnostics(self.peer, "torque_node")

    def wait_torques(self, n: int, timeout: float = 120.0) -> None:
        """n more torques (a hang guard: 1.5 s of stream at 1 kHz takes minutes at load 11+
        on 2 cores only when something is wrong)."""
        start, states = len(self.torques), len(self.states)
        assert self.peer.spin_until(lambda: len(self.torques) >= start + n, timeout), \
            (f"only {len(self.torques) - start} of {n} torques in {timeout:.0f} s, while "
             f"{len(self.states) - states} joint_states arrived here")

    def _poll(self, check, timeout: float) -> bool:
        """Spin in 0.5 s steps until check() (which reads a file being written: not on
        every spin) is true; False after timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.peer.spin_for(0.5)
            if check():
                return True
        return False

    def wait_recorded(self, path: Path, topic: str, after_ns: int, timeout: float = 30.0) -> bool:
        """Spin until the recording in progress at path holds a message on topic logged after
        after_ns (faultkit.recorded)."""
        return self._poll(lambda: recorded(path, topic, after_ns) > 0, timeout)

    def drain(self, path: Path, hang_s: float = 120.0) -> None:
        """After the publisher stopped: wait until the recording being written at path holds
        the node's answer to the publisher's last sample (a node running behind answers its
        backlog after the input stopped; a fixed wait cut those answers off: counted
        unanswered). hang_s is a hang guard."""
        self.peer.spin_for(0.5)  # the last samples still in the watch's reader
        assert self.states, "the watch received no joint_states"
        last = max(self.states)
        if not self._poll(lambda: last in self.torques and _answered(path, last), hang_s):
            raise AssertionError(f"no recorded answer to the last sample after {hang_s:.0f} s "
                                 f"(the watch {'has' if last in self.torques else 'lacks'} it)")

    def close(self) -> None:
        self.peer.close()


def _answered(path: Path, stamp: int) -> bool:
    """The recording being written at path (its closed chunks) holds a joint_torques stamped
    `stamp`."""
    try:
        return any(cdr_stamp(m.data) == stamp for _ch, m in open_bag(path).messages(["/joint_torques"]))
    except BagError:
        return False


def relaxed_thresholds(tmp: Path, **extra) -> Path:
    """check.yaml without the latency gate (a benchmark figure, not a pass/fail here)."""
    th = yaml.safe_load(config_file("check.yaml").read_text())
    th.update(latency_p99_ms_max=1e6, **extra)
    path = tmp / "check.yaml"
    path.write_text(yaml.safe_dump(th))
    return path


def check_bag_cli(*args: str, domain: int) -> subprocess.CompletedProcess:
    return subprocess.run([str(rosproc.BIN / "check_bag"), *args], env=rosproc.ros_env(domain),
                          capture_output=True, text=True, timeout=180, check=False)


def unanswered(states: dict, torques: dict) -> np.ndarray:
    """joint_states stamps without a joint_torques (the tests drain the node's answers to the
    last sample before they stop the recorder: Watch.drain)."""
    return states["stamp"][~np.isin(states["stamp"], torques["stamp"])]


def discovery_start(states: dict, torques: dict, lost: np.ndarray, pause_ns: int = 1_000_000_000,
                    most_s: float = 3.0) -> np.ndarray:
    """The unanswered samples of `lost` that precede the first answered sample of their
    publisher session (sessions: joint_states runs split by pauses over pause_ns), asserted
    to be a run from the session's first sample, under most_s long.

    A DDS writer may match its reader before the reader matches it (discovery is two
    one-way exchanges): trajectory_publisher then sees its subscribers (min_subscribers) and
    streams, the recorder records, and the torque node drops the samples of a writer it does
    not know yet; a volatile reader does not get them repaired. Seen once at load: the node
    matched 460 ms after the publisher (docs/ros.md, "Start-up: a publisher can see its
    subscriber ..."). That is not a sample the node lost: it never had it (the node's summary
    says what it received)."""
    st = states["stamp"]
    starts = np.concatenate([[0], np.flatnonzero(np.diff(st) > pause_ns) + 1, [len(st)]])
    answered = np.isin(st, torques["stamp"])
    early = np.zeros(len(lost), bool)
    for a, b in itertools.pairwise(starts):
        hit = np.flatnonzero(answered[a:b])
        first = a + (hit[0] if len(hit) else b - a)
        if first > a:
            assert (st[first - 1] - st[a]) / 1e9 < most_s, (a, first)
            early |= (lost >= st[a]) & (lost < st[first] if first < b else lost <= st[b - 1])
    return early


def processed_all_received(output: str) -> int | None:
    """The node's shutdown summary: how many samples it received, if it processed every one."""
    m = re.search(r"summary: received (\d+), processed (\d+)", output)
    return int(m.group(1)) if m is not None and m.group(1) == m.group(2) else None


def torques_matched(node, rec) -> None:
    """Both sides of the joint_torques match between torque_node and the recorder, before
    the stream: the node's writer counts the Watch's reader and the recorder's (2), the
    recorder's reader the node. An answer sent before both sides matched is not recorded
    (a CI run: the reference recorder's first torque was not the node's first answer)."""
    assert node.wait_for_output("/joint_torques: matched by 2", rosproc.STARTUP_S), node.output()
    assert rec.wait_for_output("/joint_torques: recording from 1", rosproc.STARTUP_S), rec.output()


def start_pipeline(procs: Procs, tmp: Path, domain: int):
    node = procs.start("torque_node", *NODE_ARGS, domain=domain)
    rec = procs.start("bag_recorder", "-p", f"output:={tmp / 'run.mcap'}", *DEPTH, domain=domain)
    # start-up is imports and a model build: seconds, tens of seconds at load 11 (hang guard)
    assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
    assert rec.wait_for_output("recording", rosproc.STARTUP_S), rec.output()
    torques_matched(node, rec)
    pub = procs.start("trajectory_publisher", *PUBLISHER_ARGS, domain=domain)
    return node, rec, pub


def test_publisher_killed_and_restarted(procs, tmp_path) -> None:
    domain = private_domain()
    watch = Watch(domain)
    try:
        node, rec, pub = start_pipeline(procs, tmp_path, domain)
        watch.wait_torques(1200)
        before = watch.diag.fresh()
        pub.proc.send_signal(signal.SIGKILL)
        assert pub.wait(10) == -signal.SIGKILL
        watch.peer.spin_for(1.0)
        n_down = len(watch.torques)
        watch.peer.spin_for(0.5)
        assert len(watch.torques) == n_down and node.running()  # alive, idle, not spinning on
        pub2 = procs.start("trajectory_publisher", *PUBLISHER_ARGS, domain=domain)
        watch.wait_torques(1500)
        diag = watch.diag.fresh()
        assert pub2.stop(signal.SIGINT) == 0, pub2.output()
        # stopped, it waited for its readers' acknowledgements (settle_on_stop): the node has
        # every sample it sent, also if a loaded machine starved it at that moment
        assert "]: stopped: " in pub2.output() and "not all acknowledged" not in pub2.output()
        watch.drain(tmp_path / "run.mcap")
        assert rec.stop(signal.SIGINT) == 0, rec.output()
        assert node.stop(signal.SIGINT) == 0, node.output()
    finally:
        watch.close()
    assert "Traceback" not in node.output() + rec.output() + pub2.output()
    # the node noticed the pause and restarted its estimator; nothing was refused
    assert int(diag["reset.stamp_gap"]) >= int(before["reset.stamp_gap"]) + 1
    assert diag["rejected_total"] == before["rejected_total"] == "0"

    bag = open_bag(tmp_path / "run.mcap")
    assert bag.info.complete
    states, torques = joint_series(bag, "joint_states"), joint_series(bag, "joint_torques")
    warmups = check_torque_stream(torques)
    lost = unanswered(states, torques)
    early = discovery_start(states, torques, lost)
    received = processed_all_received(node.output())
    assert received is not None, node.output()[-2000:]
    # a sample in flight at the kill may reach one subscriber and not the other
    assert (~early).sum() <= 1, lost[~early]
    # the node received every recorded sample but the ones before it knew the publisher (it
    # may have received more: the recorder, too, can match a new publisher late)
    assert received >= len(states["stamp"]) - early.sum() - 1, (received, early.sum())
    kill_gap = np.diff(states["stamp"]).max() / 1e9
    markers = bag.info.topic_counts()["/movement"]
    # check_bag cannot tell the samples the recorder got before the node matched the restarted
    # publisher (early, shown above: beside a second full run, 1 019 of them) from lost ones
    excused = int(early.sum()) + 1
    th = relaxed_thresholds(tmp_path, loss_max=excused)
    report = tmp_path / "report.json"
    chk = check_bag_cli(str(tmp_path / "run.mcap"), "--thresholds", str(th), "--json", str(report),
                        domain=domain)
    assert chk.returncode == 0, chk.stdout + chk.stderr
    rep = json.loads(report.read_text())
    assert rep["delivery"]["lost"] <= excused
    complete = [m for m in rep["movements"] if m["samples"] >= m["expected"]]
    partial = [m for m in rep["movements"] if m["samples"] < m["expected"]]
    # the one cut by the kill and the last one, stopped; and any the node never had whole
    # because it matched a publisher late (early, above: beside a second full run at load 15
    # the first movement, all 1 500 samples, went by before the node matched)
    t0 = [m["t0_ns"] for m in rep["movements"]] + [2**63]
    early_ns = lost[early]
    by_discovery = [m for i, m in enumerate(rep["movements"]) if m["samples"] < m["expected"]
                    and ((early_ns >= t0[i]) & (early_ns < t0[i + 1])).any()]
    assert len(partial) - len(by_discovery) <= 2, (partial, by_discovery)
    for m in rep["movements"]:  # a cut movement too: NRMSE scaled by the whole movement
        if m["pipeline_worst"]["nrmse"] is None:  # no torque in it to score (JSON null)
            # only a late match leaves a whole movement unanswered (CI beside a second
            # `make test`, load 15: the report's first movement had none)
            assert m in by_discovery, (m, by_discovery)
            continue
        assert m["pipeline_worst"]["nrmse"] <= 0.02 and m["state_error_rad"] <= 1e-6, m
    print(f"publisher SIGKILL + restart: {len(states['stamp'])} joint_states, "
          f"{len(torques['stamp'])} joint_torques recorded, {len(lost)} unanswered, "
          f"{warmups} warm-up samples, pause {kill_gap:.2f} s, {markers} markers; check_bag: "
          f"{len(complete)} complete and {len(partial)} cut movements within thresholds, "
          f"exit {chk.returncode}")


PLACEHOLDER = """
import signal, threading, rclpy
from rclpy.signals import SignalHandlerOptions
stop = threading.Event()
signal.signal(signal.SIGINT, lambda *_: stop.set())
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node("killed_id_placeholder")
print("placeholder up", flush=True)
stop.wait()
node.destroy_node()
rclpy.shutdown()
"""


def hold_killed_id(procs: rosproc.Procs, domain: int) -> rosproc.NodeProcess:
    """A process whose participant takes the lowest free Fast DDS participant id of the
    domain, the one a process killed just now left, so that the node restarted after it
    does not get that id.

    A participant that takes a killed one's id can take over its shared-memory data port
    (when it finds the port in use), which the publisher's writer keeps feeding; it then
    hears nothing, for good (Fast DDS's defect, not the node's: docs/reliability.md,
    benchmarks/restart_after_kill.py: 2 restarts of 85 under load; twice in this test
    beside a second suite). A process of its own, as the node is: a participant's id is
    the lowest free one as a new process counts, not as this one does after its peers."""
    proc = procs.add(rosproc.NodeProcess("killed_id_placeholder",
                                         [sys.executable, "-c", PLACEHOLDER],
                                         rosproc.ros_env(domain), rosproc._LOG_DIR,
                                         split_stderr=True))
    assert proc.wait_for_output("placeholder up", rosproc.STARTUP_S), proc.output()
    return proc


PARTICIPANT_IDS = 120  # the ids whose ports stay below the next domain's (250 / 2)


def participant_ports(pid: int, domain: int) -> set[int]:
    """The discovery and user-data unicast ports of `domain`'s participants
    (processes.rtps_port) that process `pid` has bound, from /proc: both ports of a
    participant id, never one alone. Fast DDS's sending sockets take ephemeral ports, which
    can fall in the domain's range (32768-60999 holds it): one at 38352, the discovery port
    of id 96, made a CI run beside a second suite see a port the killed node never had."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            link = os.readlink(fd)
        except OSError:  # closed meanwhile
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    bound = set()
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            bound.add(int(fields[1].rsplit(":", 1)[1], 16))
    ports = set()
    for p in range(PARTICIPANT_IDS):
        pair = {rtps_port(domain, p, False), rtps_port(domain, p, True)}
        if pair <= bound:
            ports |= pair
    return ports


def test_torque_node_killed_and_restarted(procs, tmp_path) -> None:
    domain = private_domain()
    watch = Watch(domain)
    try:
        node, rec, pub = start_pipeline(procs, tmp_path, domain)
        watch.wait_torques(1200)
        killed_ports = participant_ports(node.pid, domain)
        assert killed_ports, "the node holds no port of its domain's participant range"
        node.proc.send_signal(signal.SIGKILL)
        assert node.wait(10) == -signal.SIGKILL
        t_kill = time.time_ns()
        placeholder = hold_killed_id(procs, domain)
        watch.peer.spin_for(1.0)
        node2 = procs.start("torque_node", *NODE_ARGS, domain=domain)
        # up first (its start-up alone took > 40 s at load 11 in a full run: the old single
        # 40 s wait failed there with 0 torques), then serving
        assert node2.wait_for_output("config on", rosproc.STARTUP_S), node2.output()
        # the placeholder holds the killed node's participant id, node2 another
        assert participant_ports(placeholder.pid, domain) == killed_ports
        assert not participant_ports(node2.pid, domain) & killed_ports
        # both of its streams matched, as the node sees them (each side logs its own count;
        # a CI run beside a second suite once saw 0 answers in 120 s here, the deaf restart
        # that hold_killed_id now keeps away: a failure says which side never matched)
        assert node2.wait_for_output("/joint_states: receiving from 1", rosproc.STARTUP_S), \
            node2.output()
        assert node2.wait_for_output("/joint_torques: matched by", rosproc.STARTUP_S), \
            node2.output()
        watch.wait_torques(1500)  # it came back and serves
        diag = watch.diag.fresh()
        # The recorder may discover the new node only at Fast DDS's next participant
        # announcement (~3 s, later on a loaded machine): stop once the file being written
        # holds the new node's config, not after a fixed time.
        assert watch.wait_recorded(tmp_path / "run.mcap", "/torque_node/config", t_kill), \
            "the recorder never recorded the restarted node's config"
        assert pub.stop(signal.SIGINT) == 0, pub.output()
        watch.drain(tmp_path / "run.mcap")
        assert rec.stop(signal.SIGINT) == 0, rec.output()
        assert node2.stop(signal.SIGINT) == 0, node2.output()
        assert placeholder.stop(signal.SIGINT) == 0, placeholder.output()
    finally:
        watch.close()
    assert "Traceback" not in node2.output() + rec.output() + pub.output()
    assert diag["rejected_total"] == "0"

    bag = open_bag(tmp_path / "run.mcap")
    assert bag.info.complete
    # The config is republished with every /diagnostics message (0.5 s here): the recording
    # holds the new node's config too, logged after the kill (a latched message alone
    # reaches a running recorder only at Fast DDS's next heartbeat, ~3 s).
    from forearm_dynamics.model_config import model_from_config

    logged = [(m.log_time, json.loads(deserialize_message(m.data, String).data))
              for _ch, m in bag.messages(["/torque_node/config"])]
    configs = len(logged)
    assert any(t > t_kill for t, _ in logged), [t for t, _ in logged]
    assert all(model_from_config(c).arm.kind == "segmented" for _, c in logged)
    states, torques = joint_series(bag, "joint_states"), joint_series(bag, "joint_torques")
    after = torques["stamp"] > t_kill
    check_torque_stream({k: v[~after] for k, v in torques.items()})  # before the kill: exact
    # After the restart, exact too. The recorder may match the new node's publisher a little
    # after that node's first answers (a new participant is discovered at its announcements):
    # the first recorded answer is then not the new node's warm-up but continues from the
    # joint_states sample before it (recorded by the publisher's connection).
    back = {k: v[after] for k, v in torques.items()}
    k = int(np.searchsorted(states["stamp"], back["stamp"][0])) - 1
    try:
        check_torque_stream(back)  # the recorder heard the new node's first answer
        joined = "its first answer (a warm-up)"
    except AssertionError:
        check_torque_stream(back, prev=(int(states["stamp"][k]), states["velocity"][k]))
        joined = "after its first answers"
    lost = unanswered(states, torques)
    # one publisher session here: its stamps may still pause (a publisher stalled past its
    # catch-up burst skips: a 1.3 s gap at load 10 began a 7 s 'session' that the new node
    # answered only once it ran)
    lost = lost[~discovery_start(states, torques, lost, pause_ns=np.iinfo(np.int64).max)]
    assert processed_all_received(node2.output()) is not None, node2.output()[-2000:]
    first_back = back["stamp"].min()
    last_before = torques["stamp"][~after].max()  # the killed node's last recorded answer
    # unanswered: only what the killed node held (it answers in order: everything after its
    # last answer) or what was published while no node ran; from the new node's first
    # answer on, every sample is answered
    assert ((lost > last_before) & (lost < first_back)).all(), lost
    held = ((lost > last_before) & (lost < t_kill)).sum()
    print(f"torque_node SIGKILL + restart: {len(states['stamp'])} joint_states, "
          f"{len(torques['stamp'])} joint_torques; {len(lost)} unanswered, all during the "
          f"{(first_back - t_kill) / 1e9:.2f} s from the kill to the new node's first answer "
          f"and the {held} samples the killed node held; "
          f"{configs} config message(s); the recorder joined the new node {joined}")


# -- the recorder stopped at random points --------------------------------------------------
def _recorder_plan(rng: random.Random) -> list[tuple[str, str, float]]:
    """(signal, phase, delay): start-up = as soon as the file exists; recording = a random
    time after the recording being written holds its first torque; 'SIGINT x2' = a second
    SIGINT 2 ms on. A recorder joining a running graph may match a writer only at Fast DDS's
    next discovery heartbeat (~3 s, more at load): counted from its 'recording' line, two
    of four 3.5-5 s windows held no torque at load 7 (a busy loop beside two runs of this
    file), and the check that most stops during recording leave data for check_bag failed.
    Windows of 3.5-5 s from the first torque may still hold no marker (check_bag then
    scores the file as a recording without markers): that case is checked too."""
    plan = [(sig, phase, rng.uniform(3.5, 5.0) if phase == "recording" else 0.0)
            for sig in ("SIGKILL", "SIGTERM", "SIGINT") for phase in ("start-up", "recording")]
    return [*plan, ("SIGINT x2", "recording", rng.uniform(3.5, 5.0))]


def _send(rec, sig: str) -> None:
    rec.proc.send_signal(SIGNALS[sig.split()[0]])
    if sig == "SIGINT x2":  # a second Ctrl-C while the file is being closed
        time.sleep(0.002)
        rec.proc.send_signal(signal.SIGINT)


def _contiguous(sub: np.ndarray, ref: np.ndarray) -> bool:
    """sub is a run of consecutive elements of ref."""
    if not len(sub):
        return True
    i = np.searchsorted(ref, sub[0])
    return i + len(sub) <= len(ref) and np.array_equal(ref[i:i + len(sub)], sub)


def _last_durable(output: str) -> int:
    found = re.findall(r"chunk closed: (\d+) messages on disk", output)
    return int(found[-1]) if found else 0


def _rosbags_counts(path: Path) -> dict[str, int]:
    with Reader(path) as r:
        n = sum(1 for _ in r.messages())
        counts = {c.topic: c.msgcount for c in r.connections}
    assert n == sum(counts.values())
    return counts


def test_recorder_stopped_at_random_points(procs, tmp_path) -> None:
    """Seven recorders join a running pipeline and are stopped at random points (seeded,
    printed); a reference recorder runs throughout. Each bag: readable by check_bag (exit 0
    or 1 with its report when it holds torques and markers, else one line and exit 2);
    SIGTERM/SIGINT: complete, as many messages as the recorder said it wrote, read alike by
    rosbags; SIGKILL: every message of the chunks it reported closed, and `check_bag
    --recover` makes it a bag rosbags reads with the same counts. The recorded joint_states
    and joint_torques are unbroken runs of the reference's; those are exact torques."""
    seed = int(time.time())
    rng = random.Random(seed)
    plan = _recorder_plan(rng)
    print(f"seed {seed}: " + ", ".join(f"{s} {p} {d:.2f} s" for s, p, d in plan))
    domain = private_domain()
    watch = Watch(domain)
    try:
        node = procs.start("torque_node", *DEPTH, *EXACT, domain=domain)
        ref_path = tmp_path / "reference.mcap"
        ref = procs.start("bag_recorder", "-p", f"output:={ref_path}", *DEPTH, domain=domain)
        assert node.wait_for_output("config on", rosproc.STARTUP_S), node.output()
        assert ref.wait_for_output("recording", rosproc.STARTUP_S), ref.output()
        torques_matched(node, ref)  # the reference holds the node's first answer
        pub = procs.start("trajectory_publisher", *PUBLISHER_ARGS, domain=domain)
        watch.wait_torques(300)  # the pipeline runs before the recorders under test join
    finally:
        watch.close()
    started, due = [], {}
    for k, (sig, phase, delay) in enumerate(plan):
        path = tmp_path / f"rec{k}.mcap"
        rec = procs.start("bag_recorder", "-p", f"output:={path}", *DEPTH,
                          "--log-level", "bag_recorder:=debug", domain=domain)
        started.append((rec, path, sig, phase, delay))
        if phase == "start-up":  # the file exists, subscriptions are being made
            deadline = time.monotonic() + 30
            while not path.exists() and rec.running() and time.monotonic() < deadline:
                time.sleep(0.001)
            _send(rec, sig)
        else:
            due[k] = None
    deadline, polled = time.monotonic() + rosproc.STARTUP_S, 0.0  # a hang guard
    while due:  # stop each at its random point
        assert time.monotonic() < deadline, "recorders never recorded a torque"
        poll = time.monotonic() >= polled + 0.25  # reading the files: not every 5 ms
        polled = time.monotonic() if poll else polled
        for k in list(due):
            rec, path, sig, _phase, delay = started[k]
            if due[k] is None and poll and recorded(path, "/joint_torques") > 0:
                due[k] = time.monotonic() + delay
            elif due[k] is not None and time.monotonic() >= due[k]:
                _send(rec, sig)
                del due[k]
        time.sleep(0.005)
    time.sleep(0.5)
    assert pub.stop(signal.SIGINT) == 0 and ref.stop(signal.SIGINT) == 0
    assert node.stop(signal.SIGINT) == 0
    ref_bag = open_bag(ref_path)
    ref_states = joint_series(ref_bag, "joint_states")["stamp"]
    ref_torques = joint_series(ref_bag, "joint_torques")
    assert ref_bag.info.complete and len(ref_states) > 2000
    check_torque_stream(ref_torques)  # the reference's torques are exact, so are their runs

    rows = []
    for rec, path, sig, phase, _delay in started:
        rows.append(_judge(rec, path, sig, phase, ref_states, ref_torques, domain))
    print("\n".join(rows))
    # the stops during recording hold data that check_bag analyses
    assert sum("check_bag exit 0" in r or "check_bag exit 1" in r for r in rows) >= 3, rows


def _judge(rec, path: Path, sig: str, phase: str, ref_states, ref_torques, domain: int) -> str:
    code = rec.wait(30)
    out = rec.output()
    assert "Traceback" not in out, out
    row = f"{sig:<10} {phase:<9} exit {code:>3}"
    assert code == (-signal.SIGKILL if sig == "SIGKILL" else 0), out
    if not path.exists():
        assert phase == "start-up"
        return row + "  no file (stopped before the file was created)"
    try:
        bag = open_bag(path)
    except BagError as exc:  # killed before the header was complete: nothing to keep
        assert sig == "SIGKILL" and phase == "start-up", exc
        chk = check_bag_cli(str(path), domain=domain)
        assert chk.returncode == 2 and len(chk.stderr.strip().splitlines()) == 1, chk.stderr
        return row + f"  {path.stat().st_size} B, nothing readable ({type(exc).__name__}); check_bag exit 2"
    states = joint_series(bag, "joint_states")["stamp"]
    torques = joint_series(bag, "joint_torques")
    assert _contiguous(states, ref_states), "recorded joint_states have a hole"
    assert _contiguous(torques["stamp"], ref_torques["stamp"]), "recorded joint_torques have a hole"
    i = np.searchsorted(ref_torques["stamp"], torques["stamp"])
    np.testing.assert_array_equal(torques["effort"], ref_torques["effort"][i])
    counts = bag.info.topic_counts()
    if sig == "SIGKILL":
        assert not bag.info.complete
        durable = _last_durable(out)
        assert bag.info.message_count >= durable, (bag.info.message_count, durable)
        fixed = path.with_name(path.stem + "_recovered.mcap")
        res = check_bag_cli(str(path), "--recover", str(fixed), domain=domain)
        if bag.info.message_count == 0:
            assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
            kept = "truncated, 0 messages (nothing to recover: exit 2, one line)"
        else:
            assert res.returncode == 0, res.stderr
            assert _rosbags_counts(fixed) == counts
            assert open_bag(fixed).info.complete
            kept = (f"truncated, {bag.info.message_count} messages kept (>= {durable} in chunks "
                    "reported closed); recovered: rosbags reads the same counts")
    else:
        assert bag.info.complete, bag.info.problem
        wrote = re.search(r"wrote (\d+) messages", out)
        assert wrote and int(wrote.group(1)) == bag.info.message_count, out
        assert _rosbags_counts(path) == counts
        kept = f"complete, {bag.info.message_count} messages (= its 'wrote' line); rosbags agrees"
    chk = check_bag_cli(str(path), domain=domain)
    assert "Traceback" not in chk.stderr
    if counts.get("/joint_torques", 0) and (counts.get("/joint_states", 0) or counts.get("/movement", 0)):
        # without a marker: scored as any recording (one segment)
        assert chk.returncode in (0, 1) and "delivery:" in chk.stdout, chk.stdout + chk.stderr
    else:  # no torques, or nothing to compute a reference from (a recorder that matched
        # joint_torques before joint_states and was stopped first: seen at load 5)
        assert chk.returncode == 2 and len(chk.stderr.strip().splitlines()) == 1, chk.stderr
    fails = [ln.removeprefix("FAIL: ").split(" ")[0] for ln in chk.stdout.splitlines()
             if ln.startswith("FAIL: ")]
    why = f" ({', '.join(sorted(set(fails)))} over threshold)" if fails else ""
    return row + f"  {kept}; {len(states)} joint_states, {len(torques['stamp'])} joint_torques; " \
                 f"check_bag exit {chk.returncode}{why}"


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q", "-s"]))
