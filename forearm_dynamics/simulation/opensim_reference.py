"""The same arm integrated by OpenSim (Simbody): the independent forward-dynamics engine.

The model is opensim_engine.build_osim_model's (the tree read by a second engine), with a
CoordinateActuator and a constant PrescribedController per driven joint; Simbody's
variable-step Runge–Kutta–Merson integrates it to a tight accuracy, so what differs from
our fixed-step solver is our integration error (plus the engines' rounding). No damping
and no limits: OpenSim's would be other models (CoordinateLimitForce is smooth), not ours.
OpenSim is the optional `reference` extra, imported lazily.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..opensim_engine import _osim, build_osim_model
from ..tree import KinematicTree


def opensim_forward(tree: KinematicTree, q0, qd0, times: Sequence[float],
                    torques: Mapping[str, float] | None = None,
                    accuracy: float = 1e-9) -> np.ndarray:
    """q (len(times), nv) at `times` (s, increasing, > 0) from (q0, qd0) at t = 0, joint
    names order, under gravity and constant `torques` {joint: N·m} (others zero)."""
    osim = _osim()
    model = build_osim_model(tree)
    names = tree.joint_names
    if torques:
        unknown = sorted(set(torques) - set(names))
        if unknown:
            raise ValueError(f"torques name unknown joint(s) {unknown}")
        ctrl = osim.PrescribedController()
        ctrl.setName("constant_torques")
        for name, tau in torques.items():
            act = osim.CoordinateActuator(name)
            act.setName(f"torque_{name}")
            act.setOptimalForce(1.0)  # control = torque in N·m
            act.setMinControl(-1e9)
            act.setMaxControl(1e9)
            model.addForce(act)
            ctrl.addActuator(act)
            ctrl.prescribeControlForActuator(f"torque_{name}", osim.Constant(float(tau)))
        model.addController(ctrl)
        model.finalizeConnections()
    state = model.initSystem()
    coords = model.getCoordinateSet()
    q0, qd0 = np.asarray(q0, float), np.asarray(qd0, float)
    for i, name in enumerate(names):
        coords.get(name).setValue(state, float(q0[i]), False)
        coords.get(name).setSpeedValue(state, float(qd0[i]))
    model.realizeVelocity(state)
    manager = osim.Manager(model)
    manager.setIntegratorMethod(osim.Manager.IntegratorMethod_RungeKuttaMerson)
    manager.setIntegratorAccuracy(float(accuracy))
    manager.setRecordStatesTrajectory(False)
    state.setTime(0.0)
    manager.initialize(state)
    out = np.empty((len(times), len(names)))
    for k, t in enumerate(times):
        s = manager.integrate(float(t))
        out[k] = [coords.get(n).getValue(s) for n in names]
    return out


__all__ = ["opensim_forward"]
