"""A KinematicTree as URDF: exactly the model's inertias, axes and limits."""

from __future__ import annotations

import numpy as np

from .description import SIGN_CONVENTIONS
from .tree import KinematicTree, Link


def _v(x) -> str:
    return " ".join(repr(float(c)) for c in np.asarray(x).reshape(-1))


def _link(link: Link) -> str:
    if link.mass <= 0.0:
        return f'  <link name="{link.name}"/>'
    i = np.asarray(link.inertia, dtype=float).tolist()  # plain floats: repr round-trips
    return (
        f'  <link name="{link.name}">\n    <inertial>\n'
        f'      <origin xyz="{_v(link.com)}" rpy="0 0 0"/>\n'
        f'      <mass value="{float(link.mass)!r}"/>\n'
        f'      <inertia ixx="{i[0][0]!r}" ixy="{i[0][1]!r}" ixz="{i[0][2]!r}" '
        f'iyy="{i[1][1]!r}" iyz="{i[1][2]!r}" izz="{i[2][2]!r}"/>\n'
        "    </inertial>\n  </link>"
    )


def tree_to_urdf(tree: KinematicTree) -> str:
    """Frames are parallel to the world at q = 0, so every joint origin has rpy = 0."""
    parts = [
        '<?xml version="1.0"?>',
        (
            f"<!-- forearm_dynamics {tree.kind} model, {tree.side} arm, body size "
            f"{tree.body_size.label}. Frames: x anterior, y superior, z "
            f"{'lateral' if tree.side == 'right' else 'medial (the mirror image of the right arm)'}"
            f"; gravity {_v(tree.gravity)} m/s^2. -->"
        ),
        f'<robot name="forearm_{tree.kind}">',
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
