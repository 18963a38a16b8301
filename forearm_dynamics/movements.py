"""The paper's 65 movements: minimum-jerk transitions between postures, as data."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import yaml

from .description import JOINT_NAMES, load_description
from .paths import config_file

NV = len(JOINT_NAMES)
_INDEX = {n: i for i, n in enumerate(JOINT_NAMES)}


def min_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s, ds/dtau, d2s/dtau2 of the quintic 10t^3 - 15t^4 + 6t^5, clamped outside [0, 1]."""
    t = np.clip(tau, 0.0, 1.0)
    t2 = t * t
    s = t2 * t * (10.0 - 15.0 * t + 6.0 * t2)
    ds = 30.0 * t2 * (1.0 - 2.0 * t + t2)
    dds = 60.0 * t * (1.0 - 3.0 * t + 2.0 * t2)
    return s, ds, dds


@dataclass(frozen=True)
class Movement:
    """One movement: `start` -> `stop` postures (rad) over `transition` s after `hold_before`."""

    id: int
    name: str
    elbow: str
    hand_number: int
    start: np.ndarray  # (20,)
    stop: np.ndarray  # (20,)
    hold_before: float
    transition: float
    hold_after: float

    @property
    def duration(self) -> float:
        return self.hold_before + self.transition + self.hold_after

    @property
    def moving(self) -> tuple[str, ...]:
        return tuple(n for n, a, b in zip(JOINT_NAMES, self.start, self.stop, strict=True) if a != b)

    def sample_times(self, rate_hz: float = 1000.0) -> np.ndarray:
        n = round(self.duration * rate_hz)
        return np.arange(n) / float(rate_hz)

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd), each (N, 20), at times t (s from the movement's start), analytic."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.ndim != 1:
            raise ValueError(f"evaluate expects a 1-D array of times, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("evaluate got NaN or inf times")
        s, ds, dds = min_jerk((t - self.hold_before) / self.transition)
        delta = self.stop - self.start
        q = self.start + s[:, None] * delta
        qd = (ds / self.transition)[:, None] * delta
        qdd = (dds / self.transition**2)[:, None] * delta
        return q, qd, qdd


@lru_cache(maxsize=1)
def _spec() -> dict:
    with open(config_file("movements.yaml"), encoding="utf-8") as fh:
        return yaml.safe_load(fh)


def _expand(spec: dict, mapping: dict | None) -> list[tuple[str, str]]:
    out = []
    for key, where in (mapping or {}).items():
        names = spec["sets"].get(key, [key])
        for n in names:
            if n not in _INDEX:
                raise ValueError(f"movements.yaml names unknown joint {n!r}")
            out.append((n, where))
    return out


#: Three readings of the paper's "stop at 45 % of the maximal or minimal range" (the
#: fraction is config/movements.yaml `stop_fraction`); `stop_rule` there picks the default.
STOP_RULES = {
    "toward_limit": "neutral + f x (limit - neutral): f of the way from neutral to the limit",
    "of_limit": "f x limit: f times the limit angle itself",
    "of_range": "neutral +/- f x (upper - lower): f of the full range from neutral",
}


def stop_angle(rule: str, frac: float, start: float, lo: float, hi: float, toward: str) -> float:
    """Where a DOF moving from `start` toward its `toward` ("max"/"min") limit stops."""
    limit = hi if toward == "max" else lo
    if rule == "toward_limit":
        return start + frac * (limit - start)
    if rule == "of_limit":
        return frac * limit
    if rule == "of_range":
        return start + (1.0 if toward == "max" else -1.0) * frac * (hi - lo)
    raise ValueError(f"stop rule must be one of {tuple(STOP_RULES)}, got {rule!r}")


@lru_cache(maxsize=4)
def movement_library(stop_rule: str | None = None) -> tuple[Movement, ...]:
    """The 65 movements in id order.

    stop_rule: None = config/movements.yaml's (today "toward_limit"); the other readings
    (STOP_RULES) are for the analysis's sensitivity study.
    """
    spec = _spec()
    rule = default_stop_rule() if stop_rule is None else stop_rule
    if rule not in STOP_RULES:
        raise ValueError(f"stop rule must be one of {tuple(STOP_RULES)}, got {rule!r}")
    ranges = load_description().ranges
    lo = np.array([ranges[n][0] for n in JOINT_NAMES])
    hi = np.array([ranges[n][1] for n in JOINT_NAMES])
    neutral = 0.5 * (lo + hi)
    frac = float(spec["stop_fraction"])
    timing = spec["timing"]
    movements = []
    for hm in spec["hand_movements"]:
        base = neutral.copy()
        for n, where in _expand(spec, hm.get("hold")):
            i = _INDEX[n]
            base[i] = {"full_max": hi[i], "full_min": lo[i]}[where]
        stop = base.copy()
        for n, where in _expand(spec, hm["move"]):
            i = _INDEX[n]
            stop[i] = stop_angle(rule, frac, base[i], lo[i], hi[i], where)
        for k, cond in enumerate(spec["elbow_conditions"]):
            start_m, stop_m = base.copy(), stop.copy()
            e0, e1 = np.deg2rad(cond["elbow_deg"])
            start_m[_INDEX["elbow_flexion"]] = e0
            stop_m[_INDEX["elbow_flexion"]] = e1
            movements.append(Movement(
                id=(int(hm["number"]) - 1) * len(spec["elbow_conditions"]) + k + 1,
                name=hm["name"],
                elbow=cond["label"],
                hand_number=int(hm["number"]),
                start=start_m,
                stop=stop_m,
                hold_before=float(timing["hold_before"]),
                transition=float(timing["transition"]),
                hold_after=float(timing["hold_after"]),
            ))
    movements.sort(key=lambda m: m.id)
    return tuple(movements)


def get_movement(movement_id: int) -> Movement:
    lib = movement_library()
    if not isinstance(movement_id, (int, np.integer)) or not 1 <= movement_id <= len(lib):
        raise ValueError(f"movement id must be an integer 1..{len(lib)}, got {movement_id!r}")
    return lib[int(movement_id) - 1]


def default_stop_rule() -> str:
    return str(_spec().get("stop_rule", "toward_limit"))


def default_rate_hz() -> float:
    return float(_spec()["timing"]["rate_hz"])
