"""Causal state estimation: q, q̇, q̈ of every joint from stamped (noisy) samples.

ROS-free. Every estimator implements `StateEstimator` (base.py) and is registered by name
in ESTIMATORS; `make_estimator(name, n, settings)` builds one. Its settings are described
by `SettingSpec`s (name, default, unit, range, description) so the node can declare them
as ROS parameters `estimator.<setting>` without knowing the method.
"""

from __future__ import annotations

from collections.abc import Mapping

from .backward import BackwardDifference
from .base import SettingSpec, StateEstimator
from .butterworth import ButterworthDifference
from .kalman import KalmanCA
from .savgol import SavitzkyGolay

#: name -> class. The first entry is the default (chosen by benchmarks/estimation.py).
ESTIMATORS: dict[str, type[StateEstimator]] = {
    cls.name: cls
    for cls in (KalmanCA, BackwardDifference, ButterworthDifference, SavitzkyGolay)
}

#: What the estimation benchmark measured best for measured (noisy, positions-only) input at
#: every rate (benchmarks/estimation.py), and the node's default: right for sensors without
#: tuning, within 2 % NRMSE of the exact pipeline on exact input, a few us per sample.
RECOMMENDED_FOR_MEASURED_INPUT = "kalman"

DEFAULT_ESTIMATOR = next(iter(ESTIMATORS))


def make_estimator(name: str, n: int, settings: Mapping[str, float] | None = None) -> StateEstimator:
    """The estimator `name` for n joints; ValueError names an unknown method or setting."""
    try:
        cls = ESTIMATORS[name]
    except KeyError:
        raise ValueError(f"unknown estimator {name!r}: one of {', '.join(ESTIMATORS)}") from None
    return cls(n, dict(settings or {}))


def all_settings() -> dict[str, SettingSpec]:
    """Every estimator's settings by name (a name shared by two methods means the same)."""
    out: dict[str, SettingSpec] = {}
    for cls in ESTIMATORS.values():
        for s in cls.settings:
            out.setdefault(s.name, s)
    return out


__all__ = [
    "DEFAULT_ESTIMATOR",
    "ESTIMATORS",
    "RECOMMENDED_FOR_MEASURED_INPUT",
    "SettingSpec",
    "StateEstimator",
    "all_settings",
    "make_estimator",
]
