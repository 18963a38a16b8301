"""An object held in the hand: mass, centre of mass in the hand frame, optional inertia.

The hand frame is the carpus frame of the right arm: origin at the wrist centre (where the
wrist flexion and deviation axes meet), axes parallel to the forearm's at q = 0 — x toward
the thumb (anterior at neutral pro/sup), y toward the elbow (the fingers point along -y),
z toward the back of the hand (dorsal; the palm faces -z). For a left arm the same numbers
mean the same grasp in the mirrored hand (the whole tree, payload included, is mirrored),
so payload arguments never depend on the side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Refused above this: an object held in one hand, not a typo in grams.
MAX_MASS = 50.0  # kg
#: Refused farther than this from the wrist centre: not an object in the hand.
MAX_COM_DISTANCE = 0.5  # m
#: Default grasp: the COM of a 60 mm-diameter object (bottle, handle) held against the palm.
GRASP_OBJECT_RADIUS = 0.03  # m


@dataclass(frozen=True)
class Payload:
    """A rigid body welded to the carpus; inertia about its own COM, hand-frame axes."""

    mass: float  # kg
    com: np.ndarray  # (3,) m, hand frame
    inertia: np.ndarray  # (3, 3) kg m^2 about the COM; zeros = a point mass

    def as_dict(self) -> dict[str, Any]:
        i = self.inertia
        return {"mass": self.mass, "com": self.com.tolist(),
                "inertia": [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]}


def _finite_vector(name: str, value: Any, n: int, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {what}, got {value!r}") from None
    if arr.shape != (n,) or not np.isfinite(arr).all():
        raise ValueError(f"{name} must be {what} (finite), got {value!r}")
    return arr


def _inertia(value: Any) -> np.ndarray:
    """(Ixx, Iyy, Izz, Ixy, Ixz, Iyz) -> 3x3, refused unless a rigid body could have it."""
    ixx, iyy, izz, ixy, ixz, iyz = _finite_vector(
        "payload_inertia", value, 6, "6 numbers (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) in kg·m²")
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    moments = np.linalg.eigvalsh(inertia)
    tol = 1e-12 * max(1.0, float(np.abs(moments).max()))
    if moments[0] < -tol:
        raise ValueError(f"payload_inertia must be positive semi-definite (principal moments "
                         f"{moments.tolist()} kg·m²), got {value!r}")
    # A real body's principal moments obey I1 + I2 >= I3 (the smallest two vs the largest).
    if moments[0] + moments[1] < moments[2] - tol:
        raise ValueError(f"payload_inertia violates the triangle inequality of principal moments "
                         f"({moments.tolist()} kg·m²): no rigid body has it, got {value!r}")
    return inertia


def make_payload(mass: Any, com: Any, inertia: Any, default_com: np.ndarray) -> Payload | None:
    """Validated payload, or None when there is none (mass 0 and no inertia).

    Every refusal is a ValueError naming the argument (payload_mass, payload_com,
    payload_inertia), so a node can pass it on as the reason a parameter was refused.
    """
    try:
        if isinstance(mass, bool | str):
            raise TypeError
        m = float(mass)
    except (TypeError, ValueError):
        raise ValueError(f"payload_mass must be a number (kg), got {mass!r}") from None
    if not math.isfinite(m) or m < 0.0:
        raise ValueError(f"payload_mass must be a finite mass >= 0 kg, got {mass!r}")
    if m > MAX_MASS:
        raise ValueError(f"payload_mass {m!r} kg is more than {MAX_MASS:g} kg held in one hand")
    c = np.asarray(default_com, float).copy() if com is None else _finite_vector(
        "payload_com", com, 3, "3 coordinates (x, y, z) in m in the hand frame")
    if np.linalg.norm(c) > MAX_COM_DISTANCE:
        raise ValueError(f"payload_com {c.tolist()} is {np.linalg.norm(c):.3g} m from the wrist "
                         f"centre: more than {MAX_COM_DISTANCE} m is not an object in the hand")
    i = np.zeros((3, 3)) if inertia is None else _inertia(inertia)
    if m == 0.0:
        if np.any(i != 0.0):
            raise ValueError("payload_inertia needs a payload_mass > 0 (an inertia without mass)")
        return None
    gyration = math.sqrt(float(np.linalg.eigvalsh(i)[2]) / m)
    if gyration > MAX_COM_DISTANCE:
        raise ValueError(f"payload_inertia gives a {m:g} kg payload a radius of gyration of "
                         f"{gyration:.3g} m: more than {MAX_COM_DISTANCE} m is not an object "
                         "in the hand")
    return Payload(m, c, i)


__all__ = ["GRASP_OBJECT_RADIUS", "MAX_COM_DISTANCE", "MAX_MASS", "Payload", "make_payload"]
