"""Typed, validated ROS parameters: one clear line per mistake instead of a traceback.

Every parameter is declared with dynamic typing so that `rate_hz: 1000` (an integer in
YAML) is not a type error for a float parameter; the getters below do the type checks and
range checks themselves and raise ParameterError naming the parameter.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter


class ParameterError(ValueError):
    """A parameter value the node refuses to start with (the node exits with code 2)."""

    def __init__(self, name: str, why: str):
        super().__init__(f"invalid parameter '{name}': {why}")
        self.name = name
        self.why = why


@dataclass(frozen=True)
class Spec:
    """One parameter: name, default value and a one-line description (shown by ros2 param)."""

    name: str
    default: Any
    description: str


class Params:
    """Declares a list of Specs on a node and reads them back with validation."""

    def __init__(self, node: Node, specs: Iterable[Spec]):
        self._node = node
        self._specs = {s.name: s for s in specs}
        for s in self._specs.values():
            node.declare_parameter(
                s.name, s.default, ParameterDescriptor(description=s.description, dynamic_typing=True)
            )

    def raw(self, name: str) -> Any:
        return self._node.get_parameter(name).value

    # -- typed getters -------------------------------------------------------------------
    def string(self, name: str, choices: Sequence[str] | None = None) -> str:
        v = self.raw(name)
        if not isinstance(v, str):
            raise ParameterError(name, f"must be a string, got {v!r}")
        if choices is not None and v not in choices:
            raise ParameterError(name, f"{v!r} is not one of {', '.join(choices)}")
        return v

    def boolean(self, name: str) -> bool:
        v = self.raw(name)
        if not isinstance(v, bool):
            raise ParameterError(name, f"must be true or false, got {v!r}")
        return v

    def integer(self, name: str, lo: int | None = None, hi: int | None = None) -> int:
        v = self.raw(name)
        if isinstance(v, bool) or not isinstance(v, int):
            raise ParameterError(name, f"must be an integer, got {v!r}")
        _check_range(name, v, lo, hi)
        return v

    def number(self, name: str, lo: float | None = None, hi: float | None = None) -> float:
        v = self.raw(name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ParameterError(name, f"must be a finite number, got {v!r}")
        _check_range(name, float(v), lo, hi)
        return float(v)

    def integers(self, name: str, lo: int | None = None, hi: int | None = None) -> list[int]:
        v = self.raw(name)
        if not isinstance(v, (list, tuple)) or not v or not all(
            isinstance(x, int) and not isinstance(x, bool) for x in v
        ):
            raise ParameterError(name, f"must be a non-empty list of integers, got {v!r}")
        for x in v:
            _check_range(name, x, lo, hi)
        return list(v)

    def topic(self, name: str) -> str:
        v = self.string(name)
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
            resolved = self._node.resolve_topic_name(self.string(name))
            if resolved in seen:
                raise ParameterError(name, f"{self.raw(name)!r} is {resolved}, already the "
                                     f"{seen[resolved]}; it must be a topic of its own")
            seen[resolved] = f"topic of '{name}'"

    # -- runtime changes -----------------------------------------------------------------
    def refuse_changes(self, allowed: Callable[[Parameter], bool] | None = None) -> None:
        """Reject runtime set_parameters: values are read once at start-up."""

        def on_set(params: list[Parameter]) -> SetParametersResult:
            for p in params:
                if allowed is None or not allowed(p):
                    return SetParametersResult(
                        successful=False,
                        reason=f"parameter '{p.name}' is read at start-up only; "
                        "restart the node to change it",
                    )
            return SetParametersResult(successful=True)

        self._node.add_on_set_parameters_callback(on_set)

    def unknown_overrides(self) -> list[str]:
        """Overrides given for this node that no Spec declares (likely typos)."""
        # rclpy has no public accessor for the parsed overrides; fall back to none.
        overrides = getattr(self._node, "_parameter_overrides", {}) or {}
        known = set(self._specs) | {"use_sim_time", "start_type_description_service"}
        return sorted(n for n in overrides if n not in known)


def _check_range(name: str, v: float, lo: float | None, hi: float | None) -> None:
    if lo is not None and v < lo:
        raise ParameterError(name, f"{v!r} is below the minimum {lo!r}")
    if hi is not None and v > hi:
        raise ParameterError(name, f"{v!r} is above the maximum {hi!r}")
