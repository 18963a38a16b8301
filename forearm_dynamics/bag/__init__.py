"""The MCAP container, and only it: files that `ros2 bag` (rosbag2, Jazzy) and rosbags read.

What a message's bytes mean is codec/'s business; what a recording says, offline/'s.

- BagWriter: chunked zstd MCAP, ros2 profile, rosbag2 schemas/channel metadata/metadata.
- open_bag: validation first (empty, not MCAP, truncated), then reading; truncated files
  give every message of their complete chunks.
- recover: a truncated bag rewritten as a complete one.
"""

from .reader import Bag, BagInfo, ChannelInfo, open_bag
from .recover import RecoverResult, recover
from .rosbag2_meta import TopicQos
from .writer import CHUNK_SIZE, FLUSH_PERIOD_S, BagWriter

__all__ = [
    "CHUNK_SIZE",
    "FLUSH_PERIOD_S",
    "Bag",
    "BagInfo",
    "BagWriter",
    "ChannelInfo",
    "RecoverResult",
    "TopicQos",
    "open_bag",
    "recover",
]
