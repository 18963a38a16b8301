"""Torque errors against a reference: NRMSE per DOF per movement, and its companions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..filtering import analysis_config


@dataclass(frozen=True)
class ErrorSet:
    """Errors of one model over M movements x 20 DOFs (NaN where left out)."""

    nrmse: np.ndarray  # (M, 20) RMSE / reference peak-to-peak of that movement; NaN under the floor
    nrmse_all: np.ndarray  # (M, 20) the same with no floor (the paper's metric, literally)
    nrmse_global: np.ndarray  # (M, 20) RMSE / the DOF's reference peak-to-peak over all movements
    rmse: np.ndarray  # (M, 20) N·m
    ptp: np.ndarray  # (M, 20) reference peak-to-peak, N·m
    excluded: np.ndarray  # (20,) movements left out of `nrmse` per DOF (peak-to-peak under floor)
    floor_fraction: float

    @property
    def left_out(self) -> int:
        return int(self.excluded.sum())


def rmse(test: np.ndarray, ref: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.sqrt(np.mean((np.asarray(test) - np.asarray(ref)) ** 2, axis=axis))


def global_range(refs) -> np.ndarray:
    """(20,) peak-to-peak of each DOF's reference over every movement given."""
    lo = np.array([np.min(b, axis=0) for b in refs]).min(axis=0)
    hi = np.array([np.max(b, axis=0) for b in refs]).max(axis=0)
    return hi - lo


def movement_errors(tests: list[np.ndarray], refs: list[np.ndarray],
                    floor_fraction: float | None = None,
                    global_ptp: np.ndarray | None = None) -> ErrorSet:
    """tests/refs: per movement (N_i, 20) filtered torques, same samples.

    A movement whose reference peak-to-peak in a DOF is under `floor_fraction` of that DOF's
    peak-to-peak over all movements is left out of `nrmse` (and counted): dividing by a
    near-zero range measures the denominator, not the model. global_ptp: the all-movement
    ranges to normalise by when `refs` is a subset (held-out halves keep the same scale).
    """
    frac = float(analysis_config()["ptp_floor_fraction"] if floor_fraction is None
                 else floor_fraction)
    if len(tests) != len(refs):
        raise ValueError(f"{len(tests)} test series vs {len(refs)} reference series")
    for k, (a, b) in enumerate(zip(tests, refs, strict=True)):
        if np.shape(a) != np.shape(b):
            raise ValueError(f"movement {k}: test shape {np.shape(a)} != reference {np.shape(b)}")
    err = np.array([rmse(a, b) for a, b in zip(tests, refs, strict=True)])
    ptp = np.array([np.ptp(b, axis=0) for b in refs])
    gptp = global_range(refs) if global_ptp is None else np.asarray(global_ptp, float)
    keep = (ptp >= frac * gptp) & (ptp > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        nrmse_all = np.where(ptp > 0, err / ptp, np.nan)
        nrmse = np.where(keep, nrmse_all, np.nan)
        nrmse_global = np.where(gptp > 0, err / gptp, np.nan)
    return ErrorSet(nrmse, nrmse_all, nrmse_global, err, ptp, (~keep).sum(axis=0), frac)


def summarize(values: np.ndarray) -> dict[str, float]:
    """Mean, quartiles, median and max of the finite values (one per movement and DOF)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"n": 0, "mean": float("nan"), "q1": float("nan"), "median": float("nan"),
                "q3": float("nan"), "max": float("nan")}
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return {"n": int(v.size), "mean": float(v.mean()), "q1": float(q1), "median": float(med),
            "q3": float(q3), "max": float(v.max())}
