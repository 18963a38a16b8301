"""A KinematicTree as URDF: exactly the model's inertias, axes and limits, and something to see.

Every link with mass gets a <visual> and a <collision> drawn from its own inertia: the
uniform solid of that shape whose mass, COM and inertia tensor are the link's. A cylinder's
radius and length come from its axial and transverse moments (m r²/2, m(3r² + L²)/12), a
box's edges from its principal moments (m(b² + c²)/12 ...), placed at the COM along the
principal axes. So the picture cannot disagree with the dynamics, and a transformed tree
(scaled, mirrored) is drawn right without a second table of shapes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .description import SIGN_CONVENTIONS
from .tree import KinematicTree, Link

#: RGBA of each Link.shape: skin for the simplified segments, bone for anatomical bodies.
MATERIALS = {
    "cylinder": ("skin", (0.87, 0.69, 0.56, 1.0)),
    "prism": ("palm", (0.80, 0.60, 0.48, 1.0)),
    "bone": ("bone", (0.90, 0.87, 0.78, 1.0)),
    "": ("bone", (0.90, 0.87, 0.78, 1.0)),
    "object": ("object", (0.20, 0.45, 0.80, 1.0)),
}

#: Radius (m) drawn for a point-mass object in the hand: the default grasp's 60 mm object.
POINT_OBJECT_RADIUS = 0.03


@dataclass(frozen=True)
class Geometry:
    """A URDF primitive in the link frame: centred at `origin`, rotated by `rotation`.

    cylinder: size = (radius, length), its axis is the rotated z; box: size = (x, y, z) edges;
    sphere: size = (radius,).
    """

    kind: str  # "cylinder" | "box" | "sphere"
    size: tuple[float, ...]
    origin: np.ndarray  # (3,)
    rotation: np.ndarray  # (3, 3) proper rotation, columns = the primitive's x, y, z axes

    @property
    def rpy(self) -> np.ndarray:
        """URDF roll-pitch-yaw (fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll))."""
        return Rotation.from_matrix(self.rotation).as_euler("xyz")

    @property
    def axis(self) -> np.ndarray:
        """The cylinder's long axis (the rotated z), in the link frame."""
        return self.rotation[:, 2]


def _proper(r: np.ndarray) -> np.ndarray:
    return r if np.linalg.det(r) > 0 else r * np.array([1.0, 1.0, -1.0])


def _near_identity(vectors: np.ndarray) -> np.ndarray:
    """Principal axes (columns) reordered and signed to be as close to x, y, z as they can:
    an axis-aligned inertia gives an unrotated box (an eigen solver's order is arbitrary)."""
    order, free = [0, 0, 0], [0, 1, 2]
    for world in np.argsort(-np.abs(vectors).max(axis=1)):  # most decided world axes first
        k = max(free, key=lambda c: abs(vectors[world, c]))
        order[world] = k
        free.remove(k)
    r = vectors[:, order]
    r = r * np.where(np.diag(r) < 0, -1.0, 1.0)
    return _proper(r)


