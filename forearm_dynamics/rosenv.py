"""The environment of a child ROS process: loopback-only DDS in its own domain."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def ros_env(domain: int, log_dir: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Environment of a child node: loopback DDS in `domain`, wheel bootstrap not inherited."""
    if not 0 < domain < 233:
        raise ValueError(f"ROS_DOMAIN_ID must be 1..232 (0 is everyone's default), got {domain}")
    drop = ("ROS_", "RMW_", "FASTRTPS", "FASTDDS", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP")
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    env.update(
        ROS_DOMAIN_ID=str(domain),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        ROS_LOG_DIR=str(log_dir),
        HOME=os.environ.get("HOME") or tempfile.gettempdir(),
        PYTHONUNBUFFERED="1",
        RCUTILS_COLORIZED_OUTPUT="0",
    )
    env.update(extra or {})
    return env
