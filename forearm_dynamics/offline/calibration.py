"""check_bag's score of the torque σ (joint_torques_std) where the truth is known.

With movement markers the truth of every sample is the SAME model's torque at the exact
analytic state, movement.evaluate(stamp - t0) (as check.py's pipeline error), noiseless even
when the marker says the input was noisy. That truth has no model-simplification error, so
the σ scored is the published one less its model part in quadrature (σ² - σ_model², the
per-DOF constant the config message states under std.model_std_nm). Per DOF group, over the
samples of every movement window that have both a torque and a finite σ (inf = warming up:
counted, left out):
  - coverage: the fraction of samples x DOFs with |τ - τ_true| <= 1.96 σ (95 % band);
  - ratio: RMS(σ) / RMSE (1 = as wide as the error; < 1 overconfident).
Reported; gated only when asked (check_bag --std-coverage LO,HI --std-ratio LO,HI).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..description import DOF_GROUPS
from ..movements import get_movement
from .check import LATE_MAX_NS
from .recording import Marker, Recording

Z95 = 1.96


@dataclass
class Calibration:
    groups: dict[str, dict[str, float]]  # group -> coverage, ratio, rmse_nm, rms_std_nm, n
    samples: int  # torque samples scored (with a finite σ)
    warming_up: int  # samples with an inf σ, left out
    unmatched: int  # joint_torques without a joint_torques_std of the same stamp
    model_part: str  # what was taken out
    failures: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        g = ", ".join(f"{k} {v['coverage']:.3f} / {v['ratio']:.2f}" for k, v in self.groups.items())
        out = [(f"torque σ (joint_torques_std) vs the exact-state truth, per DOF group, coverage of "
               f"±1.96σ / RMS(σ)/RMSE: {g}"),
               (f"  {self.samples} samples scored, {self.warming_up} warming up (σ inf) left out, "
               f"{self.unmatched} torques without a σ; {self.model_part}")]
        return out


def _windows(markers: list[Marker], stamps: np.ndarray):
    """(marker, mask of stamps in its window) as check.py's pipeline windows them."""
    for i, m in enumerate(markers):
        try:
            mv = get_movement(m.id)
        except (KeyError, ValueError):
            continue
        window = round(mv.duration * 1e9) + LATE_MAX_NS
        if i + 1 < len(markers):
            window = min(window, markers[i + 1].t0_ns - m.t0_ns)
        yield m, mv, (stamps >= m.t0_ns) & (stamps < m.t0_ns + window)


def score_calibration(rec: Recording, arm, config: dict | None) -> Calibration | None:
    """None when the bag has no joint_torques_std or no markers."""
    tq, sd = rec.joint_torques, rec.joint_torques_std
    if tq is None or sd is None or not len(sd) or not rec.markers:
        return None
    order = np.argsort(sd.stamp_ns, kind="stable")
    s_stamps = sd.stamp_ns[order]
    pos = np.searchsorted(s_stamps, tq.stamp_ns)
    pos = np.minimum(pos, len(s_stamps) - 1)
    matched = s_stamps[pos] == tq.stamp_ns
    std = np.full_like(tq.effort, np.nan)
    std[matched] = sd.effort[order][pos[matched]]
    model_sd = np.zeros(len(arm.joint_names))
    note = "no model part stated (config without std.model_std_nm): the σ scored as published"
    stated = ((config or {}).get("std") or {}).get("model_std_nm")
    if isinstance(stated, dict):
        model_sd = np.array([float(stated.get(n, 0.0)) for n in arm.joint_names])
        note = ("its model part (std.model_std_nm of the config, largest "
                f"{model_sd.max():.3g} N·m) taken out in quadrature: the truth is the same model")
    errs, sigs = [], []
    warming = 0
    for m, mv, sel in _windows(rec.markers, tq.stamp_ns):
        sel &= matched
        if not sel.any():
            continue
        s = std[sel]
        known = np.isfinite(s).all(axis=1)
        warming += int((~known).sum())
        if not known.any():
            continue
        t = (tq.stamp_ns[sel][known] - m.t0_ns) / 1e9
        errs.append(tq.effort[sel][known] - arm.inverse_dynamics(*mv.evaluate(t)))
        sigs.append(np.sqrt(np.maximum(s[known] ** 2 - model_sd**2, 0.0)))
    if not errs:
        return Calibration({}, 0, warming, int((~matched).sum()), note)
    err, sig = np.concatenate(errs), np.concatenate(sigs)
    groups = {}
    for g, dofs in DOF_GROUPS.items():
        idx = [arm.joint_names.index(d) for d in dofs]
        e, s = err[:, idx], sig[:, idx]
        rmse = float(np.sqrt(np.mean(e**2)))
        rms = float(np.sqrt(np.mean(s**2)))
        groups[g] = {"coverage": float(np.mean(np.abs(e) <= Z95 * s)),
                     "ratio": rms / rmse if rmse > 0 else float("inf"),
                     "rmse_nm": rmse, "rms_std_nm": rms, "n": int(e.size)}
    return Calibration(groups, len(err), warming, int((~matched).sum()), note)


def gate(cal: Calibration | None, coverage: tuple[float, float] | None,
         ratio: tuple[float, float] | None) -> list[str]:
    """Failure sentences for the asked ranges (none asked: none); a missing σ fails an ask."""
    if coverage is None and ratio is None:
        return []
    if cal is None or not cal.groups:
        return [("std calibration asked for, but the bag has no joint_torques_std (or no movement "
                "marker, or no sample with a finite σ) to score")]
    out = []
    for g, v in cal.groups.items():
        for key, rng in (("coverage", coverage), ("ratio", ratio)):
            if rng is not None and not rng[0] <= v[key] <= rng[1]:
                out.append(f"std calibration: {g} {key} {v[key]:.3f} outside [{rng[0]:g}, {rng[1]:g}]")
    return out
