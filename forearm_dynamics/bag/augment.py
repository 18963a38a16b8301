"""A copy of an indexed MCAP bag with messages added, chunk by chunk, without re-parsing it.

bag_viz adds ~30 MarkerArrays per second to a 1 kHz bag. Copying message by message with
the mcap library costs ~100 µs a message in Python (read, then write), which caps a copy at
~10x real time on this machine; here each chunk is decompressed once (in C), the messages
wanted are found through the chunk's own MessageIndex records (log time, offset) without
parsing the others, and the added messages are appended to the chunk's records: the
original records keep their offsets, so their MessageIndex records are copied as they are,
and the chunk is compressed again (zstd, in C). Schemas, channels, metadata (the 'rosbag2'
record rewritten with the new counts), statistics, chunk and metadata indexes and the
summary offsets are written as the mcap library writes them, so any MCAP reader reads the
copy (checked with rosbags and our reader in test/test_bag_viz.py).

Needs a bag with message indexes after its chunks (rosbag2 and our writer make them); for
another, augment() raises NotIndexed and the caller copies message by message.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.well_known import MessageEncoding, SchemaEncoding

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
from .schemas import full_type_name, message_definition, type_hash
from .writer import PROFILE, library_string, open_exclusive

MAGIC = b"\x89MCAP0\r\n"
_MSG_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time


class NotIndexed(ValueError):
    """The bag has chunks without message indexes (or no chunks): copy it another way."""


@dataclass
class ChunkView:
    """One chunk's records, uncompressed; `index[channel_id]`: (log_time, offset) pairs."""

    data: bytes
    index: dict[int, np.ndarray]  # (n, 2) uint64: log time, offset of the Message record

    def payload(self, offset: int) -> bytes:
        """The message bytes (CDR) of the Message record at `offset`."""
        (length,) = struct.unpack_from("<Q", self.data, offset + 1)
        return self.data[offset + _MSG_HEAD: offset + 9 + length]


#: (index of the added topic, log time ns, message bytes)
Added = tuple[int, int, bytes]


@dataclass
class _RawChunk:
    index: ChunkIndex
    compression: str
    compressed: bytes
    uncompressed_size: int
    message_indexes: bytes  # the MessageIndex records after the chunk, as stored


def _chunks(path: Path, chunk_indexes: list[ChunkIndex]) -> Iterator[_RawChunk]:
    """Every chunk (file order) as stored, found through the summary's chunk indexes."""
    with open(path, "rb") as fh:
        for ci in sorted(chunk_indexes, key=lambda c: c.chunk_start_offset):
            fh.seek(ci.chunk_start_offset)
            rec = fh.read(ci.chunk_length)
            idx = fh.read(ci.message_index_length)
            if len(rec) != ci.chunk_length or len(idx) != ci.message_index_length or \
                    rec[0] != Opcode.CHUNK:
                raise NotIndexed(f"{path}: a chunk index points outside the file")
            usize, = struct.unpack_from("<Q", rec, 25)
            (n,) = struct.unpack_from("<I", rec, 37)
            compression = rec[41:41 + n].decode()
            (m,) = struct.unpack_from("<Q", rec, 41 + n)
            yield _RawChunk(ci, compression, rec[49 + n:49 + n + m], usize, idx)


def _decompress(c: _RawChunk) -> bytes:
    if c.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(c.compressed, max_output_size=c.uncompressed_size)
    if c.compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(c.compressed)
    if c.compression == "":
        return c.compressed
    raise NotIndexed(f"chunk compression {c.compression!r} is not supported")


