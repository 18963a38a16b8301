"""The metadata rosbag2 (Jazzy, bag format version 9) keeps inside an MCAP file.

- Channel metadata `offered_qos_profiles`: YAML list of QoS dicts with string enums (v9),
  and `topic_type_hash` (RIHS01_... or '').
- A Metadata record named 'rosbag2' with key 'serialized_metadata': the BagMetadata YAML.
  Without it rosbag2's MCAP plugin assumes version 8 and reads QoS enums as integers,
  so our string enums would fail to load.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import yaml

BAG_FORMAT_VERSION = 9
ROSBAG2_METADATA = "rosbag2"
SERIALIZED_METADATA_KEY = "serialized_metadata"
QOS_KEY = "offered_qos_profiles"
HASH_KEY = "topic_type_hash"

#: RMW_DURATION_INFINITE as rosbag2 writes it (what Fast DDS reports for "no deadline").
INFINITE = {"sec": 9223372036, "nsec": 854775807}


@dataclass(frozen=True)
class TopicQos:
    """The QoS a topic is recorded with; offered again when the bag is played back."""

    depth: int = 1000
    reliability: str = "reliable"  # reliable | best_effort
    durability: str = "volatile"  # volatile | transient_local
    history: str = "keep_last"  # keep_last | keep_all

    def as_dict(self) -> dict:
        return {
            "history": self.history,
            "depth": int(self.depth),
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": dict(INFINITE),
            "lifespan": dict(INFINITE),
            "liveliness": "automatic",
            "liveliness_lease_duration": dict(INFINITE),
            "avoid_ros_namespace_conventions": False,
        }


def dump_yaml(data) -> str:
    """Block-style YAML without a trailing newline, like yaml-cpp's YAML::Dump."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False).rstrip("\n")


def qos_yaml(profiles: list[TopicQos]) -> str:
    return dump_yaml([p.as_dict() for p in profiles])


def parse_qos_yaml(text: str) -> list[dict]:
    """Back to dicts (for re-writing a bag's metadata); [] when absent or unparsable."""
    try:
        value = yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []
    return value if isinstance(value, list) else []


@dataclass(frozen=True)
class TopicSummary:
    """What BagMetadata says about one topic."""

    name: str
    type: str
    qos: list[dict]
    type_hash: str
    message_count: int


def serialized_metadata(file_name: str, topics: list[TopicSummary], start_ns: int,
                        end_ns: int, custom_data: dict[str, str] | None = None) -> str:
    """BagMetadata YAML as rosbag2 stores it in the 'rosbag2' Metadata record."""
    count = sum(t.message_count for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    info = {
        "version": BAG_FORMAT_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.type,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": t.qos,
                    "type_description_hash": t.type_hash,
                },
                "message_count": t.message_count,
            }
            for t in topics
        ],
        "compression_format": "",  # chunk compression lives in the MCAP storage itself
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [{
            "path": file_name,
            "starting_time": {"nanoseconds_since_epoch": start},
            "duration": {"nanoseconds": duration},
            "message_count": count,
        }],
        "custom_data": dict(custom_data or {}),
        "ros_distro": os.environ.get("ROS_DISTRO", "jazzy"),
    }
    return dump_yaml(info)
