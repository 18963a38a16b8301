"""check_bag's pass/fail limits (config/check.yaml, or a file given with --thresholds): one
place, read by both scorers (offline/check.py with markers, offline/score.py without)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import yaml

from ..paths import config_file


@dataclass(frozen=True)
class Thresholds:
    """config/check.yaml: exceeding any of these makes check_bag exit 1.

    latency_p99_ms_target is reported against, never gated on; latency_p99_ms_max (None =
    off, the default) gates: a slow machine is not wrong data.
    """

    pipeline_nrmse_max: float = 0.02
    state_max_abs_rad: float = 1e-6
    loss_max: int = 0
    latency_p99_ms_target: float = 1.0
    latency_p99_ms_max: float | None = None
    model_group_median_nrmse_max: float = 0.10
    model_rel_floor: float = 0.05
    model_min_coverage: float = 0.9
    tail_grace_s: float = 0.1
    markerless_nrmse_max: float = 0.5
    old_stamps_latency_s: float = 1.0
    markerless_still_deg: float = 2.0
    markerless_posture_rms_deg_max: float = 5.0
    torque_bound_factor: float = 1.0

    @classmethod
    def load(cls, path: str | Path | None = None) -> Thresholds:
        path = Path(path) if path is not None else config_file("check.yaml")
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh) or {}
        if not isinstance(data, dict):
            raise ValueError(f"{path}: expected a mapping of thresholds")  # noqa: TRY004 - one-line config error
        known = {f.name: f.type for f in fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ValueError(f"{path}: unknown threshold(s) {unknown}; known: {sorted(known)}")
        def value(key, v):
            if v is None and key == "latency_p99_ms_max":
                return None
            try:
                return int(v) if key == "loss_max" else float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{path}: {key} must be a number, got {v!r}") from None

        return cls(**{k: value(k, v) for k, v in data.items()})