def _message_indexes(raw: bytes) -> tuple[dict[int, np.ndarray], dict[int, int]]:
    """{channel: (n, 2) uint64 (log_time, offset)}, {channel: position of its record in raw}."""
    out, where, pos = {}, {}, 0
    while pos < len(raw):
        if raw[pos] != Opcode.MESSAGE_INDEX:
            raise NotIndexed("unexpected record among the message indexes")
        (length,) = struct.unpack_from("<Q", raw, pos + 1)
        ch, n = struct.unpack_from("<HI", raw, pos + 9)
        out[ch] = np.frombuffer(raw, "<u8", n // 8, pos + 15).reshape(-1, 2)
        where[ch] = pos
        pos += 9 + length
    return out, where


def augment(src: Path, dst: Path, topics: list[tuple[str, str, TopicQos]],
            visit: Callable[[ChunkView, dict[int, Channel]], list[Added]],
            overwrite: bool = False) -> dict[str, int]:
    """Write dst = src + the messages visit() returns for each chunk (on the added topics,
    in the order given: (topic, type name, QoS)). Returns message counts per added topic."""
    with open(src, "rb") as fh:
        summary = make_reader(fh).get_summary()
    if summary is None or not summary.chunk_indexes:
        raise NotIndexed(f"{src}: no chunk index")
    if any(not ci.message_index_offsets for ci in summary.chunk_indexes):
        raise NotIndexed(f"{src}: chunks without message indexes")
    with open(src, "rb") as fh:
        metadata = [r for r in make_reader(fh).iter_metadata()]
    schemas: dict[int, Schema] = dict(summary.schemas)
    channels: dict[int, Channel] = dict(summary.channels)
    sid, cid = max(schemas, default=0) + 1, max(channels, default=0) + 1
    added_ids = []
    for topic, type_name, qos in topics:
        full = full_type_name(type_name)
        schema = next((s for s in schemas.values() if s.name == full and
                       s.encoding == SchemaEncoding.ROS2), None)
        if schema is None:
            schema = Schema(id=sid, name=full, encoding=SchemaEncoding.ROS2,
                            data=message_definition(full).encode())
            schemas[sid] = schema
            sid += 1
        channels[cid] = Channel(id=cid, topic=topic, message_encoding=MessageEncoding.CDR,
                                schema_id=schema.id,
                                metadata={QOS_KEY: qos_yaml([qos]), HASH_KEY: type_hash(full)})
        added_ids.append(cid)
        cid += 1
    stats = summary.statistics
    counts = dict(stats.channel_message_counts) if stats else {}
    added_counts = dict.fromkeys(added_ids, 0)
    start, end = (stats.message_start_time, stats.message_end_time) if stats else (2**63 - 1, 0)
    fd = open_exclusive(dst, overwrite)
    out = os.fdopen(fd, "wb")
    try:
        rb = RecordBuilder()
        out.write(MAGIC)
        Header(profile=PROFILE, library=library_string()).write(rb)
        for s in schemas.values():
            s.write(rb)
        for c in channels.values():
            c.write(rb)
        out.write(rb.end())
        chunk_indexes = []
        cctx = zstandard.ZstdCompressor(level=1)  # the copy is written once, read often: speed
        seq = dict.fromkeys(added_ids, 0)
        for raw in _chunks(src, summary.chunk_indexes):
            data = _decompress(raw)
            index, where = _message_indexes(raw.message_indexes)
            view = ChunkView(data, index)
            new = visit(view, channels)
            ci = raw.index
            chunk_rec, index_rec = None, raw.message_indexes
            if new:
                tail = RecordBuilder()
                extra: dict[int, list[tuple[int, int]]] = {}
                base = len(data)
                for k, log_time, payload in new:
                    ch = added_ids[k]
                    seq[ch] += 1
                    extra.setdefault(ch, []).append((log_time, base + tail.count))
                    tail.start_record(Opcode.MESSAGE)
                    tail.write(struct.pack("<HIQQ", ch, seq[ch], log_time, log_time))
                    tail.write(payload)
                    tail.finish_record()
                    added_counts[ch] += 1
                    start, end = min(start, log_time), max(end, log_time)
                data = data + tail.end()
                lo = min(ci.message_start_time, *(t for _k, t, _p in new))
                hi = max(ci.message_end_time, *(t for _k, t, _p in new))
                chunk = Chunk(compression="zstd", data=cctx.compress(data),
                              message_start_time=lo, message_end_time=hi,
                              uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data))
                chunk.write(rb)
                chunk_rec = rb.end()
                for c, r in extra.items():
                    where[c] = len(index_rec)
                    MessageIndex(channel_id=c, records=r).write(rb)
                    index_rec = index_rec + rb.end()
            else:
                lo, hi = ci.message_start_time, ci.message_end_time
                chunk = None
            offset = out.tell()
            if chunk_rec is None:  # nothing added here: the chunk as stored
                out.seek(0, os.SEEK_END)
                chunk_rec = _raw_chunk_record(src, ci)
            out.write(chunk_rec)
            index_start = out.tell()
            out.write(index_rec)
            chunk_indexes.append(ChunkIndex(
                message_start_time=lo, message_end_time=hi, chunk_start_offset=offset,
                chunk_length=len(chunk_rec),
                message_index_offsets={c: index_start + p for c, p in where.items()},
                message_index_length=len(index_rec),
                compression=chunk.compression if chunk is not None else raw.compression,
                compressed_size=len(chunk.data) if chunk is not None else len(raw.compressed),
                uncompressed_size=len(data)))
        counts.update(added_counts)
        metadata_indexes = []
        for m in metadata:
            if m.name == ROSBAG2_METADATA:
                m = Metadata(name=m.name, metadata={SERIALIZED_METADATA_KEY: _rosbag2(
                    dst, channels, schemas, counts, start, end)})
            offset = out.tell()
            m.write(rb)
            metadata_indexes.append(MetadataIndex(offset=offset, length=rb.count, name=m.name))
            out.write(rb.end())
        DataEnd(data_section_crc=0).write(rb)
        out.write(rb.end())
        _summary(out, rb, schemas, channels, chunk_indexes, metadata_indexes, Statistics(
            attachment_count=stats.attachment_count if stats else 0,
            channel_count=len(channels), channel_message_counts=counts,
            chunk_count=len(chunk_indexes), message_count=sum(counts.values()),
            message_end_time=end, message_start_time=start if counts else 0,
            metadata_count=len(metadata_indexes), schema_count=len(schemas)))
        out.flush()
        os.fsync(out.fileno())
    except BaseException:
        out.close()
        dst.unlink(missing_ok=True)
        raise
    out.close()
    return {topics[k][0]: added_counts[c] for k, c in enumerate(added_ids)}


