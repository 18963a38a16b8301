"""BagWriter: a chunked, zstd-compressed MCAP file that `ros2 bag` and rosbags accept.

Format decisions (why):
- profile 'ros2', one schema per type ('ros2msg', full text from the installed .msg
  files), channels 'cdr' with `offered_qos_profiles` + `topic_type_hash`, and a
  'rosbag2' metadata record at close: what rosbag2's MCAP plugin reads.
- Chunks of at most `chunk_size` uncompressed bytes (default 1 MiB) AND closed every
  `flush_period_s` (default 0.5 s) of wall time, whichever first. At 1 kHz joint_states +
  joint_torques (~1 kB each) that is ~2 MB/s, so a chunk holds <= ~0.5 s: a killed
  recorder loses at most the open chunk. zstd (level 3) shrinks JointState chunks ~15x.
- `chunk_span_s` (off by default; bag_torques: 0.5 s): a chunk also closes once its
  messages' log times span that much. A tool that writes a whole recording in a fraction
  of a second (bag_torques) closes no chunk on wall time, so 1 MiB chunks held seconds of
  recording each and a cut file lost everything after its last one (a 2-chunk output lost
  all; issue 30); with 0.5 s of log time per chunk a file cut anywhere keeps all but the
  last 0.5 s before the cut (plus what follows it).
- Bytes go straight to the file descriptor (no user-space buffer): a closed chunk is in
  the kernel's page cache and survives SIGKILL of the recorder.
- Every OSError (disk full, read-only, I/O error) becomes BagWriteError naming the file
  and how many messages the completed chunks hold; a partly written record is cut off
  (ftruncate, which also gives the space back), the descriptor is closed and later writes
  fail fast. What was written up to the last complete chunk stays readable
  (`check_bag BAG --recover OUT`). `durable_count` is the number of messages in chunks
  already handed to the kernel; `on_chunk(durable_count)` is called after each chunk.
  A chunk counts as durable the moment its Chunk record is completely in the file (mcap
  writes its message indexes in a second write, which may be the one that fails): the
  count in the error is then exactly what a reader finds in the file.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

from mcap.opcode import Opcode
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from ..errors import BagWriteError, OutputDirMissing, OutputExists, OutputNotCreated
from .rosbag2_meta import (
    HASH_KEY,
    QOS_KEY,
    ROSBAG2_METADATA,
    SERIALIZED_METADATA_KEY,
    TopicQos,
    TopicSummary,
    parse_qos_yaml,
    qos_yaml,
    serialized_metadata,
)
from .schemas import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    full_type_name,
    message_definition,
    type_hash,
)

PROFILE = "ros2"
CHUNK_SIZE = 1024 * 1024  # bytes, uncompressed: ~0.5 s of joint_states + joint_torques at 1 kHz
FLUSH_PERIOD_S = 0.5
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def library_string() -> str:
    from importlib import metadata

    def ver(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "unknown"

    return f"forearm_dynamics/{ver('forearm_dynamics')} bag writer; mcap-python/{ver('mcap')}"


class _FdSink:
    """The minimal stream mcap's Writer needs (write/tell/flush), unbuffered on a file descriptor.

    mcap's Writer hands each Chunk record over in one write() call; `on_chunk` is called
    once such a call has put every byte of the record into the file.
    """

    def __init__(self, fd: int, on_chunk: Callable[[], None]):
        self.fd = fd
        self.pos = 0
        self.on_chunk = on_chunk

    def write(self, data) -> int:
        view = memoryview(data)
        n = len(view)
        chunk = n > 0 and view[0] == Opcode.CHUNK
        while view:
            view = view[os.write(self.fd, view):]
        self.pos += n
        if chunk:
            self.on_chunk()
        return n

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        """Nothing buffered here; the kernel has every byte written."""


@dataclass
class _Channel:
    topic: str
    type_name: str
    qos: list[dict]
    type_hash: str
    count: int = 0


@dataclass
class _Stats:
    start_ns: int = 2**63 - 1
    end_ns: int = 0
    count: int = 0
    channels: dict[int, _Channel] = field(default_factory=dict)


def open_exclusive(path: Path, overwrite: bool = False) -> int:
    """Open for writing; refuse an existing file unless asked; one clear error otherwise."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if overwrite else os.O_EXCL)
    if path.is_dir():
        raise OutputExists(f"cannot create {path}: it is a directory")
    try:
        return os.open(path, flags | getattr(os, "O_CLOEXEC", 0), 0o644)
    except FileExistsError:
        raise OutputExists(f"{path} exists already; refusing to overwrite it") from None
    except FileNotFoundError as exc:
        if path.parent.is_dir():  # e.g. under /proc: the directory exists, files cannot be made
            raise OutputDirMissing(f"cannot create {path}: {exc.strerror}") from None
        raise OutputDirMissing(f"cannot create {path}: directory {path.parent} does not exist") from None
    except IsADirectoryError:
        raise OutputExists(f"cannot create {path}: it is a directory") from None
    except OSError as exc:
        raise OutputNotCreated(f"cannot create {path}: {exc.strerror or exc}") from None


