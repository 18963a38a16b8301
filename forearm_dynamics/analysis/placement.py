"""Where to split the forearm and where to put the pro/sup axis: the paper's joint placement.

Objective: mean over the 65 movements of the pro/sup NRMSE plus that of the elbow, each
normalised by the DOF's peak-to-peak over all movements (nrmse_global). Per-movement
normalisation would let the few movements with a near-still pro/sup or elbow torque (a tiny
peak-to-peak) dominate the optimum; the global one weighs every movement by its N·m error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from ..dynamics import build_model
from .comparison import Trials, compare

CM = 0.01  # the optimiser works in cm so every coordinate has a similar scale


@dataclass(frozen=True)
class Placement:
    split: float = 0.0
    axis_offset_proximal: tuple[float, float] = (0.0, 0.0)  # (anterior, lateral), m
    axis_offset_distal: tuple[float, float] = (0.0, 0.0)

    def overrides(self) -> dict:
        return {"split": self.split, "axis_offset_proximal": list(self.axis_offset_proximal),
                "axis_offset_distal": list(self.axis_offset_distal)}

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def model_of(p: Placement, body_size=50):
    kind = "solid" if p.split == 0.0 else "segmented"
    ov = p.overrides()
    if kind == "solid":
        ov.pop("split")
    return build_model(kind, body_size=body_size, **ov)


def objective(p: Placement, reference: np.ndarray, trials: Trials, body_size=50) -> float:
    e = compare(model_of(p, body_size), reference, trials)
    return float(np.nanmean(e.nrmse_global[:, 1]) + np.nanmean(e.nrmse_global[:, 0]))


def _placement(x: np.ndarray, free: tuple[str, ...], base: Placement) -> Placement:
    vals = base.as_dict()
    k = 0
    if "split" in free:
        vals["split"] = float(np.clip(x[k], 0.0, 1.0))
        k += 1
    for end in ("proximal", "distal"):
        if end in free:
            vals[f"axis_offset_{end}"] = (float(x[k]) * CM, float(x[k + 1]) * CM)
            k += 2
    return Placement(vals["split"], tuple(vals["axis_offset_proximal"]),
                     tuple(vals["axis_offset_distal"]))


def optimise(reference: np.ndarray, trials: Trials, free: tuple[str, ...],
             start: Placement, body_size=50, callback=None) -> tuple[Placement, float, int]:
    """Nelder-Mead over the free coordinates (split in [0, 1]; offsets within ±5 cm)."""
    if free == ("split",):
        r = minimize_scalar(lambda s: objective(_placement(np.array([s]), free, start), reference,
                                                trials, body_size),
                            bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-3})
        return _placement(np.array([r.x]), free, start), float(r.fun), int(r.nfev)
    x0, bounds = [], []
    if "split" in free:
        x0.append(start.split)
        bounds.append((0.0, 1.0))
    for end in ("proximal", "distal"):
        if end in free:
            x0 += [v / CM for v in getattr(start, f"axis_offset_{end}")]
            bounds += [(-5.0, 5.0)] * 2

    def f(x):
        if callback:
            callback()
        return objective(_placement(x, free, start), reference, trials, body_size)

    r = minimize(f, np.array(x0, float), method="Nelder-Mead", bounds=bounds,
                 options={"xatol": 1e-3, "fatol": 1e-7, "maxfev": 800})
    return _placement(r.x, free, start), float(r.fun), int(r.nfev)


def error_surface(reference: np.ndarray, trials: Trials, at: Placement, splits: np.ndarray,
                  distal_anterior: np.ndarray, callback=None) -> np.ndarray:
    """Objective over split x the distal anterior offset, the other coordinates at `at`."""
    out = np.empty((len(splits), len(distal_anterior)))
    for i, s in enumerate(splits):
        for j, d in enumerate(distal_anterior):
            p = Placement(float(s), at.axis_offset_proximal, (float(d), at.axis_offset_distal[1]))
            out[i, j] = objective(p, reference, trials)
            if callback:
                callback()
    return out