def _raw_chunk_record(src: Path, ci: ChunkIndex) -> bytes:
    with open(src, "rb") as fh:
        fh.seek(ci.chunk_start_offset)
        return fh.read(ci.chunk_length)


def _rosbag2(dst: Path, channels, schemas, counts, start: int, end: int) -> str:
    topics = [TopicSummary(c.topic, schemas[c.schema_id].name if c.schema_id in schemas else "",
                           parse_qos_yaml(c.metadata.get(QOS_KEY, "")), c.metadata.get(HASH_KEY, ""),
                           counts.get(c.id, 0)) for c in channels.values()]
    return serialized_metadata(dst.name, topics, start, end)


def _summary(out, rb: RecordBuilder, schemas, channels, chunk_indexes, metadata_indexes,
             stats: Statistics) -> None:
    summary_start = out.tell()
    offsets = []
    for opcode, records in ((Opcode.SCHEMA, schemas.values()), (Opcode.CHANNEL, channels.values()),
                            (Opcode.STATISTICS, [stats]), (Opcode.CHUNK_INDEX, chunk_indexes),
                            (Opcode.METADATA_INDEX, metadata_indexes)):
        group_start = rb.count
        for r in records:
            r.write(rb)
        offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + group_start,
                                     group_length=rb.count - group_start))
    summary_offset_start = summary_start + rb.count
    for o in offsets:
        o.write(rb)
    data = rb.end()
    crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start),
                     zlib.crc32(data))
    out.write(data)
    Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
           summary_crc=crc).write(rb)
    out.write(rb.end())
    out.write(MAGIC)
