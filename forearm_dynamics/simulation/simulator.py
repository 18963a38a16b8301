"""The virtual arm: forward dynamics of one ArmModel (Pinocchio's ABA) stepped at a fixed dt.

    q̈ = ABA(q, q̇, τ_cmd + τ_passive(q, q̇))      τ_passive: damping and limits (passive.py)

`ArmSimulator` holds the state and advances it one step at a time with a command held
constant over the step (a zero-order hold: what a controller sampled at 1/dt sends);
`simulate()` runs a whole horizon from a torque function evaluated at every solver stage
(a continuous-time input, as Simulink evaluates its minor steps) or from an array of
per-step commands.

Determinism: one Pinocchio Data per simulator, no threads, no random numbers, operations
in a fixed order: the same model, initial state and commands give the same trajectory bit
for bit (test_simulation checks it across two fresh simulators).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..dynamics import ArmModel
from .integrators import METHODS, stepper
from .passive import DEFAULT_DAMPING, check_stability, make_passive, neutral_posture

TorqueFn = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class SimSettings:
    """How the arm is integrated. damping: N·m·s/rad, one number for every joint, a
    {joint: value} mapping (others DEFAULT_DAMPING; "*" sets the rest) or an (nv,) array.
    joint_limits: spring-dampers beyond the movement ranges (passive.py)."""

    dt: float = 1e-3
    method: str = "rk4"
    damping: float | Mapping[str, float] | tuple[float, ...] = DEFAULT_DAMPING
    joint_limits: bool = True

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if not (isinstance(self.dt, float | int) and 0.0 < self.dt <= 0.1):
            raise ValueError(f"dt must be a step in (0, 0.1] s, got {self.dt!r}")


@dataclass(frozen=True)
class SimResult:
    """t (N+1,) s; q, qd (N+1, nv) rad, rad/s, row 0 the initial state; tau (N, nv) N·m:
    the command of each step (for a torque function: its value at the step's start)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    joint_names: tuple[str, ...]


class ArmSimulator:
    """State (t, q, qd) of one arm and the step that advances it."""

    def __init__(self, arm: ArmModel, settings: SimSettings | None = None, q0=None, qd0=None):
        self.arm = arm
        self.settings = s = settings or SimSettings()
        self.nv = arm.nv
        self.joint_names = arm.joint_names
        self.passive = make_passive(arm, s.damping, s.joint_limits)
        check_stability(arm, self.passive.damping, float(s.dt), s.method)
        self._model = arm.model
        self._data = arm.model.createData()
        self._step = stepper(s.method)
        self.dt = float(s.dt)
        self.steps = 0
        self.t = 0.0
        self.q = neutral_posture(arm)
        self.qd = np.zeros(self.nv)
        self.reset(q0, qd0)

    def reset(self, q0=None, qd0=None, t: float = 0.0) -> None:
        """Set the state; None keeps neutral posture / zero velocity."""
        q = neutral_posture(self.arm) if q0 is None else self._vector("q0", q0)
        qd = np.zeros(self.nv) if qd0 is None else self._vector("qd0", qd0)
        self.q, self.qd, self.t, self.steps = q, qd, float(t), 0

    def _vector(self, name: str, x) -> np.ndarray:
        a = np.array(x, dtype=np.float64).reshape(-1)
        if a.shape != (self.nv,) or not np.isfinite(a).all():
            raise ValueError(f"{name} must be {self.nv} finite numbers in joint_names order, "
                             f"got shape {np.shape(x)}")
        return a

    def acceleration(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """q̈ from ABA with the command plus the passive torques."""
        return pin.aba(self._model, self._data, q, qd, tau + self.passive.torque(q, qd)).copy()

    def step(self, tau) -> None:
        """Advance one dt with the command `tau` (nv,) N·m held constant over the step."""
        tau = np.asarray(tau, dtype=np.float64)
        self.q, self.qd = self._step(lambda _t, q, qd: self.acceleration(q, qd, tau),
                                     self.t, self.q, self.qd, self.dt)
        self.steps += 1
        self.t = self.steps * self.dt  # no accumulated rounding in the clock

    def energy(self, q=None, qd=None) -> float:
        """Kinetic + gravitational potential energy (J) of the state (default: the current)."""
        return total_energy(self.arm, self.q if q is None else q, self.qd if qd is None else qd)

    def describe(self) -> dict:
        """The settings as numbers: for a config message or a log."""
        p = self.passive
        out = {"dt": self.dt, "method": self.settings.method,
               "damping": dict(zip(self.joint_names, p.damping.tolist(), strict=True)),
               "joint_limits": p.limit_stiffness is not None}
        if p.limit_stiffness is not None:
            out["limit_stiffness"] = dict(zip(self.joint_names, p.limit_stiffness.tolist(), strict=True))
            out["limit_damping"] = dict(zip(self.joint_names, p.limit_damping.tolist(), strict=True))
        return out


def total_energy(arm: ArmModel, q, qd) -> float:
    data = arm.model.createData()
    q, qd = np.asarray(q, float), np.asarray(qd, float)
    return float(pin.computeKineticEnergy(arm.model, data, q, qd)
                 + pin.computePotentialEnergy(arm.model, data, q))


def simulate(arm: ArmModel, q0, qd0, torque_fn: TorqueFn | np.ndarray | None, dt: float = 1e-3,
             method: str = "rk4", *, duration: float | None = None, steps: int | None = None,
             damping=DEFAULT_DAMPING, joint_limits: bool = True) -> SimResult:
    """Integrate the arm from (q0, qd0) for `duration` s (or `steps` steps) at fixed `dt`.

    torque_fn: a function (t, q, qd) -> (nv,) N·m evaluated at every solver stage (RK4: 4
    per step), an (N, nv) array of per-step commands (held over each step; N fixes the
    horizon if neither duration nor steps is given), or None (zero command).
    method: "rk4" (the paper's) or "semi_implicit_euler". damping, joint_limits: see
    SimSettings (for a pure integration-error study pass damping=0, joint_limits=False).
    """
    sim = ArmSimulator(arm, SimSettings(dt, method, damping, joint_limits), q0, qd0)
    held = None if torque_fn is None or callable(torque_fn) else np.asarray(torque_fn, float)
    if held is not None and (held.ndim != 2 or held.shape[1] != arm.nv):
        raise ValueError(f"a torque array must be (N, {arm.nv}), got {held.shape}")
    if steps is None:
        if duration is not None:
            steps = round(duration / dt)
        elif held is not None:
            steps = held.shape[0]
        else:
            raise ValueError("give duration or steps (or a torque array)")
    if held is not None and held.shape[0] < steps:
        raise ValueError(f"torque array has {held.shape[0]} rows for {steps} steps")
    n = sim.nv
    q, qd, tau = np.empty((steps + 1, n)), np.empty((steps + 1, n)), np.zeros((steps, n))
    q[0], qd[0] = sim.q, sim.qd
    step = stepper(method)
    for k in range(steps):
        t = k * dt
        if held is not None:
            tau[k] = held[k]
            sim.step(held[k])
        elif torque_fn is None:
            sim.step(tau[k])
        else:
            tau[k] = torque_fn(t, sim.q, sim.qd)

            def f(ti, qi, qdi):
                return sim.acceleration(qi, qdi, np.asarray(torque_fn(ti, qi, qdi), float))

            sim.q, sim.qd = step(f, t, sim.q, sim.qd, dt)
            sim.steps += 1
            sim.t = sim.steps * dt
        q[k + 1], qd[k + 1] = sim.q, sim.qd
    return SimResult(np.arange(steps + 1) * dt, q, qd, tau, arm.joint_names)


__all__ = ["ArmSimulator", "SimResult", "SimSettings", "simulate", "total_energy"]
