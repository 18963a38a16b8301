"""Body size: men's and women's 5th/50th/95th percentiles or a user's own, as scale factors
on MoBL-ARMS (a 50th-percentile male)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from numbers import Integral
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


#: The tabulated sizes by name; an integer percentile p means f"male_{p}".
SEXES = ("male", "female")


def size_names() -> tuple[str, ...]:
    return tuple(_table()["sizes"])


def tabulated_dimensions(name: str, shown: Any = None) -> dict[str, float]:
    """Stature, body mass and segment lengths of a tabulated size ("male_50", "female_5"...)."""
    sizes = _table()["sizes"]
    if name not in sizes:
        raise ValueError(
            f"body_size {name if shown is None else shown!r} is not a tabulated size; "
            "use 5, 50, 95 (men), one of "
            f"{', '.join(sizes)}, or a dict of {', '.join(DIMENSIONS)}"
        )
    return dict(sizes[name])


def percentile_dimensions(percentile: int) -> dict[str, float]:
    """The men's percentile (5, 50, 95): what an integer body_size has always meant."""
    try:
        return tabulated_dimensions(f"male_{percentile}")
    except ValueError:
        raise ValueError(
            f"body_size {percentile!r} is not a tabulated percentile; use 5, 50 or 95 (men), "
            f"one of {', '.join(size_names())}, or a dict of {', '.join(DIMENSIONS)}"
        ) from None


def _size_name(text: str) -> str:
    """"50", "50th", "p50", "male_50" -> "male_50"; "female_5" -> "female_5"."""
    t = text.strip().lower()
    for sex in SEXES:
        if t.startswith(sex + "_"):
            return sex + "_" + t[len(sex) + 1:].removesuffix("th")
    digits = t.removeprefix("p").removesuffix("th")
    if not digits.isdigit():
        raise ValueError(
            f"body_size {text!r} is not a size such as 5, 50, 95, 'male_50' or 'female_50'"
        )
    return f"male_{int(digits)}"


def _label(name: str) -> str:
    """Men keep the labels p5/p50/p95 that bags and the reference file already carry."""
    sex, pct = name.split("_", 1)
    return f"p{pct}" if sex == "male" else name


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
    """Accept 5/50/95 (men; or "5th", "p50"), "male_5" ... "female_95", a BodySize, or a dict
    of stature/body_mass/segment lengths.

    Every ratio is to the male 50th percentile (MoBL-ARMS), women's sizes included. Labels:
    men p5/p50/p95 (as bags and the reference file have always carried), women female_5 ...

    A dict with only stature and body_mass scales every length by stature; explicit
    forearm_length, hand_length or hand_breadth override that length's ratio.
    """
    if isinstance(body_size, BodySize):
        return body_size
    ref = tabulated_dimensions(_table()["reference"])
    if isinstance(body_size, bool):
        raise ValueError(f"body_size must be a percentile or a dict, got {body_size!r}")  # noqa: TRY004 - API promises ValueError
    if isinstance(body_size, Integral):  # numpy integers too
        body_size = int(body_size)
        percentile_dimensions(body_size)  # the men's percentiles only: a clear error otherwise
        body_size = f"male_{body_size}"
    if isinstance(body_size, str):
        name = _size_name(body_size)
        dims = tabulated_dimensions(name, shown=body_size)
        return BodySize(
            label=_label(name),
            forearm=dims["forearm_length"] / ref["forearm_length"],
            hand_length=dims["hand_length"] / ref["hand_length"],
            hand_breadth=dims["hand_breadth"] / ref["hand_breadth"],
            mass=dims["body_mass"] / ref["body_mass"],
        )
    if not isinstance(body_size, Mapping):
        raise ValueError(  # noqa: TRY004 - API promises ValueError
            f"body_size must be 5, 50, 95, a name such as 'female_50' or a dict, "
            f"got {type(body_size).__name__}"
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
