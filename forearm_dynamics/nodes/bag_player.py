"""bag_player BAG: publish a bag's messages again with their recorded timing.

`ros2 bag play` does not come with the PyPI wheels; this is the part of it a replay test
needs. Reads any rosbag2 MCAP (ours, `ros2 bag record`'s; a truncated one up to its last
complete chunk, with a warning) and republishes the recorded CDR bytes as they are (raw
publishers: no deserialisation, no re-serialisation), each topic with the QoS it was
offered with when recorded (`offered_qos_profiles`). Remap with `--ros-args -r`.

Parameters (read at start-up; an invalid one -> one line, exit 2):
  topics          topics to play (default [joint_states]; names with or without namespace)
  rate            time scale (2.0 = twice as fast)
  loop            play again from the start until stopped (SIGINT)
  start_offset    s into the bag to start from
  timing          'log' = the recorder's receive times, 'stamp' = the header stamps
  restamp         false: original header stamps; true: stamps shifted so the first is
                  "now" (spacing kept, and shifted again on every loop), so a replay can be
                  mixed with live data and the torque node's stamp rules hold
  clock           publish /clock (rosgraph_msgs/Clock) = the bag time of each message, for
                  nodes with use_sim_time
  min_subscribers, subscriber_timeout, start_delay, drain: as the trajectory publisher
                  (subscribers counted on the first topic)

Timing: one playback thread sleeps until each message's due time; with `busy_wait_us` > 0
it sleeps until that long before and busy-waits the rest. Measured here
(benchmarks/bag_player.py, 2 shared cores): busy-waiting 0.3 ms made the p99 interval error
worse (1.75 vs 1.00 ms at load 3-4, 5.9 vs 3.7 ms at load 6-10): the spinning takes a core
from the receiving processes. So the default is 0; on a machine with a spare core try 300.
A message that is late is sent at once (never dropped); lateness is in the summary.
Progress (elapsed / total) goes to stderr when it is a terminal.
"""

from __future__ import annotations

import struct
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock

from ..bag import open_bag
from ..bag.playback import TIMINGS, Playlist, bag_file, load_playlist, write_stamp
from ..bag.schemas import message_class
from ..errors import BagError, UsageError
from ..exit_codes import USAGE
from .common import run
from .params import ParameterError, Params, Spec, init_node
from .scheduling import REALTIME_SPECS, RealtimeNode, realtime_request
from .spec import Settings

NAME = "bag_player"
PROGRESS_PERIOD_NS = 500_000_000
DEFAULT_DEPTH = 1000
_CLOCK = struct.Struct("<4siI")  # CDR encapsulation + builtin_interfaces/Time

SPECS = (
    Spec("topics", ["joint_states"], "topics to play (recorded names, namespace optional)"),
    Spec("rate", 1.0, "time scale: 2.0 plays twice as fast", "", 1e-3, 1e3),
    Spec("loop", False, "play again from the start until stopped"),
    Spec("start_offset", 0.0, "time into the bag to start from", "s", 0.0, 1e9),
    Spec("timing", "log", "'log' (recorder receive times) or 'stamp' (header stamps)",
         choices=TIMINGS),
    Spec("restamp", False, "shift header stamps so the first is now (spacing kept)"),
    Spec("clock", False, "publish /clock with the bag time of each message"),
    Spec("min_subscribers", 1, "subscribers on the first topic to wait for", "", 0, 1000),
    Spec("subscriber_timeout", 10.0, "wait this long for them; then play anyway", "s", 0.0, 3600.0),
    Spec("start_delay", 0.5, "wait after the subscribers are there (discovery settles)", "s",
         0.0, 3600.0),
    Spec("drain", 2.0, "wait at the end for reliable subscribers to acknowledge", "s", 0.0, 600.0),
    Spec("busy_wait_us", 0, "time before each due time spent busy-waiting instead of sleeping",
         "us", 0, 100_000),
    *REALTIME_SPECS,
)

_RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT,
                1: ReliabilityPolicy.RELIABLE, 2: ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "transient_local": DurabilityPolicy.TRANSIENT_LOCAL,
               1: DurabilityPolicy.TRANSIENT_LOCAL, 2: DurabilityPolicy.VOLATILE}
_HISTORY = {"keep_last": HistoryPolicy.KEEP_LAST, "keep_all": HistoryPolicy.KEEP_ALL,
            1: HistoryPolicy.KEEP_LAST, 2: HistoryPolicy.KEEP_ALL}


def qos_from_profile(profile: dict) -> QoSProfile:
    """The recorded offered QoS (rosbag2 v9 strings or v8 integers); reliable, volatile,
    keep-last 1000 where the bag says nothing usable."""
    depth = profile.get("depth", DEFAULT_DEPTH)
    depth = int(depth) if isinstance(depth, int) and depth > 0 else DEFAULT_DEPTH
    return QoSProfile(
        depth=depth,
        history=_HISTORY.get(profile.get("history"), HistoryPolicy.KEEP_LAST),
        reliability=_RELIABILITY.get(profile.get("reliability"), ReliabilityPolicy.RELIABLE),
        durability=_DURABILITY.get(profile.get("durability"), DurabilityPolicy.VOLATILE),
    )


