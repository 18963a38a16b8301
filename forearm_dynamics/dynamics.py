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
from .tree import KinematicTree

_OVERRIDES = ("split", "axis_offset_proximal", "axis_offset_distal", "cylinder")


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


def build_model(
    kind: str = "segmented",
    body_size: Any = 50,
    *,
    side: str = "right",
    payload_mass: float = 0.0,
    payload_com=None,
    payload_inertia=None,
    placement: str | None = None,
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
    return ArmModel(tree, resolve_placement(kind, desc, size, placement, **overrides))
