"""Inverse dynamics of one model with Pinocchio: per sample and in batches."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pinocchio as pin

from .anthropometry import BodySize, resolve_body_size
from .builders import ForearmPlacement, build_tree, resolve_placement
from .description import load_description
from .hand import grasp_point
from .payload import Payload, make_payload
from .ranges import AngleRanges, far_refusal
from .shoulder import ShoulderConvention, convention
from .tree import KinematicTree

_OVERRIDES = ("split", "axis_offset_proximal", "axis_offset_distal", "cylinder")


def pinocchio_model(tree: KinematicTree, shoulder: ShoulderConvention | None = None) -> pin.Model:
    """Revolute-unaligned joints in tree order, so velocity index i is tree.joints[i].

    With a shoulder: its three chain joints come first (velocity indices 0-2, at the
    humerus frame's origin, the glenohumeral centre), the humerus' mass on the last of
    them, then the tree's joints (indices 3-22).
    """
    model = pin.Model()
    model.name = f"forearm_{tree.kind}"
    model.gravity = pin.Motion(np.asarray(tree.gravity, float), np.zeros(3))
    ids = {tree.root.name: 0}
    if shoulder is not None:
        parent = 0
        for k, axis in enumerate(shoulder.axes(tree.side)):
            parent = model.addJoint(parent, pin.JointModelRevoluteUnaligned(*axis), pin.SE3.Identity(),
                                    f"shoulder_chain_{k}")
            model.lowerPositionLimit[parent - 1] = -2 * math.pi
            model.upperPositionLimit[parent - 1] = 2 * math.pi
        root = tree.root
        model.appendBodyToJoint(parent, pin.Inertia(root.mass, root.com, root.inertia), pin.SE3.Identity())
        fid = model.addJointFrame(parent)
        model.addBodyFrame(root.name, parent, pin.SE3.Identity(), fid)
        ids[root.name] = parent
    for joint in tree.joints:
        link = tree.link(joint.child)
        jid = model.addJoint(
            ids[joint.parent],
            pin.JointModelRevoluteUnaligned(*joint.axis),
            pin.SE3(np.eye(3), np.asarray(joint.origin, float)),
            joint.name,
        )
        model.lowerPositionLimit[jid - 1] = joint.lower
        model.upperPositionLimit[jid - 1] = joint.upper
        model.appendBodyToJoint(jid, pin.Inertia(link.mass, link.com, link.inertia), pin.SE3.Identity())
        fid = model.addJointFrame(jid)
        model.addBodyFrame(link.name, jid, pin.SE3.Identity(), fid)
        ids[link.name] = jid
    # Welded bodies (the payload) join their parent's joint body: mass, never a coordinate.
    where = {name: (jid, np.zeros(3)) for name, jid in ids.items()}
    for weld in tree.fixed_joints:
        link = tree.link(weld.child)
        jid, at = where[weld.parent]
        at = at + np.asarray(weld.origin, float)
        placement = pin.SE3(np.eye(3), at)
        model.appendBodyToJoint(jid, pin.Inertia(link.mass, link.com, link.inertia), placement)
        model.addBodyFrame(link.name, jid, placement, model.getFrameId(weld.parent))
        where[link.name] = (jid, at)
    return model


class ArmModel:
    """A built model: joint names, inverse dynamics, URDF export."""

    def __init__(self, tree: KinematicTree, placement: ForearmPlacement | None = None):
        self.tree = tree
        #: how the forearm was built (name, split, axis offsets); None for the anatomical model
        self.placement = placement
        self.kind = tree.kind
        self.body_size: BodySize = tree.body_size
        self.side: str = tree.side
        self.payload: Payload | None = tree.payload
        self.joint_names: tuple[str, ...] = tree.joint_names
        self.nv = len(self.joint_names)
        self.model = pinocchio_model(tree)
        self.data = self.model.createData()
        self._one = (self.nv,)
        self._ranges = None  # ranges.AngleRanges, made on the first batch

    def __repr__(self) -> str:
        payload = "" if self.payload is None else f", payload_mass={self.payload.mass!r}"
        return (f"ArmModel(kind={self.kind!r}, body_size={self.body_size.label!r}, "
                f"side={self.side!r}{payload}, nv={self.nv})")

    # -- inverse dynamics -------------------------------------------------------------
    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torques (N·m) for (20,) inputs, or (N, 20) inputs -> (N, 20)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != self._one:
            return self.inverse_dynamics_batch(q, qd, qdd)
        try:  # fast path: float64 arrays of the right size go straight to Pinocchio
            tau = pin.rnea(self.model, self.data, q, qd, qdd)
        except Exception:  # noqa: BLE001 - lists, ints or wrong sizes: convert and explain
            qd, qdd = np.asarray(qd, dtype=np.float64), np.asarray(qdd, dtype=np.float64)
            if qd.shape != q.shape or qdd.shape != q.shape:
                self._raise_shape(q, qd, qdd)
            tau = pin.rnea(self.model, self.data, q, qd, qdd)
        # NaN/inf in any input propagates into tau: one cheap check on the output.
        if not math.isfinite(tau.dot(tau)):
            self._raise_nonfinite(q, qd, qdd)
        return tau.copy()

    def inverse_dynamics_batch(self, q, qd, qdd, check_ranges: str = "warn") -> np.ndarray:
        """(N, nv) inputs -> (N, nv) torques. Angles far outside the joints' ranges (degrees
        given as radians; forearm_dynamics/ranges.py) are said in one line naming units:
        check_ranges "warn" (default: a UserWarning; the model is also used for arbitrary
        states, engine comparisons and sampling, which must not be refused), "raise" (a
        ValueError: refuse, as the command-line tools and the node do) or "off"."""
        q, qd, qdd = (np.ascontiguousarray(x, dtype=np.float64) for x in (q, qd, qdd))
        if q.ndim != 2 or q.shape[1] != self.nv or qd.shape != q.shape or qdd.shape != q.shape:
            self._raise_shape(q, qd, qdd)
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(qdd).all()):
            self._raise_nonfinite(q, qd, qdd)
        if check_ranges != "off":
            if check_ranges not in ("warn", "raise"):
                raise ValueError(f"check_ranges must be 'warn', 'raise' or 'off', got {check_ranges!r}")
            if self._ranges is None:
                self._ranges = AngleRanges.of(self.joint_names)
            if self._ranges.far(q).any():
                line = "inverse_dynamics: " + far_refusal(q, self._ranges, "q")
                if check_ranges == "raise":
                    raise ValueError(line)
                warnings.warn(line, UserWarning, stacklevel=2)
        out = np.empty_like(q)
        model, data, rnea = self.model, self.data, pin.rnea
        for k in range(q.shape[0]):
            out[k] = rnea(model, data, q[k], qd[k], qdd[k])
        return out

    def _raise_shape(self, q, qd, qdd):
        shapes = ", ".join(f"{n}{np.shape(x)}" for n, x in (("q", q), ("qd", qd), ("qdd", qdd)))
        raise ValueError(
            f"inverse_dynamics expects q, qd, qdd all of shape ({self.nv},) or (N, {self.nv}) "
            f"in joint_names order; got {shapes}"
        )

    def _raise_nonfinite(self, q, qd, qdd):
        bad = []
        for name, x in (("q", q), ("qd", qd), ("qdd", qdd)):
            cols = np.flatnonzero(~np.isfinite(np.atleast_2d(x)).all(axis=0))
            bad += [f"{name}[{self.joint_names[c]}]" for c in cols]
        if not bad:
            raise ValueError("inverse_dynamics: the torques overflow (inputs far out of range)")
        raise ValueError(f"inverse_dynamics got NaN or inf in {', '.join(bad)}")

    # -- other views --------------------------------------------------------------------
    def to_urdf(self) -> str:
        from .urdf import tree_to_urdf

        return tree_to_urdf(self.tree)

    def gravity_torques(self, q) -> np.ndarray:
        z = np.zeros(self.nv)
        return self.inverse_dynamics(q, z, z)


class ShoulderArmModel(ArmModel):
    """The model with a moving humerus: 20 joints, then the three shoulder coordinates.

    joint_names = the 20 joints' names + shoulder.joint_names (nv = 23). Inputs and outputs
    follow that order; the last three torques are the generalized forces of the shoulder
    coordinates (docs/shoulder.md: what they include and omit). Pinocchio's model holds the
    chain first: q_chain = C q_shoulder, tau_shoulder = C.T tau_chain.
    """

    def __init__(self, tree: KinematicTree, placement: ForearmPlacement | None, shoulder: ShoulderConvention):
        self.shoulder = shoulder
        super().__init__(tree, placement)
        self.joint_names = (*tree.joint_names, *shoulder.joint_names)
        self.nv = len(self.joint_names)
        self.model = pinocchio_model(tree, shoulder)
        self.data = self.model.createData()
        self._one = (self.nv,)
        self._c = shoulder.C
        self._ct = np.ascontiguousarray(shoulder.C.T)
        # public order (20 joints, then the shoulder) -> Pinocchio's (chain first) and back
        self._perm = np.r_[20:23, 0:20]
        self._inv = np.r_[3:23, 0:3]
        # the coupling's off-diagonal terms, applied in place (C = I + E, E's source
        # coordinates untouched by it: MoBL's rotation - plane); C.T's likewise
        off = [(int(i), int(j), float(self._c[i, j])) for i, j in zip(*np.nonzero(self._c - np.eye(3)))]
        self._couple = tuple(off)
        self._couple_t = tuple((j, i, k) for i, j, k in off)
        self._q = np.zeros(self.nv)
        self._qd = np.zeros(self.nv)
        self._qdd = np.zeros(self.nv)

    def __repr__(self) -> str:
        return super().__repr__()[:-1] + f", shoulder={self.shoulder.name!r})"

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Torques (N·m; the shoulder's last) for (23,) inputs, or (N, 23) -> (N, 23)."""
        try:  # fast path: float64 arrays of the right size (the node's): a few µs over rnea
            if q.shape == self._one and qd.shape == self._one and qdd.shape == self._one:
                perm = self._perm
                a, b = q.take(perm, out=self._q), qd.take(perm, out=self._qd)
                d = qdd.take(perm, out=self._qdd)
                for i, j, k in self._couple:
                    a[i] += k * a[j]
                    b[i] += k * b[j]
                    d[i] += k * d[j]
                out = pin.rnea(self.model, self.data, a, b, d).take(self._inv)
                for i, j, k in self._couple_t:
                    out[20 + i] += k * out[20 + j]
                if not math.isfinite(out.dot(out)):
                    self._raise_nonfinite(q, qd, qdd)
                return out
        except (AttributeError, TypeError):  # lists, ints: convert below
            pass
        q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
        if q.ndim == 2:
            return self.inverse_dynamics_batch(q, qd, qdd)
        if q.shape != self._one or qd.shape != self._one or qdd.shape != self._one:
            self._raise_shape(q, qd, qdd)
        return self.inverse_dynamics(q, qd, qdd)

    def inverse_dynamics_batch(self, q, qd, qdd) -> np.ndarray:
        q, qd, qdd = (np.ascontiguousarray(x, dtype=np.float64) for x in (q, qd, qdd))
        if q.ndim != 2 or q.shape[1] != self.nv or qd.shape != q.shape or qdd.shape != q.shape:
            self._raise_shape(q, qd, qdd)
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(qdd).all()):
            self._raise_nonfinite(q, qd, qdd)

        def chain(x):
            return np.ascontiguousarray(np.hstack([x[:, 20:] @ self._c.T, x[:, :20]]))

        qc, qdc, qddc = chain(q), chain(qd), chain(qdd)
        out = np.empty_like(q)
        model, data, rnea = self.model, self.data, pin.rnea
        for k in range(q.shape[0]):
            tau = rnea(model, data, qc[k], qdc[k], qddc[k])
            out[k, :20] = tau[3:]
            out[k, 20:] = self._ct @ tau[:3]
        return out