def clock_bytes(t_ns: int) -> bytes:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return _CLOCK.pack(b"\x00\x01\x00\x00", sec, nsec)


@dataclass(frozen=True)
class PlaySettings(Settings):
    """What bag_player is asked to do (its SPECS, read once at start-up)."""

    topics: list[str]
    rate: float
    loop: bool
    start_offset: float
    timing: str
    restamp: bool
    clock: bool
    min_subscribers: int
    subscriber_timeout: float
    start_delay: float
    drain: float
    busy_wait_us: int

    def __post_init__(self) -> None:
        v = self.topics
        if not isinstance(v, (list, tuple)) or not v or not all(isinstance(x, str) and x for x in v):
            raise ParameterError("topics", f"must be a non-empty list of topic names, got {v!r}")


def _check_decodes(pl: Playlist, classes: list[type]) -> None:
    """The first and last message of each topic must decode as its type: a bag of noise is
    refused here (one line, exit 2) rather than sent to subscribers that cannot read it."""
    for k, (topic, cls) in enumerate(zip(pl.topics, classes, strict=True)):
        rows = np.flatnonzero(pl.topic_index == k)
        for i in {int(rows[0]), int(rows[-1])}:
            try:
                deserialize_message(pl.payloads[i], cls)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types
                raise ParameterError("bag", f"{topic.channel.topic}: message {i + 1} does not decode "
                                     f"as {topic.channel.schema_name} ({type(exc).__name__})") from None


