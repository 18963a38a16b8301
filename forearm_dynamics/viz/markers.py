"""The arm's markers as plain arrays: what a visualization_msgs/MarkerArray holds, without ROS.

`arm_markers(scene, colours, q, tau)` gives one marker per massive link (ns = the link's
name, id 0) and, optionally, one torque arrow per joint (ns = "torque/<joint>", id 0): from
the joint centre along its axis, length |torque| x arrow_scale, pointing along +axis for a
positive torque (right-hand rule: the sense the torque turns the child). The arrays are
turned into messages by nodes/arm_markers.py (rclpy classes) or viz/marker_cdr.py (CDR
bytes, for bag_viz); keeping the numbers here lets them be tested without ROS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .colors import TorqueColours, viridis
from .scene import ArmScene

#: visualization_msgs/Marker type constants (the same numbers as the message's).
ARROW, CUBE, SPHERE, CYLINDER, TEXT = 0, 1, 2, 3, 9  # TEXT: TEXT_VIEW_FACING
KINDS = {"box": CUBE, "sphere": SPHERE, "cylinder": CYLINDER}
ARROW_NS = "torque/"
#: Arrow shaft and head diameter, head length (m).
ARROW_SCALE = (0.004, 0.008, 0.008)
#: Shortest arrow drawn (m): a zero-length arrow is invalid in RViz.
MIN_ARROW = 1e-3
#: The strongest muscle's label (muscle_forces): ns, text height (m), offset from the
#: forearm's last link along the root frame's z (lateral, m), colour (white).
MUSCLE_NS = "muscle/strongest"
MUSCLE_TEXT_HEIGHT = 0.02
MUSCLE_TEXT_OFFSET = (0.0, 0.0, 0.06)
MUSCLE_TEXT_RGBA = (1.0, 1.0, 1.0, 1.0)
#: the label's lifetime (s, ns): a viewer removes it when it is not redrawn (muscle_forces
#: stopped or fell behind), as it would keep a marker that is simply no longer sent
MUSCLE_TEXT_LIFETIME = (0, 500_000_000)
#: The joints whose links are the forearm (segmented: forearm_proximal, forearm_distal;
#: anatomical: ulna, radius; solid: forearm_distal).
FOREARM_JOINTS = ("elbow_flexion", "pro_sup")


@dataclass(frozen=True)
class MarkerFrame:
    """The markers of one instant. Shapes: n solids; arrows (if any): one per joint."""

    ns: tuple[str, ...]  # n
    types: np.ndarray  # (n,) Marker type
    positions: np.ndarray  # (n, 3) m, root frame
    orientations: np.ndarray  # (n, 4) x, y, z, w
    scales: np.ndarray  # (n, 3) Marker.scale (m)
    rgba: np.ndarray  # (n, 4)
    arrow_ns: tuple[str, ...] = ()
    arrows: np.ndarray | None = None  # (m, 2, 3): start, end (root frame)
    arrow_rgba: np.ndarray | None = None  # (m, 4)
    text: str | None = None  # the strongest muscle's label (ns MUSCLE_NS), if drawn
    text_position: np.ndarray | None = None  # (3,) root frame


def quaternions(r: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions x, y, z, w (w >= 0) of proper rotation matrices (n, 3, 3)
    (Pinocchio's Eigen conversion, one call per matrix: cheaper than numpy for ~20)."""
    q = np.array([pin.Quaternion(m).coeffs() for m in r])  # x, y, z, w
    q[q[:, 3] < 0] *= -1.0
    return q


def _scale(kind: str, size: tuple[float, ...]) -> np.ndarray:
    if kind == "cylinder":
        return np.array([2.0 * size[0], 2.0 * size[0], size[1]])
    if kind == "sphere":
        return np.full(3, 2.0 * size[0])
    return np.array(size, float)


class MarkerMaker:
    """The constant part of one model's markers (names, types, sizes, root colour), made once
    per model; `frame(q, tau)` adds what moves."""

    def __init__(self, scene: ArmScene, colours: TorqueColours, *, arrows: bool = False,
                 arrow_scale: float = 0.05, alpha: float = 1.0):
        self.scene, self.colours = scene, colours
        self.arrows, self.arrow_scale, self.alpha = arrows, float(arrow_scale), float(alpha)
        shapes = scene.shapes
        self.ns = tuple(s.link for s in shapes)
        self.types = np.array([KINDS[s.geometry.kind] for s in shapes], np.int32)
        self.scales = np.array([_scale(s.geometry.kind, s.geometry.size) for s in shapes])
        self._joint = np.array([-1 if s.joint_index is None else s.joint_index for s in shapes])
        self._fixed_rgb = np.array([s.rgba[:3] for s in shapes], float)
        self.arrow_ns = tuple(ARROW_NS + n for n in scene.joint_names) if arrows else ()
        self._n = len(scene.joint_names)
        forearm = [scene.joint_names.index(j) for j in FOREARM_JOINTS if j in scene.joint_names]
        self._forearm = np.isin(self._joint, forearm)  # the links muscle colour replaces
        self._forearm_last = int(np.nonzero(self._forearm)[0][-1]) if self._forearm.any() else -1

    def frame(self, q, tau, muscle: tuple[str, float] | None = None) -> MarkerFrame:
        """The markers at posture q (rad) with torques tau (N·m), both in joint_names order.
        muscle: (name, activation 0..1) of the forearm's strongest muscle (muscle_forces), or
        None: the forearm links are then coloured by viridis(activation) instead of their
        joints' torques, and a label "<name> <activation>" is drawn beside the forearm."""
        tau = np.asarray(tau, float).reshape(-1)
        if tau.shape != (self._n,) or not np.isfinite(tau).all():
            raise ValueError(f"torques must be {self._n} finite numbers in joint_names order, "
                             f"got shape {tau.shape}")
        pose = self.scene.poses7(q)
        pos, quat = pose[:, :3], pose[:, 3:]
        joint_rgb = self.colours.rgb(tau)
        rgb = np.where((self._joint < 0)[:, None], self._fixed_rgb, joint_rgb[self._joint])
        text = text_at = None
        if muscle is not None and self._forearm_last >= 0:
            name, a = muscle
            rgb[self._forearm] = viridis(a)
            text = f"{name} {a:.2f}"
            text_at = pos[self._forearm_last] + np.array(MUSCLE_TEXT_OFFSET)
        rgba = np.column_stack([rgb, np.full(len(rgb), self.alpha)])
        if not self.arrows:
            return MarkerFrame(self.ns, self.types, pos, quat, self.scales, rgba,
                               text=text, text_position=text_at)
        origins, axes = self.scene.joint_axes(q)
        length = np.maximum(np.abs(tau) * self.arrow_scale, MIN_ARROW) * np.where(tau < 0, -1.0, 1.0)
        ends = origins + length[:, None] * axes
        return MarkerFrame(self.ns, self.types, pos, quat, self.scales, rgba, self.arrow_ns,
                           np.stack([origins, ends], axis=1),
                           np.column_stack([joint_rgb, np.ones(self._n)]), text, text_at)
