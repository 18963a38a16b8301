"""ROS parameters declared the ROS way: descriptors, ranges, read-only, defaults from YAML.

Every node declares its parameters through `Params`:
- a `Spec` (spec.py, ROS-free) is the one definition of a parameter; the installed
  `config/nodes/<node>.yaml` is generated from the Specs (catalog.py) and read as the
  defaults at start-up (section `/**`), so an installed file can be edited and a test
  checks the committed files against the Specs, values included;
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
  named in one warning ("did you mean" a near miss) and ignored (undeclared again). They
  are found with public API only: the node is created with
  `automatically_declare_parameters_from_overrides=True` (see `NODE_OPTIONS`), so every
  override is a declared parameter before `Params` runs.

A refused value at start-up raises ParameterError: one line naming the parameter, and the
node's runner exits with code 2.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Sequence
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

from .spec import ParameterError, Spec, did_you_mean, load_defaults, unit_suffix

__all__ = ["NODE_OPTIONS", "ParameterError", "Params", "Spec", "descriptor", "finite", "init_node",
           "load_defaults"]  # Spec, ParameterError, load_defaults: defined in spec.py (ROS-free)

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


def descriptor(spec: Spec) -> ParameterDescriptor:
    """The ROS descriptor of a Spec: its text, read-only unless live, rclpy's range."""
    d = ParameterDescriptor(description=spec.text(), read_only=not spec.live,
                            dynamic_typing=spec.dynamic)
    if spec.lo is not None and not spec.dynamic:
        if isinstance(spec.default, float) or (
                isinstance(spec.default, list) and spec.default and isinstance(spec.default[0], float)):
            d.floating_point_range = [FloatingPointRange(
                from_value=float(spec.lo), to_value=float(spec.hi), step=0.0)]
        elif isinstance(spec.default, int) and not isinstance(spec.default, bool):
            d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi), step=0)]
    if spec.choices:
        d.additional_constraints = f"one of: {', '.join(spec.choices)}"
    return d


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
            raise ParameterError(f"config/nodes/{config_name}.yaml", f"cannot read the defaults: "
                                 f"{str(exc).splitlines()[0]}") from None
        extra = sorted(set(yaml_defaults) - set(self.specs))
        if extra:  # a typo in the installed file: a packaging bug, say so plainly
            raise ParameterError(extra[0], f"in config/nodes/{config_name}.yaml but not a "
                                 "parameter of this node")
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
                    node.declare_parameter(s.name, coerced, descriptor(s), ignore_override=True)
                else:  # rclpy applies the override and checks its type against the default's
                    node.declare_parameter(s.name, default, descriptor(s))
            except InvalidParameterTypeException:
                raise ParameterError(s.name, f"must be {_type_word(s.default)}, got {value!r}") from None
            except InvalidParameterValueException:
                raise ParameterError(s.name, f"{value!r} is outside [{s.lo:g}, {s.hi:g}]"
                                     f"{unit_suffix(s)}") from None
            why = s.check(value)
            if why:
                raise ParameterError(s.name, why)
            if isinstance(value, list) and isinstance(s.default, list) and not value and s.default:
                raise ParameterError(s.name, f"must be a non-empty list of {_type_word(s.default)[10:]}")

        node.add_on_set_parameters_callback(_refuse_system_changes)

    def warn_unknown(self) -> None:
        for name in self.unknown:
            self._node.get_logger().warning(
                f"ignoring unknown parameter '{name}' (not a parameter of this node"
                f"{did_you_mean(name, self.specs).replace(' (', '; ').rstrip(')')})")

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