class BagPlayer(RealtimeNode, Node):
    """Publishers per topic; a playback thread; `done` when played (and drained)."""

    def __init__(self, bag_path: str, node_name: str = NAME):
        init_node(self, node_name)
        p = Params(self, SPECS, NAME)  # every parameter read-only: read once at start-up
        s = self.settings = PlaySettings.from_params(p)
        topics, start_offset, timing = list(s.topics), s.start_offset, s.timing
        self.rate, self.loop, self.restamp, self.clock = s.rate, s.loop, s.restamp, s.clock
        self.min_subscribers, self.subscriber_timeout = s.min_subscribers, s.subscriber_timeout
        self.start_delay, self.drain = s.start_delay, s.drain
        self.busy_wait_ns = 1000 * s.busy_wait_us
        self.realtime_req = realtime_request(p)  # applied by run() before the spin
        p.warn_unknown()
        try:
            self.playlist: Playlist = load_playlist(open_bag(bag_path), topics, timing, start_offset)
            classes = [message_class(t.channel.schema_name) for t in self.playlist.topics]
        except BagError as exc:
            raise ParameterError("bag", str(exc)) from None
        except UsageError as exc:
            raise ParameterError("start_offset", str(exc)) from None
        _check_decodes(self.playlist, classes)
        for w in self.playlist.warnings:
            self.get_logger().warning(w)
        self.pubs = [self.create_publisher(cls, t.channel.topic, qos_from_profile(t.qos))
                     for cls, t in zip(classes, self.playlist.topics, strict=True)]
        self.clock_pub = self.create_publisher(Clock, "/clock", 10) if self.clock else None
        self.executor_kind = "events"
        self.done = Future()
        self.exit_code = 0
        self.sent = np.zeros(len(self.pubs), np.int64)
        self.late_ns: list[int] = []
        self.loops = 0
        self._completed = False  # played to the end (not stopped by a signal or an error)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name="bag_player", daemon=True)
        pl = self.playlist
        self.get_logger().info(
            f"{bag_path}: {len(pl)} messages on "
            + ", ".join(f"{pub.topic_name} ({t.count})" for pub, t in zip(self.pubs, pl.topics, strict=True))
            + f", {pl.duration_ns / 1e9:.3f} s at rate {self.rate:g}, timing {timing}"
            + (", restamped" if self.restamp else "") + (", looping" if self.loop else "")
            + (", /clock" if self.clock else ""))
        self._thread.start()

    # -- playback thread -----------------------------------------------------------------
    def _wait_for_subscribers(self) -> bool:
        """min_subscribers on the first topic (and one on /clock when it is published)."""
        pub = self.pubs[0]
        deadline = time.monotonic() + self.subscriber_timeout
        while not self._stop.is_set():
            n = pub.get_subscription_count()
            clock_ok = self.clock_pub is None or self.min_subscribers == 0 or \
                self.clock_pub.get_subscription_count() > 0
            if n >= self.min_subscribers and clock_ok:
                break
            if time.monotonic() > deadline:
                self.get_logger().warning(f"{n} of {self.min_subscribers} subscribers on "
                                          f"{pub.topic_name} after {self.subscriber_timeout:g} s; "
                                          "playing anyway")
                break
            time.sleep(0.01)
        return not self._stop.wait(self.start_delay)

    def _sleep_until(self, target_ns: int, clock=time.perf_counter_ns) -> None:
        while True:
            rem = target_ns - clock()
            if rem <= 0:
                return
            if rem > self.busy_wait_ns and self._stop.wait((rem - self.busy_wait_ns) / 1e9):
                return

    def _play(self) -> None:
        try:
            if self._wait_for_subscribers():
                while not self._stop.is_set():
                    self._play_once()
                    self.loops += 1
                    if not self.loop:
                        break
            if not self._stop.is_set():
                self._finish()
                self._completed = True
        except Exception as exc:  # noqa: BLE001 - a shut-down context ends the playback
            if rclpy.ok() and not self._stop.is_set():
                self.get_logger().error(f"playback failed: {type(exc).__name__}: {exc}")
                self.exit_code = 1
        finally:
            if not self.done.done():
                self.done.set_result(True)

    def _play_once(self) -> None:
        pl = self.playlist
        pubs = [p.publish for p in self.pubs]
        header = [t.header for t in pl.topics]
        clock_pub = self.clock_pub.publish if self.clock_pub is not None else None
        times, idx, stamps, payloads = pl.times_ns, pl.topic_index, pl.stamps_ns, pl.payloads
        scale = 1.0 / self.rate
        perf = time.perf_counter_ns
        shift = 0
        if self.restamp:
            first = next((int(s) for k, s in zip(idx, stamps, strict=True) if header[k]), None)
            shift = 0 if first is None else self.get_clock().now().nanoseconds - first
        bag_ns = pl.bag_ns  # /clock: each message's time on the timing's time line
        tty = sys.stderr.isatty()
        next_progress = 0
        start = perf()
        late = self.late_ns
        for i in range(len(payloads)):
            if self._stop.is_set():
                return
            due = start + int(times[i] * scale)
            self._sleep_until(due)
            now = perf()
            k = idx[i]
            data = payloads[i]
            if shift and header[k]:
                buf = bytearray(data)
                write_stamp(buf, int(stamps[i]) + shift)
                data = bytes(buf)
            if clock_pub is not None:
                clock_pub(clock_bytes(int(bag_ns[i]) + shift))
            pubs[k](data)
            self.sent[k] += 1
            late.append(now - due)
            if tty and now >= next_progress:
                next_progress = now + PROGRESS_PERIOD_NS
                sys.stderr.write(f"\r{NAME}: {(now - start) / 1e9:8.2f} / "
                                 f"{pl.duration_ns * scale / 1e9:.2f} s  loop {self.loops + 1}  ")
                sys.stderr.flush()
        if tty:
            total = pl.duration_ns * scale / 1e9
            sys.stderr.write(f"\r{NAME}: {(perf() - start) / 1e9:8.2f} / {total:.2f} s  "
                             f"loop {self.loops + 1}  \n")

    def _finish(self) -> None:
        drain = Duration(nanoseconds=round(self.drain * 1e9))
        acked = all(p.wait_for_all_acked(drain) for p in self.pubs)
        self.get_logger().info(self.summary() + ("" if acked else
                               f"; not all acknowledged within {self.drain:g} s"))

    def summary(self) -> str:
        counts = ", ".join(f"{p.topic_name} {int(n)}" for p, n in zip(self.pubs, self.sent, strict=True))
        late = np.array(self.late_ns, float) / 1e6 if self.late_ns else np.zeros(1)
        return (f"done: {int(self.sent.sum())} messages ({counts}), {self.loops} pass(es); "
                f"lateness p50 {np.percentile(late, 50):.3f} ms, p99 {np.percentile(late, 99):.3f} ms, "
                f"max {late.max():.3f} ms; scheduling {self.realtime_line()}")

    def destroy_node(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        # Not "done.done()": a SIGINT shuts the context down, the playback thread's next
        # publish fails and it completes `done` too, racing this check (seen under load).
        if not self._completed:  # stopped (SIGINT): the context is gone, log through a plain logger
            rclpy.logging.get_logger(NAME).info("stopped; " + self.summary().removeprefix("done: "))
        super().destroy_node()


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv if argv is None else argv)
    positional = remove_ros_args(argv)[1:]
    if len(positional) != 1 or positional[0].startswith("-"):
        print(f"usage: {NAME} BAG [--ros-args -p topics:=[joint_states] -p rate:=1.0 ...]",
              file=sys.stderr)
        sys.exit(USAGE)
    try:  # a bag that cannot be played: one line, before any ROS set-up
        bag = str(bag_file(positional[0]))
        open_bag(bag)
    except BagError as exc:
        print(f"{NAME}: error: {exc}", file=sys.stderr)
        sys.exit(USAGE)
    sys.exit(run(lambda: BagPlayer(bag), NAME, argv))


if __name__ == "__main__":
    main()
