"""What bag_player needs from a bag: the chosen topics' raw CDR, their times and QoS.

Reads any rosbag2 MCAP (ours, `ros2 bag record`'s, a truncated one up to its last
complete chunk). Nothing is deserialised: the player republishes the recorded bytes. The
only edit is the header stamp (`restamp`): for a type whose first field is a
std_msgs/Header, the stamp is the first 8 bytes after the 4-byte CDR encapsulation
(int32 sec, uint32 nanosec, in the encapsulation's byte order), patched in place.

Timing: `log` plays by the recorder's receive times (log_time), `stamp` by the header
stamps; a topic without a header, played by stamp, uses its log times shifted by the
median (stamp - log time) of the header topics, so both kinds stay on one time line.
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BagMissing, BagNoData, ForeignBag, SchemaError, UsageError
from .reader import Bag, ChannelInfo
from .rosbag2_meta import QOS_KEY, parse_qos_yaml

TIMINGS = ("log", "stamp")
_STAMP_LE = struct.Struct("<iI")
_STAMP_BE = struct.Struct(">iI")
_FIELD = re.compile(r"^\s*([A-Za-z0-9_/]+)(?:\[[^\]]*\])?\s+([A-Za-z0-9_]+)\s*(=.*)?$")


def bag_file(path: str | os.PathLike) -> Path:
    """The MCAP file of BAG: the file itself, or the one .mcap in a rosbag2 bag directory
    (what `ros2 bag record -s mcap` writes: metadata.yaml + one file per split)."""
    path = Path(path)
    if not path.is_dir():
        return path
    files = sorted(path.glob("*.mcap"))
    if len(files) != 1:
        raise BagMissing(f"{path}: a directory with {len(files)} .mcap files; "
                       + ("name one of them (split bags are played one file at a time)" if files
                          else "not a rosbag2 MCAP bag"))
    return files[0]


def has_header(ch: ChannelInfo) -> bool:
    """True when the type's first field is a std_msgs/Header (from the ros2msg schema)."""
    text = ch.schema_data.decode("utf-8", "replace").split("=" * 80)[0]
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        m = _FIELD.match(line)
        if m is None or m.group(3):  # a constant comes before any field: keep looking
            continue
        return m.group(1) in ("Header", "std_msgs/Header", "std_msgs/msg/Header") and m.group(2) == "header"
    return False


def read_stamp(data: bytes | bytearray) -> int:
    """Header stamp (ns) of a CDR message whose first field is a Header."""
    sec, nsec = (_STAMP_LE if data[1] & 1 else _STAMP_BE).unpack_from(data, 4)
    return sec * 1_000_000_000 + nsec


def write_stamp(buf: bytearray, stamp_ns: int) -> None:
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    (_STAMP_LE if buf[1] & 1 else _STAMP_BE).pack_into(buf, 4, sec, nsec)


@dataclass
class PlayTopic:
    """One topic to play: its channel, message class name, QoS as recorded."""

    channel: ChannelInfo
    header: bool
    qos: dict  # the first offered profile (rosbag2 v9 dict), {} when absent
    count: int = 0


@dataclass
class Playlist:
    """Messages of the chosen topics in play order, times relative to the first (ns)."""

    topics: list[PlayTopic]
    topic_index: np.ndarray  # (N,) index into topics
    times_ns: np.ndarray  # (N,) int64, play times from 0 (already offset and sorted)
    stamps_ns: np.ndarray  # (N,) int64, header stamps (0 for header-less topics)
    bag_ns: np.ndarray  # (N,) int64, each message's time on the timing's time line (absolute)
    payloads: list[bytes]
    duration_ns: int
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.payloads)


def _qos(ch: ChannelInfo) -> dict:
    profiles = parse_qos_yaml(ch.metadata.get(QOS_KEY, ""))
    return profiles[0] if profiles and isinstance(profiles[0], dict) else {}


def load_playlist(bag: Bag, topics: list[str], timing: str = "log",
                  start_offset_s: float = 0.0) -> Playlist:
    """The chosen topics' messages; BagError (one line) for what cannot be played."""
    if timing not in TIMINGS:
        raise UsageError(f"timing must be one of {', '.join(TIMINGS)}, got {timing!r}")
    info = bag.info
    warnings = []
    if not info.complete:
        warnings.append(f"{info.path}: truncated ({info.problem}); playing the "
                        f"{info.message_count} messages of its complete chunks")
    chosen: list[PlayTopic] = []
    for name in topics:
        ch = info.find_topic(name)
        if ch is None:
            raise ForeignBag(f"{info.path}: no topic {name!r} (topics: "
                           f"{', '.join(sorted(info.topic_counts())) or 'none'})")
        if ch.message_encoding != "cdr":
            raise ForeignBag(f"{info.path}: topic {ch.topic} is {ch.message_encoding!r}, "
                           "not ROS 2 CDR; cannot republish it")
        if any(p.channel.id == ch.id for p in chosen):
            continue
        chosen.append(PlayTopic(ch, has_header(ch), _qos(ch)))
    index = {p.channel.id: k for k, p in enumerate(chosen)}
    idx, logs, stamps, payloads = [], [], [], []
    for ch, msg in bag.messages([p.channel.topic for p in chosen]):
        k = index.get(ch.id)
        if k is None:
            continue
        data = bytes(msg.data)
        stamp = 0
        if chosen[k].header:
            if len(data) < 12:
                raise SchemaError(f"{info.path}: a {ch.topic} message of {len(data)} bytes "
                               "is too short for its header; the bag's messages do not decode")
            stamp = read_stamp(data)
        idx.append(k)
        logs.append(msg.log_time)
        stamps.append(stamp)
        payloads.append(data)
        chosen[k].count += 1
    empty = [p.channel.topic for p in chosen if p.count == 0]
    if empty:
        raise BagNoData(f"{info.path}: no message on {', '.join(empty)}"
                       + (f" before the damage ({info.problem})" if not info.complete else ""))
    idx_a = np.array(idx, np.int64)
    logs_a = np.array(logs, np.int64)
    stamps_a = np.array(stamps, np.int64)
    if timing == "stamp":
        hdr = np.array([chosen[k].header for k in idx], bool)
        if not hdr.any():
            raise ForeignBag(f"{info.path}: timing 'stamp' needs a topic with a header "
                           f"(none of {', '.join(p.channel.topic for p in chosen)} has one)")
        times = logs_a.copy()
        times[hdr] = stamps_a[hdr]
        if (~hdr).any():
            times[~hdr] = logs_a[~hdr] + int(np.median(stamps_a[hdr] - logs_a[hdr]))
    else:
        times = logs_a
    order = np.argsort(times, kind="stable")
    absolute = times[order]
    rel = absolute - absolute[0]
    skip = round(start_offset_s * 1e9)
    sel = rel >= skip
    if not sel.any():
        raise UsageError(f"start_offset {start_offset_s:g} s is past the end of the bag "
                       f"({rel[-1] / 1e9:.3f} s)")
    keep = order[sel]
    absolute = absolute[sel]
    rel = absolute - absolute[0]
    return Playlist(chosen, idx_a[keep], rel, stamps_a[keep], absolute, [payloads[i] for i in keep],
                    int(rel[-1]), warnings)
