"""open_bag: validate an MCAP file first, then read it with the mcap library.

Validation order (each a BagError with one line): missing, zero bytes ('empty'), bad
magic ('not_mcap'), no readable header ('unreadable'). A file without its footer/summary
(a killed recorder, a copy cut short) is 'truncated': it is scanned record by record with
mcap's StreamReader and every chunk that is complete and passes its CRC is kept, up to
the first damaged byte. `info.complete` tells which case it was; `info.problem` says where
the damage starts and `info.message_count` how many messages were recovered.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import EndOfFile
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from ..errors import BagDamaged, BagEmpty, BagMissing, BagNoData, BagUnreadable, NotMcap

MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class ChannelInfo:
    """A channel with its schema, as stored in the file."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    metadata: dict[str, str]

    @property
    def type_name(self) -> str:
        return self.schema_name


@dataclass
class BagInfo:
    """What validation found; counts are of the messages that can be read."""

    path: Path
    size: int
    complete: bool
    profile: str = ""
    library: str = ""
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    counts: dict[int, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    chunk_count: int = 0
    good_bytes: int = 0  # bytes of the file that were read without damage
    has_footer: bool = False
    problem: str | None = None  # why the file is incomplete

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def topic_counts(self) -> dict[str, int]:
        return {c.topic: self.counts.get(c.id, 0) for c in self.channels.values()}

    def find_topic(self, name: str) -> ChannelInfo | None:
        """Channel of a topic given with or without namespace: 'joint_torques' finds '/ns/joint_torques'."""
        want = name.strip("/")
        exact = [c for c in self.channels.values() if c.topic.strip("/") == want]
        if exact:
            return exact[0]
        return next((c for c in self.channels.values() if c.topic.endswith("/" + want)), None)


class _Damage(Exception):
    """Raised inside the scan at the first damaged record."""


def _channel_info(channel: Channel, schemas: dict[int, Schema]) -> ChannelInfo:
    schema = schemas.get(channel.schema_id)
    return ChannelInfo(
        id=channel.id, topic=channel.topic, message_encoding=channel.message_encoding,
        schema_name=schema.name if schema else "", schema_encoding=schema.encoding if schema else "",
        schema_data=bytes(schema.data) if schema else b"", metadata=dict(channel.metadata),
    )


def _records(fh: io.BufferedReader, info: BagInfo) -> Iterator[object]:
    """Records in file order, chunks opened; stops quietly at the first damage (info.problem)."""
    fh.seek(0)
    records = StreamReader(fh, emit_chunks=True).records
    while True:
        start = fh.tell()
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001 - any parse failure marks the damage point
            info.problem = _damage_text(start, info.size, exc)
            return
        if isinstance(record, Chunk):
            try:
                inner = breakup_chunk(record, validate_crc=True)
            except Exception as exc:  # noqa: BLE001 - bad compression or CRC: damaged chunk
                info.problem = f"chunk at byte {start} is damaged ({exc})"
                return
            info.chunk_count += 1
            info.good_bytes = fh.tell()
            yield from inner
            continue
        info.good_bytes = fh.tell()
        if isinstance(record, Footer):
            fh.seek(-len(MAGIC), os.SEEK_END)
            info.has_footer = fh.read(len(MAGIC)) == MAGIC
            if info.has_footer:
                info.good_bytes = info.size
            else:
                info.problem = f"file ends at byte {info.size} without the closing magic bytes"
            return
        yield record


def _damage_text(offset: int, size: int, exc: Exception) -> str:
    # mcap raises EndOfFile when a record's bytes stop short, struct.error when a header does
    if offset >= size or isinstance(exc, (EndOfFile, struct.error)):
        return f"file ends inside a record at byte {offset} of {size}"
    return f"unreadable record at byte {offset} of {size} ({type(exc).__name__}: {exc})"


def _scan(path: Path, info: BagInfo, want: set[int] | None = None) -> Iterator[tuple[ChannelInfo, Message]]:
    """One linear pass: fills info (channels, counts, metadata) and yields messages."""
    schemas: dict[int, Schema] = {}
    info.counts.clear()
    info.chunk_count = 0
    first = True
    with open(path, "rb") as fh:
        for rec in _records(fh, info):
            if first:
                first = False
                if not isinstance(rec, Header):
                    raise BagUnreadable(f"{path}: MCAP magic but no header record")
                info.profile, info.library = rec.profile, rec.library
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                info.channels.setdefault(rec.id, _channel_info(rec, schemas))
            elif isinstance(rec, Message):
                if rec.channel_id not in info.channels:
                    continue  # a message before its channel: unreadable for anyone
                info.counts[rec.channel_id] = info.counts.get(rec.channel_id, 0) + 1
                if info.start_ns == 0 or rec.log_time < info.start_ns:
                    info.start_ns = rec.log_time
                info.end_ns = max(info.end_ns, rec.log_time)
                if want is None or rec.channel_id in want:
                    yield info.channels[rec.channel_id], rec
            elif isinstance(rec, Metadata):
                info.metadata.append((rec.name, dict(rec.metadata)))
    if first:
        raise BagNoData(f"{path}: truncated to {info.size} bytes, before the end of "
                       "its header record; nothing to read")


def _read_summary(path: Path, info: BagInfo) -> bool:
    """Fill info from the footer/summary; False if the file has none (then scan it)."""
    with open(path, "rb") as fh:
        fh.seek(-len(MAGIC), os.SEEK_END)
        if fh.read(len(MAGIC)) != MAGIC:
            return False
        fh.seek(0)
        try:
            reader = SeekingReader(fh)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return False
            header = reader.get_header()
            metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        except Exception:  # noqa: BLE001 - a damaged summary: fall back to scanning
            return False
    stats = summary.statistics
    info.profile, info.library = header.profile, header.library
    info.channels = {cid: _channel_info(ch, summary.schemas) for cid, ch in summary.channels.items()}
    info.counts = {cid: int(n) for cid, n in stats.channel_message_counts.items()}
    info.start_ns, info.end_ns = int(stats.message_start_time), int(stats.message_end_time)
    info.chunk_count = int(stats.chunk_count)
    info.metadata = metadata
    info.good_bytes = info.size
    info.has_footer = True
    return True


class Bag:
    """A validated bag. messages() reads with the mcap library (seeking or streaming)."""

    def __init__(self, info: BagInfo, indexed: bool):
        self.info = info
        self._indexed = indexed

    @property
    def path(self) -> Path:
        return self.info.path

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[ChannelInfo, Message]]:
        """(channel, mcap Message) in file order; for a truncated bag up to the damage."""
        want = None
        if topics is not None:
            want = {c.id for t in topics if (c := self.info.find_topic(t)) is not None}
        if not self._indexed:
            scratch = BagInfo(self.info.path, self.info.size, self.info.complete)
            yield from _scan(self.info.path, scratch, want)
            return
        names = None if want is None else [self.info.channels[c].topic for c in want]
        with open(self.info.path, "rb") as fh:
            it = SeekingReader(fh, validate_crcs=True).iter_messages(topics=names, log_time_order=False)
            while True:
                try:
                    _schema, channel, message = next(it)
                except StopIteration:
                    return
                except Exception as exc:  # noqa: BLE001 - damage inside an indexed file
                    raise BagDamaged(f"{self.info.path}: damaged chunk ({exc}); "
                                   "`check_bag BAG --recover OUT` keeps the chunks before it") from None
                yield self.info.channels[channel.id], message


def open_bag(path: str | os.PathLike, scan: bool = False) -> Bag:
    """Validate and open; BagError (one line) for files that hold nothing readable.

    scan=True ignores the summary and reads record by record, checking every chunk's CRC
    and stopping at the first damage (what recover wants).
    """
    path = Path(path)
    if not path.exists():
        raise BagMissing(f"{path}: no such file")
    if not path.is_file():
        raise BagMissing(f"{path}: not a file")
    size = path.stat().st_size
    if size == 0:
        raise BagEmpty(f"{path}: empty file (0 bytes)")
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head != MAGIC:
        raise NotMcap(f"{path}: not an MCAP file (bad magic bytes)")
    info = BagInfo(path=path, size=size, complete=True)
    if not scan and _read_summary(path, info):
        return Bag(info, indexed=True)
    for _ in _scan(path, info, want=set()):
        pass
    info.complete = info.problem is None and info.has_footer
    if info.problem is None and not info.has_footer:
        info.problem = f"file ends at byte {size} without a footer"
    return Bag(info, indexed=False)
