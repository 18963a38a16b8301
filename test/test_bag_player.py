"""bag_player as a real process against a peer on a private domain: every message, in order,
byte for byte, never early, each topic with its recorded QoS; loop, rate, restamp, remap,
/clock; bad bags refused with one line and exit 2."""

from __future__ import annotations

import itertools
import struct
import subprocess
import time

import bagkit
import numpy as np
import pytest
from bagkit import DOMAIN, MS, NS, write_stream_bag
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from rosproc import BIN, Peer, own_lines, ros_env
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from forearm_dynamics.nodes.common import stream_qos

pytestmark = pytest.mark.ros

N = 1500  # 1.5 s at 1 kHz
_RUNS = itertools.count()
GAP = 400 * MS  # a silent gap after sample 999: the player must wait it out


def stamp(raw: bytes) -> int:
    sec, nsec = struct.unpack_from("<iI", raw, 4)
    return sec * 1_000_000_000 + nsec


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("player") / "stream.mcap"
    return path, write_stream_bag(path, N, ns=NS, gap_after=999, gap_ns=GAP, extra_topic=True,
                                  jitter_ns=100_000)


class Listener:
    """A peer subscribed raw to one topic (and optionally /clock).

    Start-up without a race: the player starts once it sees 2 subscribers on its first
    topic (min_subscribers:=2), but a volatile reader drops what arrives before *it* has
    matched the writer, and under load that side can lag by seconds. So the second
    subscriber ("go") is only created after each reader here has matched the player's
    writer (`receive` does it): when the player starts, the listening side is ready.
    """

    def __init__(self, topic: str = "joint_states", msg_type=JointState, clock: bool = False):
        # Each listener has topics of its own (the player is remapped onto them): a reader
        # left over from an earlier test can then never count as this player's subscriber.
        self.ns = f"{NS}/run{next(_RUNS)}"
        topic = f"{self.ns}/{topic}"
        self.peer = Peer("player_listener", domain=DOMAIN)
        self.got: list[tuple[int, bytes]] = []
        self.clock: list[int] = []
        self.first = (msg_type, topic)
        self.go = None
        self.armed_ns = 0
        self.matched: dict[str, int] = {}  # topic -> publishers matched by this peer's reader
        self.subscribe(msg_type, topic, lambda d: self.got.append((time.perf_counter_ns(), d)), raw=True)
        if clock:
            self.subscribe(Clock, f"{self.ns}/clock",
                           lambda m: self.clock.append(m.clock.sec * 10**9 + m.clock.nanosec))

    def subscribe(self, msg_type, topic: str, callback, qos=None, raw: bool = False) -> None:
        """A subscription whose DDS reader reports when it has matched a writer."""
        self.matched[topic] = 0

        def on_matched(info, topic=topic):
            self.matched[topic] = info.current_count

        self.peer.node.create_subscription(
            msg_type, topic, callback, qos or stream_qos(20000), raw=raw,
            event_callbacks=SubscriptionEventCallbacks(matched=on_matched))

    def arm(self, proc, timeout: float = 60.0) -> None:
        """Wait until every reader here has matched the player's writer (the DDS 'matched'
        event; the ROS graph can know a publisher before the reader matched it), then add
        the 'go' subscriber."""
        node = self.peer.node
        ok = self.peer.spin_until(lambda: all(n >= 1 for n in self.matched.values())
                                  or not proc.running(), timeout)
        assert ok and proc.running(), proc.output()
        self.armed_ns = time.perf_counter_ns()  # the player cannot start before this
        self.go = node.create_subscription(self.first[0], self.first[1], lambda _d: None,
                                           stream_qos(10), raw=True)

    def receive(self, proc, count: int, timeout: float = 60.0) -> None:
        if self.go is None:
            self.arm(proc)
        ok = self.peer.spin_until(lambda: len(self.got) >= count or not proc.running(), timeout)
        self.peer.spin_for(0.3)
        assert ok, proc.output()

    def close(self):
        self.peer.close()


def start_player(bag_path, lis: Listener, *ros_args: str):
    """The player on `lis`'s topics, waiting for it and its 'go' subscriber (Listener.arm)."""
    return bagkit.start_player(bag_path, "-p", "start_delay:=0.2", "-p", "subscriber_timeout:=60.0",
                               "-p", "min_subscribers:=2", "-r", f"/clock:={lis.ns}/clock",
                               "-r", f"{NS}/status:={lis.ns}/status", *ros_args,
                               "-r", f"{NS}/joint_states:={lis.ns}/joint_states")


def play_through(bag_path, lis: Listener, count: int, *ros_args: str, clock: int = 0):
    """Play the bag to its end on `lis`: `count` messages (and `clock` /clock ticks, within
    10 s) received, the player exits 0; the listener is closed whatever happens."""
    proc = start_player(bag_path, lis, *ros_args)
    try:
        lis.receive(proc, count)
        if clock:
            lis.peer.spin_until(lambda: len(lis.clock) >= clock, 10)
        assert proc.wait(30) == 0, proc.output()
    finally:
        if proc.running():
            proc.stop()
        lis.close()
    return proc


