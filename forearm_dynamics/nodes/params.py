"""ROS parameters declared the ROS way: descriptors, ranges, read-only, defaults from YAML.

Every node declares its parameters through `Params`:
- the defaults are read from the installed `config/<node>.yaml` (section `/**`), so the
  README's "read once at start-up from config/<node>.yaml" is literally what happens; a
  `Spec` gives the type (its own default is used only for a setting the YAML leaves out);
- each parameter gets a `ParameterDescriptor`: a description with its unit, `read_only`
  unless the node can apply a change at runtime (`Spec.live`), and a
  `floating_point_range` / `integer_range` where one applies: rclpy itself then refuses an
  out-of-range (or NaN) value, at start-up and for `ros2 param set`;
- types are static (rclpy refuses a string for a number) except where a parameter really
  takes two types (`Spec.dynamic`, e.g. torque_node's body_size: 50 or "female_50").
  One exception to rclpy's strictness, at start-up only: an integer written for a
  floating-point parameter (`rate_hz: 1000` in YAML, `-p split:=1`) is taken as that
  number; at runtime rclpy's rule applies (`ros2 param set ... split 1.0`).
- unknown overrides (a typo, or a parameter of another node in a shared `/**` file) are
  named in one warning and ignored (undeclared again). They are found with public API
  only: the node is created with `automatically_declare_parameters_from_overrides=True`
  (see `NODE_OPTIONS`), so every override is a declared parameter before `Params` runs.

A refused value at start-up raises ParameterError: one line naming the parameter, and the
node's runner exits with code 2.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
)
from rclpy.node import Node

from ..errors import UsageError
from ..paths import config_file

#: Keyword arguments every node passes to rclpy's Node (see the module docstring).
NODE_OPTIONS = {"automatically_declare_parameters_from_overrides": True}


def init_node(node: Node, node_name: str) -> None:
    """Node.__init__ with NODE_OPTIONS; an override rclpy cannot type -> ParameterError.

    An empty list (`-p movements:=[]`) has no type in ROS 2: rclpy refuses to declare it
    with a ValueError that names no parameter; the command line names it.
    """
    try:
        Node.__init__(node, node_name, **NODE_OPTIONS)
    except ValueError as exc:
        if "PARAMETER_NOT_SET" not in str(exc):
            raise
        empty = [a.split(":=")[0] for a in sys.argv if a.replace(" ", "").endswith(":=[]")]
        raise ParameterError(empty[0] if empty else "(from a params file)",
                             "an empty list has no type in ROS 2; give at least one value") from None

#: Parameters rclpy declares itself on every node.
SYSTEM_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})

_TYPE_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


class ParameterError(UsageError, ValueError):
    """A parameter value the node refuses to start with (the node exits with code 2)."""

    def __init__(self, name: str, why: str):
        super().__init__(f"invalid parameter '{name}': {why}")
        self.name = name
        self.why = why


@dataclass(frozen=True)
class Spec:
    """One parameter. `default` fixes the type (the value comes from config/<node>.yaml).

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

    def descriptor(self) -> ParameterDescriptor:
        text = self.description
        if self.unit:
            text += f" [{self.unit}]"
        if self.choices:
            text += f" One of: {', '.join(self.choices)}."
        text += " Can be changed at runtime." if self.live else " Read-only: set at start-up."
        d = ParameterDescriptor(description=text, read_only=not self.live,
                                dynamic_typing=self.dynamic)
        if self.lo is not None and not self.dynamic:
            if isinstance(self.default, float) or (
                    isinstance(self.default, list) and self.default and isinstance(self.default[0], float)):
                d.floating_point_range = [FloatingPointRange(
                    from_value=float(self.lo), to_value=float(self.hi), step=0.0)]
            elif isinstance(self.default, int) and not isinstance(self.default, bool):
                d.integer_range = [IntegerRange(from_value=int(self.lo), to_value=int(self.hi), step=0)]
        if self.choices:
            d.additional_constraints = f"one of: {', '.join(self.choices)}"
        return d

    def check(self, value: Any) -> str | None:
        """Why `value` is refused beyond what rclpy checks (choices, array ranges), or None."""
        if self.choices is not None and value not in self.choices:
            return f"{value!r} is not one of {', '.join(self.choices)}"
        if isinstance(value, (list, tuple)) and self.lo is not None:
            bad = [x for x in value if not (self.lo <= x <= self.hi)]
            if bad:
                return f"{bad[0]!r} is outside [{self.lo:g}, {self.hi:g}]{_unit(self)}"
        return None


def _unit(spec: Spec) -> str:
    return f" {spec.unit}" if spec.unit else ""


def load_defaults(config_name: str, path: Path | None = None) -> dict[str, Any]:
    """config/<config_name>.yaml, section `/**` -> ros__parameters, nested keys joined by '.'."""
    path = path or config_file(f"{config_name}.yaml")
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


