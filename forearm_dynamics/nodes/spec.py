"""A node parameter, defined once (ROS-free): name, default, unit, range, choices, description.

A `Spec` is the one source of a parameter: params.py turns it into a ROS declaration (type,
descriptor, range, read-only), catalog.py writes it into the node's parameter file
(config/nodes/<node>.yaml: the defaults, values included) and into docs/nodes.md, and a
test checks that the committed files are what the Specs generate. To add a parameter: add
a Spec to the node's table (and a field to its settings dataclass), then run
`python -m forearm_dynamics.nodes.catalog --write`.

Nothing here imports rclpy, so settings modules, the catalog and other nodes (arm_sim,
arm_viz share torque_config.MODEL_SPECS) can use the tables without a ROS graph.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import yaml

from ..errors import UsageError
from ..paths import node_config_file


class ParameterError(UsageError, ValueError):
    """A parameter value the node refuses to start with (the node exits with code 2)."""

    def __init__(self, name: str, why: str):
        super().__init__(f"invalid parameter '{name}': {why}")
        self.name = name
        self.why = why


@dataclass(frozen=True)
class Spec:
    """One parameter. `default` fixes the type and is the default (the generated
    config/nodes/<node>.yaml states it; the node reads that installed file at start-up).

    unit: stated in the description ("m", "kg", "s", "Hz", ...; "" for none).
    lo/hi: the range rclpy enforces (floating_point_range or integer_range by type).
    choices: the accepted strings (checked by the node: rclpy has no enumerations).
    live: the node applies a change at runtime; otherwise the parameter is read-only.
    dynamic: the parameter accepts more than one type (dynamic typing).
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    live: bool = False
    dynamic: bool = False

    def text(self) -> str:
        """The whole description, as `ros2 param describe` and the docs show it: sentences."""
        text = self.description.strip()
        if self.unit:
            text += f" [{self.unit}]"
        if not text.endswith((".", "!", "?")):
            text += "."
        if self.choices:
            text += f" One of: {', '.join(repr(c) if c == '' else c for c in self.choices)}."
        if self.lo is not None and not self.dynamic:
            text += f" Range [{self.lo:g}, {self.hi:g}]."
        text += " Can be changed at runtime." if self.live else " Read-only: set at start-up."
        return text

    def check(self, value: Any) -> str | None:
        """Why `value` is refused beyond what rclpy checks (choices, array ranges), or None."""
        if self.choices is not None and value not in self.choices:
            return f"{value!r} is not one of {', '.join(self.choices)}"
        if isinstance(value, (list, tuple)) and self.lo is not None:
            bad = [x for x in value if not (self.lo <= x <= self.hi)]
            if bad:
                return f"{bad[0]!r} is outside [{self.lo:g}, {self.hi:g}]{unit_suffix(self)}"
        return None


class Settings:
    """Base of a node's settings dataclass (as rosbag2's PlayOptions): one field per parameter
    it reads, named as the parameter ('.' -> '_'). ROS-free: `from_values` takes a dict (a
    test, an offline tool), `from_params` a node's Params; a subclass validates in
    `__post_init__` (raising ParameterError) and adds derived fields with defaults."""

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> Self:
        given = {k.replace(".", "_"): v for k, v in values.items()}
        names = [f.name for f in dataclasses.fields(cls) if f.init]
        missing = [n for n in names if n not in given and
                   next(f for f in dataclasses.fields(cls) if f.name == n).default is dataclasses.MISSING]
        if missing:
            raise ParameterError(missing[0], "not given")
        return cls(**{n: given[n] for n in names if n in given})

    @classmethod
    def from_params(cls, params) -> Self:
        """From a node's declared parameters (nodes.params.Params)."""
        return cls.from_values(params.values())


def unit_suffix(spec: Spec) -> str:
    return f" {spec.unit}" if spec.unit else ""


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """' (did you mean body_size?)' for a near miss of a known name, else ''."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.75)
    return f" (did you mean {close[0]}?)" if close else ""


def load_defaults(config_name: str, path: Path | None = None) -> dict[str, Any]:
    """config/nodes/<config_name>.yaml, section `/**` -> ros__parameters, nested keys joined
    by '.'."""
    path = path or node_config_file(config_name)
    data = yaml.safe_load(path.read_text()) or {}
    try:
        params = data["/**"]["ros__parameters"]
    except (KeyError, TypeError):
        raise ValueError(f"{path}: expected a '/**:' section with 'ros__parameters'") from None
    out: dict[str, Any] = {}

    def walk(prefix: str, d: dict) -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(f"{prefix}{k}.", v)
            else:
                out[f"{prefix}{k}"] = v

    walk("", params)
    return out
