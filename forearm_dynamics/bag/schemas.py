"""MCAP schemas for ROS 2 types, built from the installed .msg files the way rosbag2 does.

rosbag2 (rosbag2_storage_mcap's message definition cache) stores, per type, the root .msg
text followed by every dependency once, depth first in sorted order, each introduced by

    "\\n" + "=" * 80 + "\\n" + "MSG: <name as written in the .msg, pkg/Type>\\n"

Readers (ros2 bag, Foxglove, rosbags) parse that text to decode CDR, so it is generated
from the files the running message packages ship rather than hard-coded: a new message
version changes the schema with it.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import re
import sys
from functools import lru_cache
from pathlib import Path

from ..errors import SchemaError

SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
DELIMITER = "=" * 80 + "\n"

# Same patterns as rosbag2_storage_mcap: "pkg/Type" or "pkg/msg/Type"; field types in .msg.
_TYPENAME = re.compile(r"^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg|srv)/)?([a-zA-Z][a-zA-Z0-9_]*)$")
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string",
})


def split_type(type_name: str) -> tuple[str, str, str]:
    """'sensor_msgs/msg/JointState' or 'sensor_msgs/JointState' -> (pkg, 'msg', Type)."""
    m = _TYPENAME.match(type_name)
    if not m:
        raise SchemaError(f"{type_name!r} is not a ROS type name (pkg/msg/Type)")
    return m.group(1), m.group(2) or "msg", m.group(3)


def full_type_name(type_name: str) -> str:
    pkg, ns, name = split_type(type_name)
    return f"{pkg}/{ns}/{name}"


def type_name_of(msg_class: type) -> str:
    """'sensor_msgs/msg/JointState' for the generated Python class."""
    module = msg_class.__module__.split(".")
    return f"{module[0]}/{module[1]}/{msg_class.__name__}"


def message_class(type_name: str) -> type:
    """The generated Python class of a type name (imports pkg.msg)."""
    pkg, ns, name = split_type(type_name)
    try:
        return getattr(importlib.import_module(f"{pkg}.{ns}"), name)
    except (ImportError, AttributeError):
        raise SchemaError(f"message type {type_name!r} is not installed") from None


def share_dirs(package: str) -> list[Path]:
    """Where <prefix>/share/<package> may be: ament prefixes, this interpreter, the module."""
    dirs = [Path(p) / "share" / package
            for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    dirs.append(Path(sys.prefix) / "share" / package)
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.origin:
        # <prefix>/lib/pythonX.Y/site-packages/<package>/__init__.py -> <prefix>
        parents = Path(spec.origin).resolve().parents
        if len(parents) > 4:
            dirs.append(parents[4] / "share" / package)
    return dirs


def _interface_file(type_name: str, suffix: str) -> Path | None:
    pkg, ns, name = split_type(type_name)
    for share in share_dirs(pkg):
        path = share / ns / f"{name}{suffix}"
        if path.is_file():
            return path
    return None


@lru_cache(maxsize=64)
def _msg_text(type_name: str) -> str:
    path = _interface_file(type_name, ".msg")
    if path is None:
        raise SchemaError(f"no .msg file for {type_name!r} in "
                       + ", ".join(str(d) for d in share_dirs(split_type(type_name)[0])))
    return path.read_text(encoding="utf-8")


def _dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for m in _FIELD_TYPE.finditer(text):
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)


@lru_cache(maxsize=64)
def message_definition(type_name: str) -> str:
    """Full ros2msg text of a type with its dependencies, as rosbag2 writes it."""
    seen: set[str] = set()

    def expand(name: str, depth: int) -> str:
        if depth > 50:
            raise SchemaError(f"dependency loop while resolving {type_name!r}")
        text = _msg_text(name)
        out = [text]
        for dep in _dependencies(text, split_type(name)[0]):
            if dep not in seen:
                seen.add(dep)
                out.append("\n" + DELIMITER + f"MSG: {dep}\n" + expand(dep, depth + 1))
        return "".join(out)

    return expand(type_name, 0)


@lru_cache(maxsize=64)
def type_hash(type_name: str) -> str:
    """RIHS01 type description hash from the installed <Type>.json, or '' if absent."""
    path = _interface_file(type_name, ".json")
    if path is None:
        return ""
    try:
        hashes = json.loads(path.read_text(encoding="utf-8")).get("type_hashes", [])
    except (OSError, ValueError):
        return ""
    full = full_type_name(type_name)
    return next((h.get("hash_string", "") for h in hashes if h.get("type_name") == full), "")
