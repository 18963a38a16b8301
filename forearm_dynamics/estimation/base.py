"""The interface every state estimator implements, and how it describes its settings."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass(frozen=True)
class SettingSpec:
    """One estimator setting: what the node declares as ROS parameter `estimator.<name>`."""

    name: str
    default: float
    unit: str  # e.g. "Hz", "s", "rad"
    description: str
    lo: float = 0.0
    hi: float = 1e6


class StateEstimator(ABC):
    """q, q̇, q̈ (model order, (n,) float64) from stamped samples, causally.

    Contract:
    - `update(t_ns, q, qd)` takes the sample at t_ns (qd None: positions only); afterwards
      `self.q`, `self.qd`, `self.qdd` hold the estimate at t_ns. Returns `warm`: False while
      the history is too short for a real estimate (the caller counts such outputs).
      The caller guarantees t_ns increases; it calls `reset()` on a stamp jump.
    - `predict(t_ns)` overwrites q, qd, qdd with the extrapolation to t_ns ≥ the last
      update (for a fixed output rate); it never changes the filter state.
    - No allocation per sample: q, qd, qdd are preallocated and filled in place.
    - `describe(dt)` states the method, its settings, the lag of each estimate (s) at
      sample period dt and the noise level it believes in (rad, None if it has none).
    """

    name: ClassVar[str]
    settings: ClassVar[tuple[SettingSpec, ...]] = ()

    def __init__(self, n: int, settings: Mapping[str, float]):
        known = {s.name: s for s in self.settings}
        unknown = sorted(set(settings) - set(known))
        if unknown:
            raise ValueError(f"estimator {self.name!r} has no setting {', '.join(unknown)}")
        values = {s.name: float(settings.get(s.name, s.default)) for s in self.settings}
        for k, x in values.items():
            s = known[k]
            if not math.isfinite(x) or not s.lo <= x <= s.hi:
                raise ValueError(f"estimator setting {k} = {x!r} is outside [{s.lo}, {s.hi}] {s.unit}")
        self.values = values
        self.n = n
        self.q = np.zeros(n)
        self.qd = np.zeros(n)
        self.qdd = np.zeros(n)
        self._t_ns: int | None = None  # stamp of the last update

    @abstractmethod
    def reset(self) -> None:
        """Forget the history (after a stamp jump): the next samples warm up again."""

    @abstractmethod
    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        """Take the sample at t_ns; fill self.q/qd/qdd; return warm."""

    def predict(self, t_ns: int) -> None:
        """Constant-acceleration extrapolation from the last update (subclasses may refine)."""
        if self._t_ns is None:
            return
        dt = (t_ns - self._t_ns) * 1e-9
        if dt <= 0.0:
            return
        self.q += dt * self.qd + (0.5 * dt * dt) * self.qdd
        self.qd += dt * self.qdd

    @abstractmethod
    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        """Low-frequency delay (s) of the q, qd, qdd estimates at sample period dt."""

    def noise(self) -> float | None:
        """The position noise (rad, standard deviation) the estimator believes in."""
        return None

    def describe(self, dt: float, velocity_given: bool = False) -> dict:
        return {
            "method": self.name,
            "settings": dict(self.values),
            "lag_s": self.lag(dt, velocity_given),
            "at_sample_period_s": dt,
            "velocity_given": velocity_given,
            "noise_rad": self.noise(),
        }
