"""The same KinematicTree as an OpenSim model: an independent inverse-dynamics reference.

OpenSim (Simbody) is an optional extra (`pip install .[reference]`), so it is imported lazily;
the rest of the package never needs it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from .shoulder import ShoulderConvention
from .tree import KinematicTree, Link

#: OpenSim coordinate names of a shoulder's chain joints (the engine's own; see OpenSimArm)
CHAIN_NAMES = ("shoulder_chain_0", "shoulder_chain_1", "shoulder_chain_2")


def opensim_available() -> bool:
    """True when the optional `opensim` package can be imported."""
    return importlib.util.find_spec("opensim") is not None


def _osim() -> Any:
    try:
        import opensim  # optional dependency: imported only when used
    except ImportError as exc:
        raise ImportError(
            "the OpenSim reference needs the optional 'opensim' package: pip install '.[reference]'"
        ) from exc
    opensim.Logger.removeFileSink()  # no opensim.log in the user's working directory
    return opensim


def _orthonormal(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing `axis` to a right-handed basis (CustomJoint needs 3 axes)."""
    a = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    b = np.cross(a, helper)
    b /= np.linalg.norm(b)
    return b, np.cross(a, b)


def _vec3(osim: Any, v) -> Any:
    x, y, z = (float(c) for c in v)
    return osim.Vec3(x, y, z)


def _custom_joint(osim: Any, name: str, coordinate: str, axis, parent: Any, origin, child: Any) -> Any:
    """A one-coordinate CustomJoint: rotation about `axis` (parent frame) at `origin`."""
    zero = osim.Vec3(0.0, 0.0, 0.0)
    st = osim.SpatialTransform()
    axes = (axis, *_orthonormal(np.asarray(axis, float)))
    for k, ax in enumerate(axes):
        rot = st.updTransformAxis(k)
        rot.setAxis(_vec3(osim, ax))
        if k == 0:
            rot.setCoordinateNames(osim.ArrayStr(coordinate, 1))
            # setFunction(osim.LinearFunction()) segfaults; set_function with a copy works.
            rot.set_function(osim.LinearFunction(1.0, 0.0))
        else:
            rot.set_function(osim.Constant(0.0))
    for k in range(3, 6):
        st.updTransformAxis(k).set_function(osim.Constant(0.0))
    return osim.CustomJoint(name, parent, _vec3(osim, origin), zero, child, zero, zero, st)


