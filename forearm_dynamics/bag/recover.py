"""recover: rewrite a truncated (or any readable) bag into a complete, indexed one.

Keeps every message of the complete chunks, the same schemas, channels (topic, encoding,
QoS and type-hash metadata) and metadata records; the 'rosbag2' record is regenerated
with the recovered counts (its custom_data is carried over).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml

from ..errors import BagNoData, OutputExists
from .reader import open_bag
from .rosbag2_meta import ROSBAG2_METADATA, SERIALIZED_METADATA_KEY
from .writer import BagWriter


@dataclass(frozen=True)
class RecoverResult:
    src: Path
    dst: Path
    messages: int
    counts: dict[str, int]
    source_complete: bool
    problem: str | None  # the damage found in the source, if any


def custom_data(metadata: list[tuple[str, dict[str, str]]]) -> dict[str, str]:
    """The rosbag2 metadata's custom_data of a bag (kept by a copy)."""
    for name, data in metadata:
        if name == ROSBAG2_METADATA and SERIALIZED_METADATA_KEY in data:
            try:
                info = yaml.safe_load(data[SERIALIZED_METADATA_KEY]) or {}
            except yaml.YAMLError:
                return {}
            custom = info.get("custom_data") if isinstance(info, dict) else None
            return {str(k): str(v) for k, v in (custom or {}).items()}
    return {}


def copy_layout(info, writer: BagWriter) -> dict[int, int]:
    """Copy a bag's metadata records (but its rosbag2 one: the writer writes its own) and its
    schemas and channels into `writer`; returns source channel id -> new channel id, so
    messages can then be copied as they are (recover, bag_torques)."""
    for name, data in info.metadata:
        if name != ROSBAG2_METADATA:
            writer.add_metadata(name, data)
    ids: dict[int, int] = {}
    for ch in sorted(info.channels.values(), key=lambda c: c.id):
        sid = writer.add_schema(ch.schema_name, ch.schema_encoding, ch.schema_data) \
            if ch.schema_name else 0
        ids[ch.id] = writer.add_channel(ch.topic, sid, ch.schema_name, ch.metadata,
                                        ch.message_encoding)
    return ids


def recover(src: str | os.PathLike, dst: str | os.PathLike, *, overwrite: bool = False) -> RecoverResult:
    """Copy every readable message of `src` into a new complete bag `dst`."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise OutputExists(f"{dst}: recover needs a different output file than its input")
    bag = open_bag(src, scan=True)
    info = bag.info
    if info.message_count == 0:
        raise BagNoData(f"{src}: nothing to recover (no complete chunk with messages; "
                       f"{info.problem or 'no messages'})")
    writer = BagWriter(dst, overwrite=overwrite, library=info.library or None,
                       custom_data=custom_data(info.metadata))
    try:
        ids = copy_layout(info, writer)
        for ch, msg in bag.messages():
            writer.write(ids[ch.id], msg.data, msg.log_time, msg.publish_time, msg.sequence)
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return RecoverResult(src, dst, writer.message_count, writer.counts(), info.complete, info.problem)
