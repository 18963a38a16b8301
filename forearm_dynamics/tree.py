"""An engine-neutral kinematic tree: what Pinocchio, URDF and OpenSim builders all read."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .anthropometry import BodySize

#: Link.shape values: which uniform solid the inertia was computed from. A viewer draws
#: it from the inertia alone (urdf.geometry), so a transformed (e.g. mirrored) link keeps
#: a drawing that matches its inertia.
SHAPES = ("cylinder", "prism", "bone")


@dataclass(frozen=True)
class Link:
    """A rigid body; frame parallel to the world at q = 0. Massless links have mass 0.

    shape: "cylinder" (forearm pieces, thumb metacarpal, phalanges), "prism" (the palm),
    "bone" (an anatomical body: no simple solid, drawn as its inertia-equivalent box), or
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
class KinematicTree:
    kind: str
    body_size: BodySize
    gravity: np.ndarray
    root: Link  # fixed in the world (the humerus)
    links: tuple[Link, ...]  # every moving link, each the child of exactly one joint
    joints: tuple[Joint, ...]  # parents before children; joint i drives velocity index i

    def link(self, name: str) -> Link:
        if name == self.root.name:
            return self.root
        for link in self.links:
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