class BagWriter:
    """Write CDR bytes to an MCAP file as rosbag2 would. Not thread-safe (one executor thread)."""

    def __init__(self, path: str | os.PathLike, *, chunk_size: int = CHUNK_SIZE,
                 flush_period_s: float = FLUSH_PERIOD_S, compression: str = "zstd",
                 overwrite: bool = False, library: str | None = None,
                 custom_data: dict[str, str] | None = None, chunk_span_s: float | None = None):
        if compression not in COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(COMPRESSION)}, got {compression!r}")
        if chunk_size < 1024:
            raise ValueError(f"chunk_size must be >= 1024 bytes, got {chunk_size}")
        self.path = Path(path)
        self.flush_period_s = float(flush_period_s)
        if chunk_span_s is not None and not chunk_span_s > 0:
            raise ValueError(f"chunk_span_s must be > 0 s, got {chunk_span_s}")
        self._span_ns = None if chunk_span_s is None else round(chunk_span_s * 1e9)
        self._chunk_lo = self._chunk_hi = None  # log-time range of the open chunk's messages
        self.custom_data = dict(custom_data or {})
        self._schemas: dict[str, int] = {}
        self._stats = _Stats()
        self._seq: dict[int, int] = {}
        self._closed = False
        self._error: BagWriteError | None = None
        self._durable = 0  # messages in chunks already written to the file
        self._staged = 0  # messages handed to mcap's Writer (in a chunk, written or open)
        self.on_chunk: Callable[[int], None] | None = None
        self._fd = open_exclusive(self.path, overwrite)
        try:
            self._sink = _FdSink(self._fd, self._chunk_written)
            self._mcap = McapWriter(self._sink, chunk_size=chunk_size,
                                    compression=COMPRESSION[compression])
            self._last_flush = time.monotonic()
            self._guard(self._mcap.start, PROFILE, library or library_string())
        except BaseException as exc:  # disk full, or a signal (KeyboardInterrupt) right now
            if self._error is None:
                os.close(self._fd)
            if not overwrite:  # we created it: do not leave an empty, headerless file behind
                self.path.unlink(missing_ok=True)
            if isinstance(exc, BagWriteError):
                raise OutputNotCreated(f"cannot write to {self.path}: {exc.why}") from None
            raise

    # -- schema and channel registration -----------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        if name not in self._schemas:
            self._schemas[name] = self._guard(self._mcap.register_schema, name, encoding, data)
        return self._schemas[name]

    def add_channel(self, topic: str, schema_id: int, type_name: str,
                    metadata: dict[str, str], message_encoding: str = MESSAGE_ENCODING) -> int:
        """A channel with given metadata (used by recover to copy channels as they were)."""
        cid = self._guard(self._mcap.register_channel, topic, message_encoding, schema_id, metadata)
        self._stats.channels[cid] = _Channel(topic, type_name, parse_qos_yaml(metadata.get(QOS_KEY, "")),
                                             metadata.get(HASH_KEY, ""))
        self._seq[cid] = 0
        return cid

    def add_topic(self, topic: str, type_name: str, qos: TopicQos | None = None) -> int:
        """Register a ROS topic: schema from the installed .msg files, rosbag2 channel metadata."""
        type_name = full_type_name(type_name)
        sid = self.add_schema(type_name, SCHEMA_ENCODING, message_definition(type_name).encode())
        metadata = {QOS_KEY: qos_yaml([qos or TopicQos()]), HASH_KEY: type_hash(type_name)}
        return self.add_channel(topic, sid, type_name, metadata)

    # -- messages ----------------------------------------------------------------------
    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record (the 'rosbag2' one is written by close())."""
        self._guard(self._mcap.add_metadata, name, dict(data))

    def write(self, channel_id: int, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None, sequence: int | None = None) -> None:
        """Append one serialized message; closes the chunk when it is full or old enough."""
        if self._error is not None:
            raise self._error
        st = self._stats
        ch = st.channels[channel_id]
        seq = self._seq[channel_id] = self._seq[channel_id] + 1 if sequence is None else sequence
        st.count += 1  # counted from here: written, or lost with the open chunk
        self._staged = st.count  # a chunk written now holds this message too
        try:
            if self._span_ns is not None:
                self._log_span(log_time_ns)
            self._mcap.add_message(channel_id, log_time_ns, data,
                                   log_time_ns if publish_time_ns is None else publish_time_ns, seq)
            if time.monotonic() - self._last_flush >= self.flush_period_s:
                self._flush_chunk()
        except OSError as exc:
            raise self._fail(exc) from None
        ch.count += 1
        st.start_ns = min(st.start_ns, log_time_ns)
        st.end_ns = max(st.end_ns, log_time_ns)

    def flush_if_due(self) -> None:
        """Close the open chunk if it is older than flush_period_s (call from a timer)."""
        if self._error is None and not self._closed and \
                time.monotonic() - self._last_flush >= self.flush_period_s:
            self._guard(self._flush_chunk)

    def flush(self) -> None:
        """Close the open chunk now."""
        if self._error is None and not self._closed:
            self._guard(self._flush_chunk)

    def _log_span(self, log_time_ns: int) -> None:
        """chunk_span_s: close the open chunk before a message that would widen its log-time
        range beyond the span (so that the message opens the next chunk)."""
        lo, hi = self._chunk_lo, self._chunk_hi
        if lo is not None and max(hi, log_time_ns) - min(lo, log_time_ns) >= self._span_ns:
            self._staged = self._stats.count - 1  # the message being written is not in it
            self._mcap.flush()
            self._last_flush = time.monotonic()
            lo = None
        if lo is None:
            self._chunk_lo = self._chunk_hi = log_time_ns
        else:
            self._chunk_lo, self._chunk_hi = min(lo, log_time_ns), max(hi, log_time_ns)

    def _flush_chunk(self) -> None:
        self._staged = self._stats.count
        self._mcap.flush()
        self._last_flush = time.monotonic()
        self._chunk_lo = self._chunk_hi = None

    def _chunk_written(self) -> None:
        """The sink wrote a whole Chunk record: every message staged so far is in the file."""
        self._durable = self._staged
        if self.on_chunk is not None:
            self.on_chunk(self._durable)

    # -- state -------------------------------------------------------------------------
    @property
    def message_count(self) -> int:
        return self._stats.count

    @property
    def durable_count(self) -> int:
        """Messages in completed chunks: what a SIGKILL right now would leave readable."""
        return self._durable

    def counts(self) -> dict[str, int]:
        return {c.topic: c.count for c in self._stats.channels.values()}

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Write the rosbag2 metadata record, the summary (statistics, indexes) and the footer."""
        if self._closed:
            return
        if self._error is not None:
            self._closed = True
            raise self._error
        self._guard(self._flush_chunk)  # the last chunk first, counted as durable
        st = self._stats
        topics = [TopicSummary(c.topic, c.type_name, c.qos, c.type_hash, c.count)
                  for c in st.channels.values()]
        text = serialized_metadata(self.path.name, topics, st.start_ns, st.end_ns, self.custom_data)
        self._guard(self._mcap.add_metadata, ROSBAG2_METADATA, {SERIALIZED_METADATA_KEY: text})
        self._guard(self._mcap.finish)
        self._closed = True
        try:
            os.fsync(self._fd)
        except OSError:
            pass  # fsync is a courtesy (e.g. not supported on some pipes); data was written
        os.close(self._fd)

    def abort(self) -> None:
        """Close the descriptor without a summary (the file reads as truncated)."""
        if not self._closed:
            self._closed = True
            if self._error is None:
                os.close(self._fd)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- errors ------------------------------------------------------------------------
    def _guard(self, fn, *args):
        if self._error is not None:
            raise self._error
        try:
            return fn(*args)
        except OSError as exc:
            raise self._fail(exc) from None

    def _fail(self, exc: OSError) -> BagWriteError:
        lost = self._stats.count - self._durable
        self._error = BagWriteError(
            f"writing {self.path} failed: {exc.strerror or exc}; its completed chunks keep "
            f"{self._durable} messages ({lost} in the open chunk are lost); "
            "`check_bag BAG --recover OUT` makes it a complete bag", why=exc.strerror or str(exc))
        try:
            os.ftruncate(self._fd, self._sink.pos)  # cut a partly written record
        except OSError:
            pass
        try:
            os.close(self._fd)
        except OSError:
            pass
        return self._error
