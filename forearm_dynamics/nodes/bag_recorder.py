"""bag_recorder: record the pipeline's topics into one MCAP file (ros2 bag, rosbags, check_bag).

Raw subscriptions hand over the CDR bytes; the callback only stamps the receive time and
appends them to the writer (no deserialisation, no copy beyond rclpy's). log_time =
publish_time = receive time (system clock, ns): the publisher's send time is not exposed
to a raw callback under the EventsExecutor, and every stamped message keeps its own
header stamp inside the payload (check_bag's latency = log_time - header stamp).

Topics (parameter `topics`): the five the pipeline uses by default; an entry is 'name'
for those or 'name:pkg/msg/Type' for any other. The latched `torque_node/config` and the
`movement` markers are subscribed transient-local (depth LATCHED_DEPTH), so what their
writers keep is recorded even when the recorder matches them late: discovery matches each
topic on its own, so a publisher that saw the recorder on `joint_states` may send its
first marker before the recorder's `movement` reader is matched (a CI run lost movement
3's marker that way). Everything else: volatile, depth `qos_depth` (1000: a writer pause
of ~0.5 s at 2 kHz does not drop), reliable, and adapted to what the publishers offer as
`ros2 bag record` does: once a best-effort publisher of a topic is seen (polled every
DISCOVERY_POLL_S) its subscription is made best effort (a reliable reader matches no
best-effort writer: "offering incompatible QoS", nothing recorded). Subscribing only once
publishers are seen (rosbag2's way) was tried: the later match lost the first answers of a
restarted torque node (test_faults_process). The channel's QoS metadata states the
recorder's default (reliable).

Files: `output` (default forearm_YYYYmmdd_HHMMSS.mcap in the working directory) is
never overwritten; a missing or unwritable directory is one error line and exit code 2 (USAGE).
SIGINT/SIGTERM finish the file (summary, statistics; exit 0, OK), also during start-up (an
empty, complete bag) and when a second signal arrives while the file is being closed; the
messages the readers already hold are written first (DRAIN_S at most).
After SIGKILL the file holds every chunk closed before: chunks close at 1 MiB or every
`flush_period` s (each closed chunk is logged at debug level with the messages it makes
safe: `--log-level bag_recorder:=debug`). A write failure (disk full) logs one error
naming the messages kept, stops recording and exits 1 (DATA); it is not retried. Parameters are
read at start-up; runtime changes are refused.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ..bag import CHUNK_SIZE, FLUSH_PERIOD_S, BagWriter, TopicQos
from ..bag.schemas import message_class, type_name_of
from ..bag.writer import COMPRESSION
from ..errors import BagError, BagWriteError
from ..exit_codes import DATA, OK
from .common import CONFIG_TOPIC, MatchLog, latched_qos, main_for, stream_qos
from .params import ParameterError, Params, Spec, init_node
from .scheduling import REALTIME_SPECS, RealtimeNode, realtime_request
from .spec import Settings

DEFAULT_TOPICS = ("joint_states", "joint_torques", "movement", "/diagnostics", CONFIG_TOPIC)
#: seconds a stopped recorder may spend writing what its readers already hold (with a live
#: stream it writes what keeps coming for that long: the stop waits DRAIN_S)
DRAIN_S = 1.0
# History a latched subscription takes over when it matches: trajectory_publisher keeps its
# last 100 markers, the torque node its last config; a burst of history must not overwrite
# itself in a reader of depth 1 before the callback takes it.
LATCHED_DEPTH = 100
KNOWN_TYPES: dict[str, type] = {
    "joint_states": JointState,
    "joint_torques": JointState,
    "movement": String,
    "diagnostics": DiagnosticArray,
    CONFIG_TOPIC: String,
}

DISCOVERY_POLL_S = 0.1  # s between looks at the QoS the stream topics' publishers offer

SPECS = (
    Spec("topics", list(DEFAULT_TOPICS), "topics to record: 'name' (types known for the "
         "pipeline's topics) or 'name:pkg/msg/Type'"),
    Spec("latched_topics", [CONFIG_TOPIC, "movement"], "topics subscribed reliable + "
         "transient-local (depth 100), so samples latched before the recorder matched are recorded"),
    Spec("output", "", "MCAP file to create ('' = forearm_<date>_<time>.mcap in the working "
         "directory); an existing file is never overwritten"),
    Spec("qos_depth", 1000, "history depth of the stream subscriptions (reliable, volatile)",
         "messages", 1, 1_000_000),
    Spec("chunk_size", CHUNK_SIZE, "a chunk is closed after this much uncompressed data",
         "bytes", 1024, 1 << 30),
    Spec("flush_period", FLUSH_PERIOD_S, "an open chunk is closed after this long anyway", "s",
         0.01, 3600.0),
    Spec("compression", "zstd", "chunk compression", choices=tuple(COMPRESSION)),
    *REALTIME_SPECS,
)


@dataclass(frozen=True)
class TopicPlan:
    """One subscription: the name as given, its message class and whether it is latched."""

    name: str
    msg_class: type
    latched: bool


def _strings(name: str, v) -> list[str]:
    if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) and x for x in v):
        raise ParameterError(name, f"must be a list of non-empty strings, got {v!r}")
    return list(v)


@dataclass(frozen=True)
class RecordSettings(Settings):
    """What bag_recorder is asked to do (its SPECS, read once at start-up)."""

    topics: list[str]
    latched_topics: list[str]
    output: str
    qos_depth: int
    chunk_size: int
    flush_period: float
    compression: str

    def __post_init__(self) -> None:
        _strings("topics", self.topics)
        _strings("latched_topics", self.latched_topics)


def _known_type(topic: str) -> type | None:
    key = topic.strip("/")
    return KNOWN_TYPES.get(key) or KNOWN_TYPES.get(key.rsplit("/", 1)[-1])


def plan_topics(entries: list[str], latched: list[str]) -> list[TopicPlan]:
    latched_set = {t.strip("/") for t in latched}
    plans, seen = [], set()
    for entry in entries:
        name, _, type_name = entry.partition(":")
        if name.strip("/") in seen:
            raise ParameterError("topics", f"topic {name!r} is listed twice")
        seen.add(name.strip("/"))
        if type_name:
            try:
                cls = message_class(type_name)
            except BagError as exc:
                raise ParameterError("topics", str(exc)) from None
        else:
            cls = _known_type(name)
            if cls is None:
                raise ParameterError("topics", f"type of {name!r} unknown; write it as "
                                     f"'{name}:pkg/msg/Type'")
        plans.append(TopicPlan(name, cls, name.strip("/") in latched_set))
    return plans


def default_output() -> Path:
    return Path.cwd() / f"forearm_{time.strftime('%Y%m%d_%H%M%S')}.mcap"


def _topic_qos(qos: QoSProfile) -> TopicQos:
    return TopicQos(depth=qos.depth, reliability=qos.reliability.name.lower(),
                    durability=qos.durability.name.lower(), history=qos.history.name.lower())


class BagRecorder(RealtimeNode, Node):
    """Raw subscriptions -> BagWriter; `done` completes when recording must stop (write failure)."""

    def __init__(self, node_name: str = "bag_recorder"):
        init_node(self, node_name)
        p = Params(self, SPECS, "bag_recorder")
        s = self.settings = RecordSettings.from_params(p)
        plans = plan_topics(list(s.topics), list(s.latched_topics))
        depth, chunk_size, flush_period = s.qos_depth, s.chunk_size, s.flush_period
        compression, output = s.compression, s.output
        self.realtime_req = realtime_request(p)  # applied by run() before the spin
        p.warn_unknown()
        resolved = []
        for plan in plans:
            try:
                resolved.append(self.resolve_topic_name(plan.name))
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types for bad names
                raise ParameterError("topics", f"{plan.name!r} is not a valid topic name ({exc})") from None
        path = Path(output).expanduser() if output else default_output()
        self.done = Future()
        self.exit_code = OK
        self.executor_kind = "events"
        # after SIGINT/SIGTERM, what the readers already hold is written too (common.spin's
        # drain: until nothing came for 50 ms, at most DRAIN_S)
        self.drain_on_stop = (DRAIN_S, lambda: self.writer.message_count if self.writer else 0)
        # SIGINT/SIGTERM never raise here (common.hold_stop_signals: they only request the
        # stop, which run() carries out after the spin): a write is never cut short, and a
        # stop during start-up finishes a made file as a complete bag (finish()).
        self.writer = None
        existed = path.exists()
        try:
            self.writer = BagWriter(path, chunk_size=chunk_size, flush_period_s=flush_period,
                                    compression=compression)
            self._depth = depth
            self._streams: list[tuple[TopicPlan, str, int]] = []  # reliable until adapted
            self._muted: set[int] = set()  # channels whose reliable subscription is replaced
            self._matches: dict[str, MatchLog] = {}  # stream topic -> its reader's count
            for plan, topic in zip(plans, resolved, strict=True):
                qos = latched_qos(LATCHED_DEPTH) if plan.latched else stream_qos(depth)
                channel = self.writer.add_topic(topic, type_name_of(plan.msg_class), _topic_qos(qos))
                cb = self._callback(channel, None if plan.latched else self._muted)
                sub = self.create_subscription(plan.msg_class, topic, cb, qos, raw=True)
                if not plan.latched:
                    self._streams.append((plan, topic, channel))
                    self._matches[topic] = self._match_log(topic, sub)
            self.create_timer(flush_period, self._flush_if_due)
            self.create_timer(DISCOVERY_POLL_S, self._look_at_publishers)
        except BagWriteError as exc:
            if self.writer is not None:
                self.writer.abort()
            raise ParameterError("output", str(exc)) from None
        except BaseException:  # a signal during start-up: leave a complete (empty) bag
            if self.writer is not None:
                self.finish()
            elif not existed and path.exists():
                path.unlink(missing_ok=True)
            raise
        debug = self.get_logger().debug
        self.writer.on_chunk = lambda n: debug(f"chunk closed: {n} messages on disk")
        self.get_logger().info(
            f"recording {', '.join(resolved)} to {path} (depth {depth}, {compression} chunks of "
            f"<= {chunk_size} B or {flush_period} s)")

    def _callback(self, channel: int, muted: set[int] | None = None):
        """The raw callback writing to `channel`; it drops what it gets once `channel` is in
        `muted` (a reliable subscription replaced by a best-effort one, see _adapt_qos)."""
        write, now = self.writer.write, time.time_ns

        def on_message(data: bytes) -> None:
            if muted and channel in muted:
                return
            # No signal interrupts this write (common.hold_stop_signals): a KeyboardInterrupt
            # inside mcap's add_message once left its statistics counting a message no chunk
            # holds (rosbags then read 5688 messages of 5689 counted; a loaded fault-test run).
            try:
                write(channel, data, now())
            except BagWriteError as exc:
                self._stop(exc)

        return on_message

    def _look_at_publishers(self) -> None:
        self._adapt_qos()
        for log in self._matches.values():
            log()

    def _match_log(self, topic: str, sub) -> MatchLog:
        """'<topic>: recording from N publisher(s)' on each change of this reader's count of
        matched publishers (its own side of the match: common.MatchLog)."""
        return MatchLog(self, sub.get_publisher_count,
                        lambda n: f"{topic}: recording from {n} publisher(s)")

    def _adapt_qos(self) -> None:
        """Adapt each stream subscription to what its publishers offer, as `ros2 bag record`
        does: it starts reliable (matched from the first sample, as before); once a
        best-effort publisher of the topic is seen it is made best effort (a reliable reader
        matches no best-effort writer: "offering incompatible QoS", nothing recorded), and
        it stays so (a best-effort reader takes reliable writers too). On a topic with
        reliable and best-effort writers, what the reliable ones send while the new
        subscription is being matched (one discovery round) is not recorded."""
        for item in list(self._streams):
            plan, topic, channel = item
            infos = self.get_publishers_info_by_topic(topic)
            if all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos):
                continue
            # Not destroyed: under the EventsExecutor a subscription with a pending QoS event
            # ("incompatible") cannot be destroyed safely (InvalidHandle in the executor); it
            # is muted (its callback drops what reliable writers still send it: no duplicates).
            self._muted.add(channel)
            sub = self.create_subscription(plan.msg_class, topic, self._callback(channel),
                                           stream_qos(self._depth, False), raw=True)
            self._matches[topic] = self._match_log(topic, sub)
            self._streams.remove(item)
            self.get_logger().info(f"{topic}: subscribed best effort, as its publisher(s) offer")

    def _flush_if_due(self) -> None:
        try:  # a chunk is written whole: no signal interrupts it (common.hold_stop_signals)
            self.writer.flush_if_due()
        except BagWriteError as exc:
            self._stop(exc)

    def _stop(self, exc: BagWriteError) -> None:
        if not self.done.done():
            self.get_logger().error(str(exc))
            self.exit_code = DATA
            self.done.set_result(True)

    def finish(self) -> int:
        """Close the file (summary, statistics); the exit code of the run."""
        if self.writer.closed:
            return self.exit_code
        # After SIGINT/SIGTERM the context is gone: the node's logger would fail to reach
        # /rosout (an rcl error line), so log through a plain logger then.
        log = self.get_logger() if self.context.ok() else rclpy.logging.get_logger("bag_recorder.close")
        # A second SIGINT/SIGTERM cannot cut the summary short: it only notes a stop.
        try:
            self.writer.close()
        except BagWriteError as exc:
            if self.exit_code == OK:
                log.error(str(exc))
            return DATA
        counts = ", ".join(f"{t} {n}" for t, n in self.writer.counts().items())
        log.info(f"wrote {self.writer.message_count} messages to {self.writer.path} "
                               f"({counts})")
        return self.exit_code



def main() -> None:
    """Record until SIGINT/SIGTERM (exit OK), a write failure (DATA) or a bad parameter (USAGE)."""
    main_for(BagRecorder, "bag_recorder")


if __name__ == "__main__":
    main()
