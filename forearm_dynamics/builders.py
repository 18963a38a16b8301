"""The three forearm architectures, each + the shared hand, as a KinematicTree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .anthropometry import BodySize
from .description import ModelDescription, RigidBody
from .hand import hand_subtree
from .tree import Joint, KinematicTree, Link, combine, cylinder_inertia, massless

MODEL_KINDS = ("anatomical", "solid", "segmented")


def _scaled(body: RigidBody, length: float, mass: float) -> RigidBody:
    return RigidBody(body.mass * mass, body.com * length, body.inertia * mass * length**2)


@dataclass(frozen=True)
class ForearmCylinder:
    """The simplified forearm: a uniform cylinder from the elbow origin to the wrist centre."""

    mass: float
    radius: float
    wrist: np.ndarray  # wrist centre in the elbow (proximal) frame; the cylinder axis end
    anterior: np.ndarray  # unit cross-section directions used by axis offsets
    lateral: np.ndarray

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.wrist))

    @property
    def axis(self) -> np.ndarray:
        return self.wrist / self.length


def forearm_cylinder(desc: ModelDescription, size: BodySize) -> ForearmCylinder:
    """Cylinder with ulna + radius mass; radius by least squares on the principal moments.

    The composite inertia (about its COM, in the cylinder frame) has moments I_aa, I_ee, I_ll;
    a cylinder has m r^2/2 about its axis and m(3 r^2 + L^2)/12 across. Minimising the sum of
    squared relative errors is linear in r^2, so it has a closed form.
    """
    a = desc.anatomical
    ulna = _scaled(a.ulna, size.forearm, size.mass)
    radius = _scaled(a.radius, size.forearm, size.mass)
    ru = a.radioulnar_origin * size.forearm
    wrist = ru + a.wrist_centre * size.forearm
    m, _, inertia = combine([(ulna.mass, ulna.com, ulna.inertia),
                             (radius.mass, ru + radius.com, radius.inertia)])
    e = wrist / np.linalg.norm(wrist)
    ant = np.array([1.0, 0.0, 0.0]) - e[0] * e
    ant /= np.linalg.norm(ant)
    lat = np.cross(e, ant)
    length = np.linalg.norm(wrist)
    i_ee, i_aa, i_ll = (float(v @ inertia @ v) for v in (e, ant, lat))
    c = np.array([m / (2 * i_ee), m / (4 * i_aa), m / (4 * i_ll)])
    d = np.array([1.0, 1 - m * length**2 / (12 * i_aa), 1 - m * length**2 / (12 * i_ll)])
    r2 = max(float(c @ d / (c @ c)), 1e-8)
    return ForearmCylinder(m, float(np.sqrt(r2)), wrist, ant, lat)


def _validate_simplified(split: float, prox, dist) -> tuple[float, np.ndarray, np.ndarray]:
    try:
        split = float(split)
    except (TypeError, ValueError):
        raise ValueError(f"split must be a number in [0, 1], got {split!r}") from None
    if not 0.0 <= split <= 1.0:
        raise ValueError(f"split must be in [0, 1] (fraction of forearm length), got {split!r}")
    out = []
    for name, v in (("axis_offset_proximal", prox), ("axis_offset_distal", dist)):
        arr = np.asarray(v, dtype=float).reshape(-1)
        if arr.shape != (2,) or not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > 0.1):
            raise ValueError(f"{name} must be 2 finite offsets (anterior, lateral) within "
                             f"±0.1 m, got {v!r}")
        out.append(arr)
    return split, out[0], out[1]


def simplified_forearm(
    desc: ModelDescription, size: BodySize, split: float, offset_proximal, offset_distal
) -> tuple[list[Link], list[Joint], str, np.ndarray]:
    """Elbow + pro/sup over a (possibly split) cylinder. split = 0 is the solid model.

    The pro/sup axis runs from the elbow end to the wrist end of the cylinder, each end moved
    by its (anterior, lateral) offset in the end's cross-section; it points proximally so
    positive = pronation.
    """
    cyl = forearm_cylinder(desc, size)
    a = desc.anatomical
    rng = desc.ranges
    # Offsets are given at the 50th percentile and scale like every forearm length.
    prox, dist = np.asarray(offset_proximal) * size.forearm, np.asarray(offset_distal) * size.forearm
    p0 = prox[0] * cyl.anterior + prox[1] * cyl.lateral
    p1 = cyl.wrist + dist[0] * cyl.anterior + dist[1] * cyl.lateral
    axis = (p0 - p1) / np.linalg.norm(p0 - p1)
    split_point = split * cyl.wrist
    # Pro/sup joint origin: the point of the axis nearest the split point.
    joint_origin = p0 + ((split_point - p0) @ axis) * axis

    def part(frac0: float, frac1: float, origin: np.ndarray):
        m = cyl.mass * (frac1 - frac0)
        if m <= 0.0:
            return 0.0, np.zeros(3), np.zeros((3, 3))
        com = 0.5 * (frac0 + frac1) * cyl.wrist - origin
        return m, com, cylinder_inertia(m, cyl.radius, (frac1 - frac0) * cyl.length, cyl.axis)

    links = [Link("forearm_proximal", *part(0.0, split, np.zeros(3)), "cylinder"),
             Link("forearm_distal", *part(split, 1.0, joint_origin), "cylinder")]
    joints = [
        Joint("elbow_flexion", "humerus", "forearm_proximal", a.elbow_origin, a.elbow_axis,
              *rng["elbow_flexion"]),
        Joint("pro_sup", "forearm_proximal", "forearm_distal", joint_origin, axis, *rng["pro_sup"]),
    ]
    return links, joints, "forearm_distal", cyl.wrist - joint_origin


def anatomical_forearm(
    desc: ModelDescription, size: BodySize
) -> tuple[list[Link], list[Joint], str, np.ndarray]:
    """MoBL-ARMS: ulna hinged at the elbow, radius turning about the oblique pro_sup axis."""
    a = desc.anatomical
    ulna = _scaled(a.ulna, size.forearm, size.mass)
    radius = _scaled(a.radius, size.forearm, size.mass)
    links = [Link("ulna", ulna.mass, ulna.com, ulna.inertia, "bone"),
             Link("radius", radius.mass, radius.com, radius.inertia, "bone")]
    joints = [
        Joint("elbow_flexion", "humerus", "ulna", a.elbow_origin, a.elbow_axis,
              *desc.ranges["elbow_flexion"]),
        Joint("pro_sup", "ulna", "radius", a.radioulnar_origin * size.forearm,
              a.radioulnar_axis, *desc.ranges["pro_sup"]),
    ]
    return links, joints, "radius", a.wrist_centre * size.forearm


def build_tree(
    kind: str,
    desc: ModelDescription,
    size: BodySize,
    split: float | None = None,
    axis_offset_proximal=None,
    axis_offset_distal=None,
) -> KinematicTree:
    """The full 20-DOF tree of one model kind at one body size."""
    s = desc.simplified
    if kind == "anatomical":
        if split is not None or axis_offset_proximal is not None or axis_offset_distal is not None:
            raise ValueError("split and axis offsets apply to the solid and segmented models only")
        links, joints, parent, wrist = anatomical_forearm(desc, size)
    elif kind in ("solid", "segmented"):
        if kind == "solid" and split not in (None, 0, 0.0):
            raise ValueError("the solid model has no split (it is the segmented model at split=0)")
        # The solid model is the paper's: pro/sup about the cylinder's own axis, unless told.
        zero = np.zeros(2)
        defaults = (0.0, zero, zero) if kind == "solid" else (
            s.split, s.axis_offset_proximal, s.axis_offset_distal)
        sp, prox, dist = _validate_simplified(
            defaults[0] if split is None else split,
            defaults[1] if axis_offset_proximal is None else axis_offset_proximal,
            defaults[2] if axis_offset_distal is None else axis_offset_distal,
        )
        links, joints, parent, wrist = simplified_forearm(desc, size, sp, prox, dist)
    else:
        raise ValueError(f"unknown model kind {kind!r}; expected one of {MODEL_KINDS}")
    h_links, h_joints = hand_subtree(desc, size, parent, wrist)
    hum = desc.anatomical.humerus
    root = Link("humerus", hum.mass * size.mass, hum.com, hum.inertia * size.mass, "bone")
    links = [links[0], links[1], *h_links]
    return KinematicTree(kind, size, desc.gravity.copy(), root, tuple(links), tuple(joints + h_joints))


__all__ = ["MODEL_KINDS", "build_tree", "forearm_cylinder", "massless"]