def build_osim_model(tree: KinematicTree, shoulder: ShoulderConvention | None = None) -> Any:
    """An osim.Model mirroring `tree`: one single-coordinate CustomJoint per tree joint.

    shoulder: the humerus hangs from the ground by three one-coordinate CustomJoints in the
    convention's chain (coordinates CHAIN_NAMES, two massless intermediate bodies) instead
    of a weld.
    """
    osim = _osim()
    model = osim.Model()
    model.setName(f"forearm_{tree.kind}_{tree.side}_{tree.body_size.label}")
    model.setGravity(_vec3(osim, tree.gravity))  # explicit: never rely on the default

    def body(link: Link) -> Any:
        i = np.asarray(link.inertia, float)
        inertia = osim.Inertia(i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
        return osim.Body(link.name, float(link.mass), _vec3(osim, link.com), inertia)

    bodies = {tree.root.name: body(tree.root)}
    model.addBody(bodies[tree.root.name])
    if shoulder is None:
        model.addJoint(osim.WeldJoint(f"{tree.root.name}_ground", model.getGround(), bodies[tree.root.name]))
    else:
        parent = model.getGround()
        for k, axis in enumerate(shoulder.axes(tree.side)):
            if k < 2:
                child = osim.Body(f"shoulder_phantom_{k}", 0.0, osim.Vec3(0.0, 0.0, 0.0),
                                  osim.Inertia(0.0, 0.0, 0.0))
                model.addBody(child)
            else:
                child = bodies[tree.root.name]
            cj = _custom_joint(osim, f"shoulder_{k}", CHAIN_NAMES[k], axis, parent, np.zeros(3), child)
            model.addJoint(cj)
            coord = cj.upd_coordinates(0)
            coord.setRangeMin(-2 * np.pi)
            coord.setRangeMax(2 * np.pi)
            coord.setDefaultClamped(False)
            coord.setDefaultLocked(False)
            parent = child
    zero = osim.Vec3(0.0, 0.0, 0.0)
    for joint in tree.joints:
        child = bodies[joint.child] = body(tree.link(joint.child))
        model.addBody(child)
        st = osim.SpatialTransform()
        axes = (joint.axis, *_orthonormal(np.asarray(joint.axis, float)))
        for k, ax in enumerate(axes):
            rot = st.updTransformAxis(k)
            rot.setAxis(_vec3(osim, ax))
            if k == 0:
                rot.setCoordinateNames(osim.ArrayStr(joint.name, 1))
                # setFunction(osim.LinearFunction()) segfaults; set_function with a copy works.
                rot.set_function(osim.LinearFunction(1.0, 0.0))
            else:
                rot.set_function(osim.Constant(0.0))
        for k in range(3, 6):
            st.updTransformAxis(k).set_function(osim.Constant(0.0))
        cj = osim.CustomJoint(joint.name, bodies[joint.parent], _vec3(osim, joint.origin), zero,
                              child, zero, zero, st)
        model.addJoint(cj)
        coord = cj.upd_coordinates(0)
        coord.setRangeMin(float(joint.lower))
        coord.setRangeMax(float(joint.upper))
        coord.setDefaultClamped(False)  # ID must work outside the anatomical range too
        coord.setDefaultLocked(False)
    for weld in tree.fixed_joints:  # the payload: a body welded to the carpus
        child = bodies[weld.child] = body(tree.link(weld.child))
        model.addBody(child)
        model.addJoint(osim.WeldJoint(weld.name, bodies[weld.parent], _vec3(osim, weld.origin), zero,
                                      child, zero, zero))
    model.finalizeConnections()
    return model


class OpenSimArm:
    """OpenSim inverse dynamics with the ArmModel interface (joint_names order, N·m).

    With a shoulder: the same 23 inputs and outputs as ShoulderArmModel (the 20 joints,
    then the convention's public coordinates); the engine's chain coordinates are
    C @ public, its public generalized forces C.T @ chain forces.
    """

    def __init__(self, tree: KinematicTree, shoulder: ShoulderConvention | None = None):
        osim = _osim()
        self.tree = tree
        self.kind = tree.kind
        self.shoulder = shoulder
        self.joint_names: tuple[str, ...] = tree.joint_names + (() if shoulder is None else CHAIN_NAMES)
        self.nv = len(self.joint_names)
        self.model = build_osim_model(tree, shoulder)
        self._state = self.model.initSystem()
        self._solver = osim.InverseDynamicsSolver(self.model)
        self._to_vector = osim.Vector.createFromMat
        self.internal_order = self._internal_order()

    def __repr__(self) -> str:
        return f"OpenSimArm(kind={self.kind!r}, body_size={self.tree.body_size.label!r})"

    def _internal_order(self) -> np.ndarray:
        """order[k] = index in joint_names of slot k of the state's Q/U (Simbody mobility) vectors.

        Simbody numbers mobilities by its own tree traversal, not by CoordinateSet order, and the
        ID solver answers in that order. Tagging each coordinate with a distinct value and reading
        the raw vectors back finds the map without relying on either ordering rule.
        """
        s = self._state
        if s.getNQ() != self.nv or s.getNU() != self.nv:
            raise RuntimeError(f"expected {self.nv} q and u, got {s.getNQ()} and {s.getNU()}")
        coords = self.model.getCoordinateSet()
        for i, name in enumerate(self.joint_names):
            coords.get(name).setValue(s, 0.001 * (i + 1), False)
            coords.get(name).setSpeedValue(s, float(i + 1))
        order = np.rint(s.getU().to_numpy()).astype(int) - 1
        if sorted(order) != list(range(self.nv)) or not np.allclose(
            s.getQ().to_numpy(), 0.001 * (order + 1), rtol=0.0, atol=1e-12
        ):
            raise RuntimeError("could not map OpenSim's internal coordinate order to joint_names")
        return order

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torques (N·m) for (20,) inputs, or (N, 20) inputs -> (N, 20)."""
        q, qd, qdd = (np.asarray(x, dtype=np.float64) for x in (q, qd, qdd))
        single = q.ndim == 1
        if q.shape[-1:] != (self.nv,) or q.ndim > 2 or qd.shape != q.shape or qdd.shape != q.shape:
            raise ValueError(f"expected q, qd, qdd all of shape ({self.nv},) or (N, {self.nv}) "
                             f"in joint_names order; got {q.shape}, {qd.shape}, {qdd.shape}")
        if not (np.isfinite(q).all() and np.isfinite(qd).all() and np.isfinite(qdd).all()):
            raise ValueError("inverse_dynamics got NaN or inf in the inputs")
        if self.shoulder is not None:  # public shoulder coordinates -> the engine's chain
            c = self.shoulder.C
            q, qd, qdd = (np.concatenate([np.atleast_2d(x)[:, :20], np.atleast_2d(x)[:, 20:] @ c.T], axis=1)
                          for x in (q, qd, qdd))
        order = self.internal_order
        # Permute once for the whole batch so each row is already in state order.
        qi, ui, ai = (np.ascontiguousarray(np.atleast_2d(x)[:, order]) for x in (q, qd, qdd))
        out = np.empty_like(qi)
        s, solve, vec = self._state, self._solver.solve, self._to_vector
        for k in range(qi.shape[0]):
            s.setQ(vec(qi[k]))
            s.setU(vec(ui[k]))
            # solve() realizes to Stage::Dynamics itself (gravity included); no realize here.
            out[k] = solve(s, vec(ai[k])).to_numpy()
        tau = np.empty_like(out)
        tau[:, order] = out
        if self.shoulder is not None:
            tau[:, 20:] = tau[:, 20:] @ self.shoulder.C
        return tau[0] if single else tau

    def to_osim(self, path: str | Path) -> Path:
        """Write the model as an .osim XML file (to open in the OpenSim GUI or tools)."""
        path = Path(path)
        self.model.printToXML(str(path))
        return path


__all__ = ["CHAIN_NAMES", "OpenSimArm", "build_osim_model", "opensim_available"]
