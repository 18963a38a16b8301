"""Inverse dynamics of one model with Pinocchio: per sample and in batches."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pinocchio as pin

from .anthropometry import BodySize, resolve_body_size
from .builders import build_tree
from .description import load_description
from .tree import KinematicTree

_OVERRIDES = ("split", "axis_offset_proximal", "axis_offset_distal")


def pinocchio_model(tree: KinematicTree) -> pin.Model:
    """Revolute-unaligned joints in tree order, so velocity index i is tree.joints[i]."""
    model = pin.Model()
    model.name = f"forearm_{tree.kind}"
    model.gravity = pin.Motion(np.asarray(tree.gravity, float), np.zeros(3))
    ids = {tree.root.name: 0}
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
    return model


class ArmModel:
    """A built model: joint names, inverse dynamics, URDF export."""

    def __init__(self, tree: KinematicTree):
        self.tree = tree
        self.kind = tree.kind
        self.body_size: BodySize = tree.body_size
        self.joint_names: tuple[str, ...] = tree.joint_names
        self.nv = len(self.joint_names)
        self.model = pinocchio_model(tree)
        self.data = self.model.createData()
        self._one = (self.nv,)

    def __repr__(self) -> str:
        return f"ArmModel(kind={self.kind!r}, body_size={self.body_size.label!r}, nv={self.nv})"

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

    def inverse_dynamics_batch(self, q, qd, qdd) -> np.ndarray:
        q, qd, qdd = (np.ascontiguousarray(x, dtype=np.float64) for x in (q, qd, qdd))
        if q.ndim != 2 or q.shape[1] != self.nv or qd.shape != q.shape or qdd.shape != q.shape:
            self._raise_shape(q, qd, qdd)
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(qdd).all()):
            self._raise_nonfinite(q, qd, qdd)
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


def build_model(kind: str = "segmented", body_size: Any = 50, **overrides) -> ArmModel:
    """Build one of the three 20-DOF models.

    kind: "segmented", "solid" or "anatomical". body_size: 5, 50, 95, or a dict with
    stature/body_mass (and optional forearm_length, hand_length, hand_breadth), in m and kg.
    overrides (simplified models only): split, axis_offset_proximal, axis_offset_distal.
    """
    unknown = set(overrides) - set(_OVERRIDES)
    if unknown:
        raise ValueError(f"unknown override(s) {sorted(unknown)}; accepted: {_OVERRIDES}")
    if not isinstance(kind, str):
        raise ValueError(f"model kind must be a string, got {kind!r}")  # noqa: TRY004
    size = resolve_body_size(body_size)
    return ArmModel(build_tree(kind, load_description(), size, **overrides))
