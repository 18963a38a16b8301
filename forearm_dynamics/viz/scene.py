"""The arm as a set of solids posed by forward kinematics: one per massive link.

Each solid is the link's URDF <visual> (urdf.geometry: the uniform solid of the link's own
inertia), so what a viewer draws from our markers is what it draws from the exported URDF,
and its pose is the link frame (forward kinematics of the built Pinocchio model) times the
visual origin. Poses are in the URDF root link's frame (the humerus, fixed in the world), so
no TF tree is needed: the PyPI ROS wheels have neither tf2 nor robot_state_publisher.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..dynamics import ArmModel
from ..tree import KinematicTree
from ..urdf import MATERIALS, Geometry, geometry


@dataclass(frozen=True)
class LinkShape:
    """A massive link's visual solid and the joint whose torque colours it.

    joint: the revolute joint that moves the link (for a welded body, the one that moves the
    body it is welded to); None for the root link, which no joint moves.
    """

    link: str
    joint: str | None
    joint_index: int | None  # index in joint_names (= velocity index)
    geometry: Geometry
    rgba: tuple[float, float, float, float]  # the URDF material's colour


@dataclass(frozen=True)
class PosedShape:
    shape: LinkShape
    position: np.ndarray  # (3,) solid centre, root frame, m
    rotation: np.ndarray  # (3, 3) solid axes (columns) in the root frame

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """geometry_msgs/Quaternion order (x, y, z, w), w >= 0."""
        x, y, z, w = pin.Quaternion(self.rotation).coeffs()
        q = np.array([x, y, z, w])
        return -q if w < 0 else q


def _moving_joint(tree: KinematicTree) -> dict[str, str | None]:
    """link name -> the revolute joint that moves it (welds resolved to their parent's)."""
    out: dict[str, str | None] = {tree.root.name: None}
    out.update({j.child: j.name for j in tree.joints})
    for w in tree.fixed_joints:  # welds are listed after their parent exists
        out[w.child] = out[w.parent]
    return out


def link_shapes(tree: KinematicTree) -> tuple[LinkShape, ...]:
    """Every massive link's solid, root first, then in the tree's (URDF's) link order."""
    moving = _moving_joint(tree)
    index = {n: i for i, n in enumerate(tree.joint_names)}
    shapes = []
    for link in (tree.root, *tree.links, *tree.fixed_links):
        g = geometry(link)
        if g is None:
            continue
        joint = moving[link.name]
        shapes.append(LinkShape(link.name, joint, None if joint is None else index[joint], g,
                                MATERIALS.get(link.shape, MATERIALS[""])[1]))
    return tuple(shapes)


class ArmScene:
    """Forward kinematics of one built model, with its own Pinocchio data (never the
    ArmModel's, which the torque computation may be using)."""

    def __init__(self, arm: ArmModel):
        self.arm = arm
        self.tree = arm.tree
        self.root_frame: str = arm.tree.root.name
        self.joint_names = arm.joint_names
        self.shapes = link_shapes(arm.tree)
        self._model = arm.model
        self._data = arm.model.createData()
        # The root link is the world of the Pinocchio model (no frame): its pose is identity.
        self._frames = [None if s.link == self.root_frame else arm.model.getFrameId(s.link)
                        for s in self.shapes]
        # One operational frame per moving solid at its centre, axes = the solid's, on a
        # private copy of the model: Pinocchio then places every solid in one C++ call and
        # SE3ToXYZQUAT gives its marker pose directly (~10x cheaper than numpy per frame).
        self._vmodel = pin.Model(arm.model)
        self._solid_frames, self._fixed = [], {}
        for k, (s, fid) in enumerate(zip(self.shapes, self._frames)):
            g = pin.SE3(np.asarray(s.geometry.rotation, float), np.asarray(s.geometry.origin, float))
            if fid is None:
                self._fixed[k] = pin.SE3ToXYZQUAT(g)
                continue
            f = self._vmodel.frames[fid]
            joint = getattr(f, "parentJoint", None)
            joint = f.parent if joint is None else joint
            self._solid_frames.append((k, self._vmodel.addFrame(pin.Frame(
                f"{s.link}_visual", joint, fid, f.placement * g, pin.FrameType.OP_FRAME))))
        self._vdata = self._vmodel.createData()  # after the frames were added
        self._origins = np.array([s.geometry.origin for s in self.shapes], float)
        self._rotations = np.array([s.geometry.rotation for s in self.shapes], float)
        if arm.model.nframes in self._frames:
            raise ValueError("a link of the tree has no frame in the model")
        self._joint_ids = [arm.model.getJointId(n) for n in arm.joint_names]
        self._axes = np.array([j.axis for j in arm.tree.joints], float)

    def _checked(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape != (len(self.joint_names),) or not np.isfinite(q).all():
            raise ValueError(f"positions must be {len(self.joint_names)} finite numbers in "
                             f"joint_names order, got shape {q.shape}")
        return q

    def _fk(self, q) -> None:
        q = self._checked(q)
        pin.forwardKinematics(self._model, self._data, q)
        pin.updateFramePlacements(self._model, self._data)

    def poses7(self, q) -> np.ndarray:
        """(n, 7): every solid's centre (x, y, z) and orientation quaternion (x, y, z, w), w >= 0,
        in the root frame at q (self.shapes order)."""
        q = self._checked(q)
        pin.framesForwardKinematics(self._vmodel, self._vdata, q)
        out = np.empty((len(self.shapes), 7))
        frames = self._vdata.oMf
        for k, fid in self._solid_frames:
            out[k] = pin.SE3ToXYZQUAT(frames[fid])
        for k, pose in self._fixed.items():
            out[k] = pose
        neg = out[:, 6] < 0
        out[neg, 3:] *= -1.0
        return out

    def poses(self, q) -> tuple[np.ndarray, np.ndarray]:
        """(centres (n, 3), axes (n, 3, 3)) of the solids (self.shapes order) in the root frame."""
        self._fk(q)
        frames = self._data.oMf
        rot = np.array([np.eye(3) if f is None else frames[f].rotation for f in self._frames])
        pos = np.array([np.zeros(3) if f is None else frames[f].translation for f in self._frames])
        return pos + np.einsum("nij,nj->ni", rot, self._origins), rot @ self._rotations

    def posed(self, q) -> list[PosedShape]:
        """Every solid's centre and axes in the root frame at joint positions q (rad)."""
        self._fk(q)
        out = []
        for shape, fid in zip(self.shapes, self._frames):
            g = shape.geometry
            if fid is None:
                out.append(PosedShape(shape, np.array(g.origin, float), np.array(g.rotation)))
                continue
            m = self._data.oMf[fid]
            r = m.rotation
            out.append(PosedShape(shape, m.translation + r @ g.origin, r @ g.rotation))
        return out

    def joint_axes(self, q=None) -> tuple[np.ndarray, np.ndarray]:
        """(origins (n, 3), unit axes (n, 3)) of the joints in the root frame at q (None: the
        posture of the last poses/posed call); a positive torque turns the child about +axis
        (right-hand rule)."""
        if q is not None:
            self._fk(q)
        origins = np.array([self._data.oMi[j].translation for j in self._joint_ids])
        axes = np.array([self._data.oMi[j].rotation @ a for j, a in zip(self._joint_ids, self._axes)])
        return origins, axes
