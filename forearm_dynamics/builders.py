"""The three forearm architectures, each + the shared hand, as a KinematicTree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .anthropometry import BodySize
from .description import RADIUS_INERTIA, ModelDescription, RigidBody
from .hand import hand_subtree
from .payload import Payload
from .personal import check_side, personalise
from .tree import Joint, KinematicTree, Link, combine, cylinder_inertia, massless

MODEL_KINDS = ("anatomical", "solid", "segmented")
PLACEMENTS = ("paper", "parallel", "oblique")
CYLINDERS = ("uniform", "mass_matched")


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
    composite_com: np.ndarray  # ulna + radius COM (elbow frame, pro/sup 0)

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
    m, com, inertia = combine([(ulna.mass, ulna.com, ulna.inertia),
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
    return ForearmCylinder(m, float(np.sqrt(r2)), wrist, ant, lat, com)


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


def _axis_points(cyl: ForearmCylinder, prox: np.ndarray, dist: np.ndarray):
    """The pro/sup axis through the offset elbow end p0, pointing proximally (pronation +)."""
    p0 = prox[0] * cyl.anterior + prox[1] * cyl.lateral
    p1 = cyl.wrist + dist[0] * cyl.anterior + dist[1] * cyl.lateral
    return p0, (p0 - p1) / np.linalg.norm(p0 - p1)


def _mass_shift(cyl: ForearmCylinder, cylinder: str) -> np.ndarray:
    """How far the cylinder's mass is moved from the elbow-to-wrist segment's centre."""
    if cylinder == "uniform":
        return np.zeros(3)
    if cylinder == "mass_matched":
        return cyl.composite_com - 0.5 * cyl.wrist
    raise ValueError(f"cylinder must be one of {CYLINDERS}, got {cylinder!r}")


def _cylinder_part(cyl: ForearmCylinder, shift: np.ndarray, frac0: float, frac1: float,
                   origin: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, COM (relative to `origin`) and inertia of the cylinder between two cut planes.

    The cut planes sit at frac0 and frac1 of the elbow-to-wrist length; the (possibly
    shifted) cylinder of length L covers [u0, u0 + L] along its axis, so a shifted cylinder
    may reach proximal of the elbow or distal of the wrist: a part starting at 0 or ending
    at 1 reaches to the cylinder's end, and a part from 0 to 0 (or 1 to 1) is empty.
    """
    length, e = cyl.length, cyl.axis
    u0 = float(shift @ e)
    perp = shift - u0 * e
    if frac1 <= 0.0 or frac0 >= 1.0:  # split 0 (solid): no proximal part; split 1: no distal
        return 0.0, np.zeros(3), np.zeros((3, 3))
    lo = u0 if frac0 <= 0.0 else min(max(u0, frac0 * length), u0 + length)
    hi = u0 + length if frac1 >= 1.0 else max(min(u0 + length, frac1 * length), u0)
    if hi <= lo:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    m = cyl.mass * (hi - lo) / length
    com = 0.5 * (lo + hi) * e + perp - origin
    return m, com, cylinder_inertia(m, cyl.radius, hi - lo, e)


def radius_inertia_target(desc: ModelDescription, size: BodySize) -> float:
    """The radius's moment of inertia (kg m^2) about MoBL's pro/sup axis, through its joint."""
    a = desc.anatomical
    r = _scaled(a.radius, size.forearm, size.mass)
    u = a.radioulnar_axis
    c = r.com  # the radius frame sits on the joint origin
    return float(u @ r.inertia @ u + r.mass * (c @ c - (c @ u) ** 2))


def radius_inertia_split(desc: ModelDescription, size: BodySize, offset_proximal, offset_distal,
                         cylinder: str = "uniform") -> float:
    """The paper's split rule: distal part's inertia about the pro/sup axis = the radius's.

    The distal part's inertia about the axis falls monotonically as the cut moves distally,
    so bisection finds the cut; 0 or 1 when even the whole cylinder cannot match (clamped).
    """
    cyl = forearm_cylinder(desc, size)
    prox = np.asarray(offset_proximal, float) * size.forearm
    dist = np.asarray(offset_distal, float) * size.forearm
    p0, axis = _axis_points(cyl, prox, dist)
    shift = _mass_shift(cyl, cylinder)
    target = radius_inertia_target(desc, size)

    def about_axis(s: float) -> float:
        m, com, inertia = _cylinder_part(cyl, shift, s, 1.0, p0)
        d = com - (com @ axis) * axis
        return float(axis @ inertia @ axis + m * d @ d)

    lo, hi = 0.0, 1.0
    if about_axis(lo) <= target:
        return 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if about_axis(mid) > target else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class ForearmPlacement:
    """What a simplified model was built with: publishable (e.g. in a node's config message).

    name: "paper" | "parallel" | "oblique" (config/model.yaml), "solid", or "custom" when
    overrides changed a named placement. Offsets are (anterior, lateral), m, at this body
    size (the config's 50th-percentile offsets scaled with forearm length).
    """

    name: str
    split: float
    axis_offset_proximal: tuple[float, float]
    axis_offset_distal: tuple[float, float]
    cylinder: str = "uniform"
    split_rule: str = "fixed"  # "fixed" or "radius_inertia"

    def as_dict(self) -> dict:
        return {"name": self.name, "split": self.split, "split_rule": self.split_rule,
                "axis_offset_proximal": list(self.axis_offset_proximal),
                "axis_offset_distal": list(self.axis_offset_distal), "cylinder": self.cylinder}


