"""Why the simplified models' elbow torque differs from the anatomical one, in numbers.

Two causes, separated by the mass-matched cylinder (same mass, radius and length as the
uniform one, moved so its COM is the ulna + radius composite's): "cylinder geometry" (a
uniform cylinder from elbow to wrist puts the forearm COM at its middle) and "pro/sup
placement" (what turns with pro/sup, and about which axis).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..anthropometry import resolve_body_size
from ..builders import forearm_cylinder
from ..description import load_description
from ..movements import movement_library
from .placement import VARIANTS, Scorer

ELBOW_ANGLES_DEG = (0.0, 45.0, 90.0)


def com_geometry() -> dict:
    """Where the composite COM sits relative to the uniform cylinder's (mm, elbow frame)."""
    cyl = forearm_cylinder(load_description(), resolve_body_size(50))
    c = cyl.composite_com
    return {"cylinder_length_mm": 1000 * cyl.length,
            "uniform_com_along_mm": 500 * cyl.length,
            "composite_com_along_mm": 1000 * float(c @ cyl.axis),
            "composite_com_anterior_mm": 1000 * float(c @ cyl.anterior),
            "composite_com_lateral_mm": 1000 * float(c @ cyl.lateral),
            "mass_kg": cyl.mass, "radius_mm": 1000 * cyl.radius}


def static_differences(scorer: Scorer, overrides: dict) -> dict:
    """Gravity-only elbow torque (N·m) of each model minus the anatomical one, neutral
    posture (movement 1's start), elbow at 0, 45, 90 deg."""
    q0 = movement_library()[0].start.copy()
    anat = scorer.anatomical_model()
    out = {}
    for name in ("solid", "solid_mass_matched", "paper", "oblique"):
        m = scorer.model(VARIANTS[name], **overrides.get(name, {}))
        diffs = []
        for deg in ELBOW_ANGLES_DEG:
            q = q0.copy()
            q[0] = np.deg2rad(deg)
            diffs.append(float(m.gravity_torques(q)[0] - anat.gravity_torques(q)[0]))
        out[name] = dict(zip((f"elbow_{d:g}" for d in ELBOW_ANGLES_DEG), diffs, strict=True))
    return out


def rmse_decomposition(scorer: Scorer, overrides: dict) -> dict:
    """Mean elbow RMSE (N·m) over the movements: uniform vs mass-matched x solid vs oblique."""
    out = {}
    for name in ("solid", "oblique"):
        for cyl in ("uniform", "mass_matched"):
            v = replace(VARIANTS[name], cylinder=cyl)
            e = scorer.errors(v, **overrides.get(name, {}))
            out[f"{name}_{cyl}"] = {"elbow_rmse_mean": float(np.mean(e.rmse[:, 0])),
                                    "elbow_nrmse_global_mean": float(np.mean(e.nrmse_global[:, 0]))}
    return out


def still_elbow_ranges(reference: np.ndarray) -> dict:
    """Reference elbow peak-to-peak (N·m) in the movements where the elbow is still."""
    lib = movement_library()
    still = [k for k, m in enumerate(lib) if m.start[0] == m.stop[0]]
    ptp = np.ptp(reference[still, :, 0], axis=1)
    return {"n": len(still), "min": float(ptp.min()), "median": float(np.median(ptp)),
            "max": float(ptp.max())}


def elbow_analysis(scorer: Scorer, overrides: dict) -> dict:
    return {"com": com_geometry(), "static_difference_nm": static_differences(scorer, overrides),
            "rmse": rmse_decomposition(scorer, overrides),
            "still_elbow_reference_ptp_nm": still_elbow_ranges(scorer.reference)}