def build_model(
    kind: str = "segmented",
    body_size: Any = 50,
    *,
    side: str = "right",
    payload_mass: float = 0.0,
    payload_com=None,
    payload_inertia=None,
    placement: str | None = None,
    shoulder: str = "none",
    **overrides,
) -> ArmModel:
    """Build one of the three 20-DOF models.

    kind: "segmented", "solid" or "anatomical". body_size: 5, 50, 95 (men), "male_5" ...
    "female_95", or a dict with stature/body_mass (and optional forearm_length, hand_length,
    hand_breadth), in m and kg. side: "right" or "left" (the mirror image, same joint names
    and signs). payload_mass (kg), payload_com ((x, y, z) m in the hand frame; None = the
    default power-grasp point, hand.grasp_point), payload_inertia (None = point mass, or
    (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) kg·m² about the payload COM): an object held in the hand,
    see payload.py for the frame. placement (segmented only): "paper", "parallel" or
    "oblique" (config/model.yaml); None = the config's default_placement. The built model's
    `placement` says which. overrides (simplified models only): split,
    axis_offset_proximal, axis_offset_distal, cylinder ("uniform" | "mass_matched").
    shoulder: "none" (the humerus welded, vertical and still: the model of the paper),
    "mobl" or "fullbody" (three more coordinates turn the humerus, in that model's
    sequence: a ShoulderArmModel, nv = 23; forearm_dynamics/shoulder.py, docs/shoulder.md).
    """
    unknown = set(overrides) - set(_OVERRIDES)
    if unknown:
        raise ValueError(f"unknown override(s) {sorted(unknown)}; accepted: {_OVERRIDES}")
    if not isinstance(kind, str):
        raise ValueError(f"model kind must be a string, got {kind!r}")  # noqa: TRY004
    size = resolve_body_size(body_size)
    desc = load_description()
    payload = make_payload(payload_mass, payload_com, payload_inertia, grasp_point(desc, size))
    tree = build_tree(kind, desc, size, placement=placement, side=side, payload=payload, **overrides)
    resolved = resolve_placement(kind, desc, size, placement, **overrides)
    if shoulder == "none":
        return ArmModel(tree, resolved)
    return ShoulderArmModel(tree, resolved, convention(shoulder))