def geometry(link: Link) -> Geometry | None:
    """The link's solid, from its mass and inertia alone; None for a massless link."""
    if link.mass <= 0.0:
        return None
    moments, vectors = np.linalg.eigh(0.5 * (link.inertia + link.inertia.T))
    moments = np.clip(moments, 0.0, None)
    com = np.asarray(link.com, float)
    if link.shape == "object":
        # an object in the hand: the sphere of its mean moment (I = 2/5 m r²); a point mass
        # (no inertia) is drawn at the default grasp object's size
        mean = float(moments.mean())
        r = float(np.sqrt(2.5 * mean / link.mass)) if mean > 0.0 else POINT_OBJECT_RADIUS
        return Geometry("sphere", (r,), com, np.eye(3))
    if link.shape == "cylinder":
        # the axial moment is the one standing apart from the two equal transverse ones
        k = int(np.argmax([abs(moments[i] - moments[[j for j in range(3) if j != i]].mean())
                           for i in range(3)]))
        transverse = float(np.delete(moments, k).mean())
        r2 = 2.0 * moments[k] / link.mass
        length2 = max(12.0 * transverse / link.mass - 3.0 * r2, 0.0)
        z = vectors[:, k] / np.linalg.norm(vectors[:, k])
        # x: the world x (else y) made perpendicular to the axis, so roll-pitch-yaw stays
        # away from pitch = ±90° (a gimbal lock) for the segments of this tree
        e = np.array([1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        x = e - (e @ z) * z
        x /= np.linalg.norm(x)
        return Geometry("cylinder", (float(np.sqrt(r2)), float(np.sqrt(length2))), com,
                        np.column_stack([x, np.cross(z, x), z]))
    # A uniform box with these principal moments: edge_i² = 6 (I_j + I_k - I_i) / m.
    edges = np.sqrt(np.clip(6.0 * (moments.sum() - 2.0 * moments) / link.mass, 0.0, None))
    r = _near_identity(vectors)
    size = tuple(float(edges[np.argmax(np.abs(vectors.T @ r[:, c]))]) for c in range(3))
    return Geometry("box", size, com, r)


def _v(x) -> str:
    return " ".join(repr(float(c)) for c in np.asarray(x).reshape(-1))


def _shape_xml(g: Geometry) -> str:
    if g.kind == "cylinder":
        return f'<cylinder radius="{g.size[0]!r}" length="{g.size[1]!r}"/>'
    if g.kind == "sphere":
        return f'<sphere radius="{g.size[0]!r}"/>'
    return f'<box size="{_v(g.size)}"/>'


def _link(link: Link) -> str:
    g = geometry(link)
    if g is None:
        return f'  <link name="{link.name}"/>'
    i = np.asarray(link.inertia, dtype=float).tolist()  # plain floats: repr round-trips
    origin = f'<origin xyz="{_v(g.origin)}" rpy="{_v(g.rpy)}"/>'
    material = MATERIALS.get(link.shape, MATERIALS[""])[0]
    return (
        f'  <link name="{link.name}">\n    <inertial>\n'
        f'      <origin xyz="{_v(link.com)}" rpy="0 0 0"/>\n'
        f'      <mass value="{float(link.mass)!r}"/>\n'
        f'      <inertia ixx="{i[0][0]!r}" ixy="{i[0][1]!r}" ixz="{i[0][2]!r}" '
        f'iyy="{i[1][1]!r}" iyz="{i[1][2]!r}" izz="{i[2][2]!r}"/>\n'
        "    </inertial>\n"
        f"    <visual>\n      {origin}\n      <geometry>{_shape_xml(g)}</geometry>\n"
        f'      <material name="{material}"/>\n    </visual>\n'
        f"    <collision>\n      {origin}\n      <geometry>{_shape_xml(g)}</geometry>\n"
        "    </collision>\n  </link>"
    )


def _materials() -> list[str]:
    seen = {}
    for name, rgba in MATERIALS.values():
        seen.setdefault(name, rgba)
    return [f'  <material name="{n}"><color rgba="{_v(c)}"/></material>' for n, c in seen.items()]


def tree_to_urdf(tree: KinematicTree) -> str:
    """Frames are parallel to the world at q = 0, so every joint origin has rpy = 0."""
    parts = [
        '<?xml version="1.0"?>',
        (
            f"<!-- forearm_dynamics {tree.kind} model, {tree.side} arm, body size "
            f"{tree.body_size.label}. Frames: x anterior, y superior, z "
            f"{'lateral' if tree.side == 'right' else 'medial (the mirror image of the right arm)'}"
            f"; gravity {_v(tree.gravity)} m/s^2. Visual and collision shapes: the uniform "
            "solid of each link's own inertia. -->"
        ),
        f'<robot name="forearm_{tree.kind}">',
        *_materials(),
        _link(tree.root),
    ]
    parts += [_link(link) for link in (*tree.links, *tree.fixed_links)]
    for j in tree.joints:
        parts.append(
            f"  <!-- {j.name}: {SIGN_CONVENTIONS[j.name]} -->\n"
            f'  <joint name="{j.name}" type="revolute">\n'
            f'    <parent link="{j.parent}"/>\n    <child link="{j.child}"/>\n'
            f'    <origin xyz="{_v(j.origin)}" rpy="0 0 0"/>\n'
            f'    <axis xyz="{_v(j.axis)}"/>\n'
            f'    <limit lower="{float(j.lower)!r}" upper="{float(j.upper)!r}"'
            ' effort="1000" velocity="100"/>\n'
            "  </joint>"
        )
    for w in tree.fixed_joints:
        parts.append(
            f"  <!-- {w.name}: {w.child} welded to {w.parent} (no coordinate) -->\n"
            f'  <joint name="{w.name}" type="fixed">\n'
            f'    <parent link="{w.parent}"/>\n    <child link="{w.child}"/>\n'
            f'    <origin xyz="{_v(w.origin)}" rpy="0 0 0"/>\n'
            "  </joint>"
        )
    parts.append("</robot>\n")
    return "\n".join(parts)
