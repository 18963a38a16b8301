"""Torque errors against a reference: NRMSE per DOF per movement, and its companions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filtering import analysis_config


@dataclass(frozen=True)
class ErrorSet:
    """Errors of one model over M movements x 20 DOFs (NaN where left out)."""

    nrmse: np.ndarray  # (M, 20) RMSE / reference peak-to-peak of that movement and DOF
    nrmse_global: np.ndarray  # (M, 20) RMSE / reference peak-to-peak of that DOF over all M
    rmse: np.ndarray  # (M, 20) N·m
    ptp: np.ndarray  # (M, 20) reference peak-to-peak, N·m
    left_out: int  # entries of `nrmse` left out for a peak-to-peak under the floor


def rmse(test: np.ndarray, ref: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.sqrt(np.mean((np.asarray(test) - np.asarray(ref)) ** 2, axis=axis))


def movement_errors(tests: list[np.ndarray], refs: list[np.ndarray],
                    floor: float | None = None) -> ErrorSet:
    """tests/refs: per movement (N_i, 20) filtered torques, same samples."""
    floor = float(analysis_config()["ptp_floor_nm"] if floor is None else floor)
    if len(tests) != len(refs):
        raise ValueError(f"{len(tests)} test series vs {len(refs)} reference series")
    for k, (a, b) in enumerate(zip(tests, refs, strict=True)):
        if np.shape(a) != np.shape(b):
            raise ValueError(f"movement {k}: test shape {np.shape(a)} != reference {np.shape(b)}")
    err = np.array([rmse(a, b) for a, b in zip(tests, refs, strict=True)])
    ptp = np.array([np.ptp(b, axis=0) for b in refs])
    lo = np.array([b.min(axis=0) for b in refs]).min(axis=0)
    hi = np.array([b.max(axis=0) for b in refs]).max(axis=0)
    global_ptp = hi - lo
    keep = ptp >= floor
    with np.errstate(divide="ignore", invalid="ignore"):
        nrmse = np.where(keep, err / ptp, np.nan)
        nrmse_global = np.where(global_ptp >= floor, err / global_ptp, np.nan)
    return ErrorSet(nrmse, nrmse_global, err, ptp, int((~keep).sum()))


def summarize(values: np.ndarray) -> dict[str, float]:
    """Mean, quartiles and max of the finite values (one dot per movement and DOF)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"n": 0, "mean": float("nan"), "q1": float("nan"), "median": float("nan"),
                "q3": float("nan"), "max": float("nan")}
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return {"n": int(v.size), "mean": float(v.mean()), "q1": float(q1), "median": float(med),
            "q3": float(q3), "max": float(v.max())}