def test_plays_every_message_in_order_never_early(bag):
    path, written = bag
    lis = Listener()
    status = []
    lis.subscribe(String, f"{lis.ns}/status", status.append, stream_qos(1000, reliable=False), raw=True)
    proc = play_through(path, lis, N, "-p", "topics:=[joint_states, status]")
    assert [d for _, d in lis.got] == written["payloads"]  # byte for byte, in order
    # DDS pads a payload to 4 bytes on the wire: the recorded bytes, then zeros
    assert len(status) == len(written["status"])
    for d, o in zip(status, written["status"], strict=True):
        assert d[:len(o)] == o and not d[len(o):].strip(b"\0")
    t = np.array([r for r, _ in lis.got])
    logs = written["logs"]
    # Never early: the player starts after it was armed, so message k cannot arrive before
    # armed + its recorded offset from the first (a delay in delivery, e.g. on a loaded
    # machine, only makes it later: the bound cannot be met by accident nor missed by one)
    offsets = np.asarray(logs) - logs[0]
    early = np.flatnonzero(t - lis.armed_ns < offsets)
    assert not len(early), (early[:5], proc.output())
    # (how late is the receiver's business on a loaded machine, where deliveries bunch up:
    # the player's timing error is a benchmark figure, benchmarks/bag_player.py)
    assert "done: 1650 messages" in proc.output()


def test_offered_qos_is_the_recorded_one(bag):
    path, _ = bag
    lis = Listener()
    proc = start_player(path, lis, "-p", "topics:=[joint_states, status]", "-p", "min_subscribers:=5",
                        "-p", "subscriber_timeout:=60.0")
    try:
        node = lis.peer.node
        assert lis.peer.spin_until(lambda: node.get_publishers_info_by_topic(f"{lis.ns}/status")
                                   and node.get_publishers_info_by_topic(f"{lis.ns}/joint_states"),
                                   30), proc.output()
        status = node.get_publishers_info_by_topic(f"{lis.ns}/status")[0].qos_profile
        joints = node.get_publishers_info_by_topic(f"{lis.ns}/joint_states")[0].qos_profile
    finally:
        proc.stop()
        lis.close()
    assert status.reliability == ReliabilityPolicy.BEST_EFFORT
    assert joints.reliability == ReliabilityPolicy.RELIABLE


def test_rate_scales_time(bag):
    path, written = bag
    lis = Listener()
    play_through(path, lis, N, "-p", "rate:=4.0")
    assert len(lis.got) == N
    t = np.array([r for r, _ in lis.got])
    span_bag = (written["logs"][-1] - written["logs"][0]) / 1e9
    # never early at 4x: message k not before armed + its offset / 4; and faster than 1x:
    # the whole bag took less than its recorded span (at 4x: a quarter of it, plus start-up
    # and whatever delays a loaded machine adds to delivery)
    offsets = (np.asarray(written["logs"]) - written["logs"][0]) / 4
    assert not np.flatnonzero(t - lis.armed_ns < offsets).size
    assert (t[-1] - lis.armed_ns) / 1e9 < span_bag, ((t[-1] - lis.armed_ns) / 1e9, span_bag)


def test_loop_repeats_the_bag(bag, tmp_path):
    short = tmp_path / "short.mcap"
    written = write_stream_bag(short, 200, ns=NS)
    lis = Listener()
    proc = start_player(short, lis, "-p", "loop:=true")
    try:
        lis.receive(proc, 3 * 200 + 10)
        assert proc.running(), proc.output()
    finally:
        code = proc.stop()
        lis.close()
    assert code == 0, proc.output()
    got = [d for _, d in lis.got]
    for k, d in enumerate(got[:600]):
        assert d == written["payloads"][k % 200], k
    assert "stopped;" in proc.output()


def test_restamp_shifts_stamps_to_now_keeping_spacing(bag):
    path, written = bag
    lis = Listener()
    before = time.time_ns()
    play_through(path, lis, N, "-p", "restamp:=true")
    after = time.time_ns()
    stamps = np.array([stamp(d) for _, d in lis.got])
    assert len(stamps) == N
    np.testing.assert_array_equal(np.diff(stamps), np.diff(written["stamps"]))
    assert before <= stamps[0] <= after
    # every other byte is the recorded one
    for (_, d), orig in zip(lis.got, written["payloads"], strict=True):
        assert d[:4] == orig[:4] and d[12:] == orig[12:]


def test_remap(bag):
    path, written = bag
    lis = Listener("replayed")
    play_through(path, lis, N, "-r", f"{NS}/joint_states:={lis.ns}/replayed")
    assert [d for _, d in lis.got] == written["payloads"]


def test_clock(bag):
    path, written = bag
    lis = Listener(clock=True)
    play_through(path, lis, N, "-p", "clock:=true", "-p", "timing:=log", clock=N)
    # /clock carries the recorded time of each message, in order. A latest-value topic (the
    # player's writer keeps 10): a lagging reader on a loaded machine may miss ticks (18 of
    # 800 once), never get a wrong or reordered one; most arrive.
    clock = np.array(lis.clock)
    assert np.all(np.diff(clock) > 0) and np.isin(clock, written["logs"]).all()
    assert len(clock) >= N // 2, len(clock)


