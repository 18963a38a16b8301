"""Body size: the 5th/50th/95th percentiles or a user's own, as scale factors on MoBL-ARMS."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import yaml

from .paths import config_file

DIMENSIONS = ("stature", "body_mass", "forearm_length", "hand_length", "hand_breadth")


@dataclass(frozen=True)
class BodySize:
    """Scale factors against the 50th-percentile male (MoBL-ARMS), plus a label."""

    label: str
    forearm: float  # forearm length ratio
    hand_length: float
    hand_breadth: float
    mass: float  # body mass ratio


@lru_cache(maxsize=1)
def _table() -> dict[str, Any]:
    with open(config_file("body_sizes.yaml"), encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def percentile_dimensions(percentile: int) -> dict[str, float]:
    table = _table()["percentiles"]
    if percentile not in table:
        raise ValueError(
            f"body_size {percentile!r} is not a tabulated percentile; use one of "
            f"{sorted(table)} or a dict of {', '.join(DIMENSIONS)}"
        )
    return dict(table[percentile])


def _check(name: str, value: Any) -> float:
    bounds = _table()["bounds"]
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    lo, hi = bounds[name]
    if not lo <= v <= hi:  # also refuses NaN
        raise ValueError(f"{name} = {v!r} is outside the plausible range [{lo}, {hi}]")
    return v


def resolve_body_size(body_size: int | str | Mapping[str, float] | BodySize = 50) -> BodySize:
    """Accept 5/50/95 (or "5th"), a BodySize, or a dict of stature/body_mass/segment lengths.

    A dict with only stature and body_mass scales every length by stature; explicit
    forearm_length, hand_length or hand_breadth override that length's ratio.
    """
    if isinstance(body_size, BodySize):
        return body_size
    ref = percentile_dimensions(_table()["reference_percentile"])
    if isinstance(body_size, str):
        digits = body_size.strip().removesuffix("th").removesuffix("p")
        if not digits.isdigit():
            raise ValueError(f"body_size {body_size!r} is not a percentile such as 5, 50 or 95")
        body_size = int(digits)
    if isinstance(body_size, bool):
        raise ValueError(f"body_size must be a percentile or a dict, got {body_size!r}")  # noqa: TRY004 - API promises ValueError
    if isinstance(body_size, int):
        dims = percentile_dimensions(body_size)
        return BodySize(
            label=f"p{body_size}",
            forearm=dims["forearm_length"] / ref["forearm_length"],
            hand_length=dims["hand_length"] / ref["hand_length"],
            hand_breadth=dims["hand_breadth"] / ref["hand_breadth"],
            mass=dims["body_mass"] / ref["body_mass"],
        )
    if not isinstance(body_size, Mapping):
        raise ValueError(  # noqa: TRY004 - API promises ValueError
            f"body_size must be 5, 50, 95 or a dict, got {type(body_size).__name__}"
        )
    unknown = set(body_size) - set(DIMENSIONS)
    if unknown:
        raise ValueError(f"unknown anthropometry keys {sorted(unknown)}; expected {DIMENSIONS}")
    dims = {k: _check(k, v) for k, v in body_size.items()}
    if "body_mass" not in dims:
        raise ValueError("a custom body size needs body_mass (kg)")
    if "stature" not in dims and not {"forearm_length", "hand_length", "hand_breadth"} <= set(dims):
        raise ValueError(
            "a custom body size needs stature, or all of forearm_length, hand_length, hand_breadth"
        )
    k = dims["stature"] / ref["stature"] if "stature" in dims else 1.0
    return BodySize(
        label="custom",
        forearm=dims["forearm_length"] / ref["forearm_length"] if "forearm_length" in dims else k,
        hand_length=dims["hand_length"] / ref["hand_length"] if "hand_length" in dims else k,
        hand_breadth=dims["hand_breadth"] / ref["hand_breadth"] if "hand_breadth" in dims else k,
        mass=dims["body_mass"] / ref["body_mass"],
    )
