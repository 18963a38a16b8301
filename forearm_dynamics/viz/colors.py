"""The torque colour scale: |torque| / full scale of the joint's DOF group, through viridis.

A link is coloured by the |torque| of the joint that moves it, divided by the full scale of
that joint's DOF group (description.DOF_GROUPS: pro_sup, elbow, wrist, thumb, fingers, in
N·m), clipped to [0, 1] and mapped through viridis (dark purple = 0, yellow = full scale or
more): perceptually uniform and readable by colour-blind viewers. The default full scale of
a group (FULL_SCALE_NM) is the movement library's peak rounded up to two significant
digits: the largest |torque| of any of its joints in any of the 65 movements of the shipped
reference (the anatomical model in OpenSim, 50th percentile; `library_peaks()` computes it
and test_viz_markers checks the table against it). One scale per group, because an elbow
torque (~5 N·m) would make every finger (~0.04 N·m) look idle on a common scale. A table,
not a computation at start-up: decoding the reference costs ~0.5 s.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..description import DOF_GROUPS

#: viridis (matplotlib's) at 0, 1/8, ..., 1; linear in between (max error < 0.01 per channel).
VIRIDIS = np.array([
    (0.2670, 0.0049, 0.3294), (0.2788, 0.1755, 0.4834), (0.2297, 0.3224, 0.5457),
    (0.1727, 0.4488, 0.5579), (0.1276, 0.5669, 0.5506), (0.1579, 0.6838, 0.5017),
    (0.3692, 0.7889, 0.3829), (0.6785, 0.8637, 0.1895), (0.9932, 0.9062, 0.1439),
])
GROUPS = tuple(DOF_GROUPS)
#: Full scale (N·m) per DOF group: library_peaks() at the 50th percentile, rounded up.
FULL_SCALE_NM = {"pro_sup": 0.67, "elbow": 5.7, "wrist": 1.1, "thumb": 0.032, "fingers": 0.041}


def viridis(x) -> np.ndarray:
    """RGB (..., 3) for x in [0, 1] (clipped)."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0) * (len(VIRIDIS) - 1)
    k = np.minimum(x.astype(int), len(VIRIDIS) - 2)
    f = (x - k)[..., None]
    return VIRIDIS[k] * (1.0 - f) + VIRIDIS[k + 1] * f


@lru_cache(maxsize=4)
def library_peaks(body_size: int = 50) -> dict[str, float]:
    """Per DOF group, the peak |torque| (N·m) of the shipped reference's 65 movements.

    Decodes only this body size's part of the reference file (its torques are stored body
    size after body size), a third of the work of reading it all."""
    from ..reference import REFERENCE_FILE, decode_torques

    with np.load(REFERENCE_FILE) as z:
        code, shape = z["torques_code"], tuple(int(x) for x in z["shape"])
        sizes = [int(x) for x in z["body_sizes"]]
        names = [str(x) for x in z["joint_names"]]
    if body_size not in sizes:
        raise ValueError(f"no reference for body size {body_size!r}; have {tuple(sizes)}")
    per = shape[1] * shape[2] * shape[3]
    k = sizes.index(body_size)
    t = np.abs(decode_torques(code[:, k * per:(k + 1) * per], (1, *shape[1:]))[0])
    return {g: float(t[..., [names.index(n) for n in dofs]].max())
            for g, dofs in DOF_GROUPS.items()}


class TorqueColours:
    """Colours of joint torques for one joint order; full_scale: N·m per DOF group (a
    missing or non-positive group takes FULL_SCALE_NM, the library's peak)."""

    def __init__(self, joint_names, full_scale: dict[str, float] | None = None):
        peaks = FULL_SCALE_NM
        given = {g: float(v) for g, v in (full_scale or {}).items() if v is not None and v > 0}
        unknown = sorted(set(given) - set(GROUPS))
        if unknown:
            raise ValueError(f"unknown DOF group(s) {unknown}; groups: {', '.join(GROUPS)}")
        self.full_scale = {g: given.get(g, peaks[g]) for g in GROUPS}
        group_of = {n: g for g, names in DOF_GROUPS.items() for n in names}
        self.joint_names = tuple(joint_names)
        self._scale = np.array([self.full_scale[group_of[n]] for n in self.joint_names])

    def fraction(self, tau) -> np.ndarray:
        """|tau| / its group's full scale, clipped to [0, 1], per joint."""
        return np.clip(np.abs(np.asarray(tau, float)) / self._scale, 0.0, 1.0)

    def rgb(self, tau) -> np.ndarray:
        """(n, 3) colours of the joint torques tau (n,), N·m."""
        return viridis(self.fraction(tau))
