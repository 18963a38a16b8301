"""rclpy's CDR serialiser and the ROS message classes, imported when first used.

Why lazy: the core and the offline tools (build_model, estimation, bag_torques, mot_to_bag,
check_bag, bag_export, reproduce_paper) must import without rclpy (test/test_packaging.py):
a Python user of the model, or a tool that only plans work, needs no ROS graph. Reading or
writing message bytes does need rclpy's serialiser (the same C code the nodes use, so a bag
written offline is what the nodes would have published); without it that call raises one
RosMissing line saying what to install.
"""

from __future__ import annotations

import importlib
from functools import cache

from ..errors import UsageError

#: message type -> its module (every type the offline code reads or writes itself)
MODULES = {"JointState": "sensor_msgs.msg", "String": "std_msgs.msg",
           "DiagnosticArray": "diagnostic_msgs.msg"}


class RosMissing(UsageError):
    """rclpy or a message package is not installed (they are required dependencies)."""


@cache
def message(type_name: str) -> type:
    """The message class (JointState, String, DiagnosticArray)."""
    try:
        return getattr(importlib.import_module(MODULES[type_name]), type_name)
    except ImportError as exc:
        raise RosMissing(f"{type_name} needs the ROS 2 message packages ({exc.name}); they are "
                         "installed with forearm_dynamics (pip install forearm_dynamics)") from None


@cache
def _serialization():
    try:
        return importlib.import_module("rclpy.serialization")
    except ImportError:
        raise RosMissing("reading or writing message bytes needs rclpy (ros-jazzy-rclpy), "
                         "installed with forearm_dynamics (pip install forearm_dynamics)") from None


def deserialize(data: bytes, type_name: str):
    """rclpy.serialization.deserialize_message(data, <type>)."""
    return _serialization().deserialize_message(data, message(type_name))


def serialize(msg) -> bytes:
    """rclpy.serialization.serialize_message(msg)."""
    return _serialization().serialize_message(msg)