def _coerce(spec: Spec, value: Any) -> Any:
    """An integer given for a floating-point parameter (or array) -> float; else unchanged."""
    if isinstance(spec.default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(spec.default, list) and spec.default and isinstance(spec.default[0], float) \
            and isinstance(value, list) and value and all(
                isinstance(x, int) and not isinstance(x, bool) for x in value):
        return [float(x) for x in value]
    return value


def _type_word(default: Any) -> str:
    if isinstance(default, list):
        inner = _TYPE_WORDS.get(type(default[0]), "values") if default else "values"
        return f"a list of {inner.removeprefix('an ').removeprefix('a ')}s"
    return _TYPE_WORDS.get(type(default), type(default).__name__)


class Params:
    """Declares a node's Specs (defaults from config/<config_name>.yaml) and reads them."""

    def __init__(self, node: Node, specs: Iterable[Spec], config_name: str):
        self._node = node
        self.specs = {s.name: s for s in specs}
        try:
            yaml_defaults = load_defaults(config_name)
        except (OSError, yaml.YAMLError, ValueError) as exc:  # a broken install: one line
            raise ParameterError(f"config/{config_name}.yaml", f"cannot read the defaults: "
                                 f"{str(exc).splitlines()[0]}") from None
        extra = sorted(set(yaml_defaults) - set(self.specs))
        if extra:  # a typo in the installed file: a packaging bug, say so plainly
            raise ParameterError(extra[0], f"in config/{config_name}.yaml but not a parameter of "
                                 "this node")
        # What the user gave (params files, -p): declared already (NODE_OPTIONS).
        given = {n: node.get_parameter(n).value
                 for n in node.list_parameters([], 0).names if n not in SYSTEM_PARAMETERS}
        self.unknown = sorted(n for n in given if n not in self.specs)
        for name in list(given):
            node.undeclare_parameter(name)
        for s in self.specs.values():
            default = _coerce(s, yaml_defaults.get(s.name, s.default))
            value = given.get(s.name, default)
            coerced = _coerce(s, value)
            try:
                if coerced is not value:  # an integer for a float: rclpy would refuse the type
                    node.declare_parameter(s.name, coerced, s.descriptor(), ignore_override=True)
                else:  # rclpy applies the override and checks its type against the default's
                    node.declare_parameter(s.name, default, s.descriptor())
            except InvalidParameterTypeException:
                raise ParameterError(s.name, f"must be {_type_word(s.default)}, got {value!r}") from None
            except InvalidParameterValueException:
                raise ParameterError(s.name, f"{value!r} is outside [{s.lo:g}, {s.hi:g}]{_unit(s)}") from None
            why = s.check(value)
            if why:
                raise ParameterError(s.name, why)
            if isinstance(value, list) and isinstance(s.default, list) and not value and s.default:
                raise ParameterError(s.name, f"must be a non-empty list of {_type_word(s.default)[10:]}")

        node.add_on_set_parameters_callback(_refuse_system_changes)

    def warn_unknown(self) -> None:
        for name in self.unknown:
            self._node.get_logger().warning(
                f"ignoring unknown parameter '{name}' (not a parameter of this node)")

    def value(self, name: str) -> Any:
        return self._node.get_parameter(name).value

    def values(self, names: Iterable[str] | None = None) -> dict[str, Any]:
        return {n: self.value(n) for n in (self.specs if names is None else names)}

    def topic(self, name: str) -> str:
        v = self.value(name)
        try:
            self._node.resolve_topic_name(v)
        except Exception as exc:  # noqa: BLE001 - rclpy raises several types for bad names
            raise ParameterError(name, f"{v!r} is not a valid topic name ({exc})") from None
        return v

    def distinct_topics(self, names: Sequence[str], reserved: dict[str, str] | None = None) -> None:
        """Refuse two of these topic parameters naming one topic, or one naming a topic the
        node uses for something else (`reserved`: topic -> what it is for): the node would
        subscribe to its own output, or rcl would refuse a second type on the topic."""
        seen: dict[str, str] = {}
        for topic, what in (reserved or {}).items():
            seen[self._node.resolve_topic_name(topic)] = what
        for name in names:
            resolved = self._node.resolve_topic_name(self.value(name))
            if resolved in seen:
                raise ParameterError(name, f"{self.value(name)!r} is {resolved}, already the "
                                     f"{seen[resolved]}; it must be a topic of its own")
            seen[resolved] = f"topic of '{name}'"


def _refuse_system_changes(params) -> SetParametersResult:
    """use_sim_time etc. are not read-only in rclpy, but these nodes read them at start-up."""
    for p in params:
        if p.name in SYSTEM_PARAMETERS:
            return SetParametersResult(successful=False, reason=f"{p.name} is read-only: set at "
                                       "start-up (-p) only")
    return SetParametersResult(successful=True)


def finite(name: str, x: float) -> float:
    """rclpy's range check refuses NaN and inf; a parameter without a range is checked here."""
    if not math.isfinite(x):
        raise ParameterError(name, f"must be a finite number, got {x!r}")
    return x
