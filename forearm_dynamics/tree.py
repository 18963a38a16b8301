"""An engine-neutral kinematic tree: what Pinocchio, URDF and OpenSim builders all read."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .anthropometry import BodySize
from .payload import Payload

SIDES = ("right", "left")
#: Reflection in the sagittal plane (z -> -z): the right arm's frames to the left arm's.
MIRROR = np.diag([1.0, 1.0, -1.0])

#: Link.shape values: which uniform solid the inertia was computed from. A viewer draws
#: it from the inertia alone (urdf.geometry), so a transformed (e.g. mirrored) link keeps
#: a drawing that matches its inertia.
SHAPES = ("cylinder", "prism", "bone")


@dataclass(frozen=True)
class Link:
    """A rigid body; frame parallel to the world at q = 0. Massless links have mass 0.

    shape: "cylinder" (forearm pieces, thumb metacarpal, phalanges), "prism" (the palm),
    "bone" (an anatomical body: no simple solid, drawn as its inertia-equivalent box),
    "object" (something held in the hand: drawn as a sphere), or
    "" (unknown: drawn like "bone").
    """

    name: str
    mass: float
    com: np.ndarray  # (3,) in the link frame
    inertia: np.ndarray  # (3, 3) about the COM, link frame
    shape: str = ""


@dataclass(frozen=True)
class Joint:
    """A revolute joint; the child frame sits at `origin` in the parent frame at q = 0."""

    name: str
    parent: str
    child: str
    origin: np.ndarray  # (3,)
    axis: np.ndarray  # (3,) unit, in the parent (= child) frame
    lower: float
    upper: float


@dataclass(frozen=True)
class FixedJoint:
    """A weld (no coordinate): the child frame sits at `origin` in the parent frame, parallel."""

    name: str
    parent: str
    child: str
    origin: np.ndarray  # (3,)


@dataclass(frozen=True)
class KinematicTree:
    kind: str
    body_size: BodySize
    gravity: np.ndarray
    root: Link  # fixed in the world (the humerus)
    links: tuple[Link, ...]  # every moving link, each the child of exactly one joint
    joints: tuple[Joint, ...]  # parents before children; joint i drives velocity index i
    # Bodies welded to a link (the object in the hand): they add mass, never a coordinate.
    fixed_joints: tuple[FixedJoint, ...] = ()
    fixed_links: tuple[Link, ...] = ()
    side: str = "right"
    payload: Payload | None = None  # as given, in the hand frame (see payload.py)

    def link(self, name: str) -> Link:
        if name == self.root.name:
            return self.root
        for link in (*self.links, *self.fixed_links):
            if link.name == name:
                return link
        raise KeyError(name)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)


def massless(name: str) -> Link:
    return Link(name, 0.0, np.zeros(3), np.zeros((3, 3)))


def cylinder_inertia(mass: float, radius: float, length: float, axis: np.ndarray) -> np.ndarray:
    """Solid uniform cylinder about its COM, long axis along the unit vector `axis`."""
    e = np.outer(axis, axis)
    transverse = mass * (3.0 * radius**2 + length**2) / 12.0
    return transverse * (np.eye(3) - e) + 0.5 * mass * radius**2 * e


def prism_inertia(mass: float, dx: float, dy: float, dz: float) -> np.ndarray:
    """Solid uniform rectangular prism with edges along x, y, z, about its COM."""
    return (mass / 12.0) * np.diag([dy**2 + dz**2, dx**2 + dz**2, dx**2 + dy**2])


def combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Composite (mass, com, inertia about com) of parts given in one frame."""
    mass = sum(m for m, _, _ in parts)
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, i in parts:
        d = c - com
        inertia += i + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


def weld(tree: KinematicTree, name: str, parent: str, origin: np.ndarray, link: Link) -> KinematicTree:
    """The tree with `link` (named `name`) welded to `parent` at `origin` (parent frame)."""
    tree.link(parent)  # KeyError for an unknown parent
    return replace(tree, fixed_joints=(*tree.fixed_joints, FixedJoint(name, parent, link.name,
                                                                      np.asarray(origin, float))),
                   fixed_links=(*tree.fixed_links, link))


def mirror_link(link: Link) -> Link:
    """Reflect a body: COM S c, inertia S I S (mass unchanged; S = diag(1, 1, -1))."""
    return replace(link, com=MIRROR @ link.com, inertia=MIRROR @ link.inertia @ MIRROR)


def mirror_tree(tree: KinematicTree) -> KinematicTree:
    """The other arm: the mirror image of `tree` in the sagittal (x-y) plane.

    Points and bodies reflect with S = diag(1, 1, -1): origins S o, COMs S c, inertias S I S.
    A rotation axis is a pseudo-vector: S R(a, q) S = R(-S a, q) (conjugating by a
    reflection keeps the fixed line S a but reverses the sense of turning), so a joint axis
    becomes -S a and the same angle q gives the mirrored posture. Every frame stays parallel
    to the world at q = 0 (rotation I, det +1): the mirror lives in the numbers, never in a
    left-handed frame. Gravity is the world's and is left as it is; it lies in the mirror
    plane (-y), so mirrored motions need the same joint torques (docs/models.md, "The left arm").
    """
    if tree.side not in SIDES:
        raise ValueError(f"side must be one of {SIDES}, got {tree.side!r}")
    joints = tuple(replace(j, origin=MIRROR @ j.origin, axis=-(MIRROR @ j.axis)) for j in tree.joints)
    fixed = tuple(replace(f, origin=MIRROR @ f.origin) for f in tree.fixed_joints)
    return replace(
        tree,
        root=mirror_link(tree.root),
        links=tuple(mirror_link(link) for link in tree.links),
        joints=joints,
        fixed_joints=fixed,
        fixed_links=tuple(mirror_link(link) for link in tree.fixed_links),
        side=SIDES[1 - SIDES.index(tree.side)],
    )