def resolve_placement(kind: str, desc: ModelDescription, size: BodySize, placement=None,
                      split=None, axis_offset_proximal=None, axis_offset_distal=None,
                      cylinder=None) -> ForearmPlacement | None:
    """The placement a simplified model is built with; None for the anatomical model."""
    given = {"split": split, "axis_offset_proximal": axis_offset_proximal,
             "axis_offset_distal": axis_offset_distal}
    if kind == "anatomical":
        if any(v is not None for v in given.values()) or placement is not None or cylinder:
            raise ValueError("placement, split, axis offsets and cylinder apply to the solid and "
                             "segmented models only")
        return None
    cylinder = "uniform" if cylinder is None else cylinder
    _mass_shift(forearm_cylinder(desc, size), cylinder)  # validates the name
    rule = False
    if kind == "solid":
        if placement is not None:
            raise ValueError("the solid model has no placement (its pro/sup joint is at the elbow); "
                             "placement applies to the segmented model")
        if split not in (None, 0, 0.0):
            raise ValueError("the solid model has no split (it is the segmented model at split=0)")
        zero = np.zeros(2)
        sp, prox, dist = _validate_simplified(
            0.0, zero if axis_offset_proximal is None else axis_offset_proximal,
            zero if axis_offset_distal is None else axis_offset_distal)
        name = "solid"
    else:
        name = desc.simplified.default_placement if placement is None else placement
        if name not in desc.simplified.placements:
            raise ValueError(f"placement must be one of {tuple(desc.simplified.placements)}, "
                             f"got {placement!r}")
        spec = desc.simplified.placements[name]
        prox_in = spec.axis_offset_proximal if axis_offset_proximal is None else axis_offset_proximal
        dist_in = spec.axis_offset_distal if axis_offset_distal is None else axis_offset_distal
        split_in = spec.split if split is None else split
        if any(v is not None for v in given.values()):
            name = "custom"
        rule = isinstance(split_in, str) and split_in == RADIUS_INERTIA
        _, prox, dist = _validate_simplified(0.0 if rule else split_in, prox_in, dist_in)
        sp = radius_inertia_split(desc, size, prox, dist, cylinder) if rule else split_in
        sp, _, _ = _validate_simplified(sp, prox, dist)
    k = size.forearm
    return ForearmPlacement(name, float(sp), (float(prox[0] * k), float(prox[1] * k)),
                            (float(dist[0] * k), float(dist[1] * k)), cylinder,
                            "radius_inertia" if rule else "fixed")


def simplified_forearm(
    desc: ModelDescription, size: BodySize, placement: ForearmPlacement
) -> tuple[list[Link], list[Joint], str, np.ndarray]:
    """Elbow + pro/sup over a (possibly split) cylinder. split = 0 is the solid model.

    The pro/sup axis runs from the elbow end to the wrist end of the cylinder, each end moved
    by its (anterior, lateral) offset in the end's cross-section; it points proximally so
    positive = pronation.
    """
    cyl = forearm_cylinder(desc, size)
    a = desc.anatomical
    rng = desc.ranges
    prox = np.asarray(placement.axis_offset_proximal)
    dist = np.asarray(placement.axis_offset_distal)
    p0, axis = _axis_points(cyl, prox, dist)
    split = placement.split
    split_point = split * cyl.wrist
    # Pro/sup joint origin: the point of the axis nearest the split point.
    joint_origin = p0 + ((split_point - p0) @ axis) * axis
    shift = _mass_shift(cyl, placement.cylinder)
    links = [Link("forearm_proximal", *_cylinder_part(cyl, shift, 0.0, split, np.zeros(3)), "cylinder"),
             Link("forearm_distal", *_cylinder_part(cyl, shift, split, 1.0, joint_origin), "cylinder")]
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
    placement: str | None = None,
    cylinder: str | None = None,
    *,
    side: str = "right",
    payload: Payload | None = None,
) -> KinematicTree:
    """The full 20-DOF tree of one model kind at one body size, either arm, with a payload.

    placement (segmented only): "paper" | "parallel" | "oblique" (config/model.yaml);
    None = the config's default_placement. split/axis offsets override the named placement.
    cylinder (solid, segmented): "uniform" (the paper's) or "mass_matched".
    The right arm is built, the payload welded to its carpus, and for side="left" the whole
    tree is mirrored (tree.mirror_tree), so every engine reading the tree gets both.
    """
    side = check_side(side)
    if kind not in MODEL_KINDS:
        raise ValueError(f"unknown model kind {kind!r}; expected one of {MODEL_KINDS}")
    pl = resolve_placement(kind, desc, size, placement, split, axis_offset_proximal,
                           axis_offset_distal, cylinder)
    if pl is None:
        links, joints, parent, wrist = anatomical_forearm(desc, size)
    else:
        links, joints, parent, wrist = simplified_forearm(desc, size, pl)
    h_links, h_joints = hand_subtree(desc, size, parent, wrist)
    hum = desc.anatomical.humerus
    root = Link("humerus", hum.mass * size.mass, hum.com, hum.inertia * size.mass, "bone")
    links = [links[0], links[1], *h_links]
    tree = KinematicTree(kind, size, desc.gravity.copy(), root, tuple(links), tuple(joints + h_joints))
    return personalise(tree, side, payload)


__all__ = ["CYLINDERS", "MODEL_KINDS", "PLACEMENTS", "ForearmPlacement", "build_tree",
           "forearm_cylinder", "massless", "radius_inertia_split", "resolve_placement"]
