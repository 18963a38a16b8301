"""A bag copied with computed outputs written in beside its messages (bag_torques, bag_muscles).

Both batch tools write the same kind of file: every message of the input (same channels, QoS,
log times), a latched `std_msgs/String` config JSON at the first output's log time, and
JointState outputs each written right after the input message whose log time it carries
(interleaved, as a node's answer follows its input in a recording). One function writes it,
so the two tools cannot drift apart in how a failed write is cleaned up (the writer aborted,
a new output file removed) or where an output lands in the file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..bag.recover import copy_layout, custom_data
from ..bag.rosbag2_meta import TopicQos
from ..bag.writer import BagWriter
from ..codec.ros import message, serialize

JOINT_STATE = "sensor_msgs/msg/JointState"
CONFIG = "std_msgs/msg/String"


def copy_with_outputs(bag, dst: Path, topics: Sequence[tuple[str, str]], config: dict,
                      log_ns: np.ndarray, emit: Callable[[int, BagWriter, dict[str, int]], None],
                      *, overwrite: bool = False, **writer_options) -> dict[str, int]:
    """Every message of `bag` (an open_bag) plus the outputs into dst; counts per topic.

    `topics`: (name, type) in channel order; JointState topics get depth 1000, the one
    std_msgs/String topic (the config) depth 1, transient local, and `config` as its one
    message. `emit(k, writer, channels)` writes output k (channels: name as given -> channel
    id), called in order after the input messages logged at or before log_ns[k].
    `writer_options` go to BagWriter (e.g. chunk_span_s).
    """
    info = bag.info
    writer = BagWriter(dst, overwrite=overwrite, custom_data=custom_data(info.metadata),
                       **writer_options)
    try:
        ids = copy_layout(info, writer)
        channels = {}
        for name, kind in topics:
            qos = (TopicQos(depth=1, durability="transient_local") if kind == CONFIG
                   else TopicQos(depth=1000))
            channels[name] = writer.add_topic("/" + name.strip("/"), kind, qos)
        first_log = int(log_ns.min()) if len(log_ns) else info.start_ns
        config_topic = next(name for name, kind in topics if kind == CONFIG)
        writer.write(channels[config_topic], serialize(message("String")(data=json.dumps(config))),
                     first_log)
        k, n = 0, len(log_ns)
        # interleave: each output right after its input (both carry the input's log time)
        for ch, msg in bag.messages():
            writer.write(ids[ch.id], msg.data, msg.log_time, msg.publish_time, msg.sequence)
            while k < n and log_ns[k] <= msg.log_time:
                emit(k, writer, channels)
                k += 1
        for rest in range(k, n):
            emit(rest, writer, channels)
        writer.close()
    except BaseException:
        writer.abort()
        if not overwrite:
            try:
                os.unlink(dst)
            except OSError:
                pass
        raise
    return writer.counts()