@pytest.mark.parametrize("kind", ["empty", "not_mcap", "missing", "no_topic", "truncated_to_nothing",
                                  "garbage"])
def test_bad_bags_one_line_exit_2(tmp_path, bag, kind):
    path = tmp_path / "bad.mcap"
    args = []
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "not_mcap":
        path.write_text("hello, this is not a bag\n")
    elif kind == "no_topic":
        path = bag[0]
        args = ["--ros-args", "-p", "topics:=[nope]"]
    elif kind == "garbage":
        from forearm_dynamics.bag import BagWriter

        with BagWriter(path) as w:
            ch = w.add_topic(f"{NS}/joint_states", "sensor_msgs/msg/JointState")
            for k in range(20):
                w.write(ch, b"\x00\x01\x00\x00" + bytes(range(k, k + 40)), bagkit.T0 + k)
    elif kind == "truncated_to_nothing":
        path.write_bytes(bag[0].read_bytes()[:30])
    r = subprocess.run([str(BIN / "bag_player"), str(path), *args], env=ros_env(DOMAIN), capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = own_lines(r.stderr)
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr + r.stdout
    if kind == "garbage":
        assert "does not decode" in r.stderr


def test_truncated_bag_plays_its_complete_chunks(tmp_path):
    """A bag cut mid-file (recorder killed): the complete chunks play, with a warning."""
    full = tmp_path / "full.mcap"
    written = write_stream_bag(full, 2000, ns=NS, chunk_size=64 * 1024)  # ~20 chunks
    cut = tmp_path / "cut.mcap"
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    lis = Listener()
    proc = start_player(cut, lis)
    try:
        lis.arm(proc)
        ok = lis.peer.spin_until(lambda: not proc.running(), 60)
        lis.peer.spin_for(0.3)
        assert ok and proc.wait(5) == 0, proc.output()
    finally:
        if proc.running():
            proc.stop()
        lis.close()
    got = [d for _, d in lis.got]
    assert 0 < len(got) < 2000
    assert got == written["payloads"][: len(got)]
    assert "truncated" in proc.output()


def test_plays_a_bag_written_by_another_rosbag2_writer(tmp_path):
    """A rosbag2 MCAP written by rosbags (an independent implementation), not by us."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    JS = ts.types["sensor_msgs/msg/JointState"]
    Hdr, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    out = tmp_path / "foreign_bag"
    payloads = []
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection(f"{NS}/joint_states", JS.__msgtype__, typestore=ts)
        for k in range(300):
            t = bagkit.T0 + k * MS
            msg = JS(header=Hdr(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="x"),
                     name=["a", "b"], position=np.array([0.1 * k, 1.0]), velocity=np.array([1.0, 2.0]),
                     effort=np.array([3.0, 4.0]))
            data = bytes(ts.serialize_cdr(msg, JS.__msgtype__))
            payloads.append(data)
            w.write(conn, t, data)
    assert len(list(out.glob("*.mcap"))) == 1
    lis = Listener()
    proc = play_through(out, lis, 300)  # the bag directory, as `ros2 bag record` leaves it
    got = [d for _, d in lis.got]
    assert len(got) == 300, proc.output()
    for d, o in zip(got, payloads, strict=True):
        assert d[:len(o)] == o and not d[len(o):].strip(b"\0")


def test_timing_by_stamp_and_start_offset(tmp_path):
    """Log times with a 1 s recorder stall that the stamps do not have: timing:=stamp plays
    by the stamps (no stall), /clock then carries the stamps; start_offset skips the start."""
    path = tmp_path / "stall.mcap"
    w = write_stream_bag(path, 1000, ns=NS)
    from forearm_dynamics.bag import BagWriter, TopicQos, open_bag

    stalled = tmp_path / "stalled.mcap"
    with BagWriter(stalled) as out:
        ch = out.add_topic(f"{NS}/joint_states", "sensor_msgs/msg/JointState", TopicQos())
        for k, (_c, m) in enumerate(open_bag(path).messages()):
            out.write(ch, m.data, m.log_time + (1_000_000_000 if k >= 500 else 0))
    lis = Listener(clock=True)
    play_through(stalled, lis, 800, "-p", "timing:=stamp", "-p", "clock:=true", "-p", "start_offset:=0.2",
                 clock=800)
    got = [d for _, d in lis.got]
    assert got == w["payloads"][200:]  # 0.2 s in: from sample 200
    t = np.array([r for r, _ in lis.got])
    assert (t[300] - t[299]) / 1e9 < 0.5  # the log-time stall (1 s) is not replayed
    # /clock carries the stamps, not the log times (1 s later from sample 500 on). It is a
    # latest-value topic (the player's writer keeps 10): a reader that lags on a loaded
    # machine may miss some ticks (782 of 800 seen), never get a wrong one.
    clock = np.array(lis.clock)
    assert np.all(np.diff(clock) > 0) and np.isin(clock, w["stamps"][200:]).all()
    assert (clock >= w["stamps"][500]).sum() >= 150  # most of the 300 after the stall: stamps
