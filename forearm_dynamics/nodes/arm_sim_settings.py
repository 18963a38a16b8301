"""arm_sim's parameters: the torque node's model parameters (imported, not copied) and the
simulation's own, validated into one frozen ArmSimSettings."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..description import JOINT_NAMES, load_description
from ..dynamics import ArmModel, build_model
from ..estimation import DEFAULT_ESTIMATOR
from ..simulation import DEFAULT_DAMPING, METHODS, SimSettings
from .common import EXECUTORS
from .params import ParameterError, Params, Spec
from .scheduling import REALTIME_SPECS
from .torque_config import MODEL_SPECS, TORQUE_STD_ONLY, ModelRequest

#: torque_node's model parameters, one definition: read-only here (a running simulation
#: keeps its arm; restart it for another).
SIM_MODEL_SPECS = tuple(replace(s, live=False) for s in MODEL_SPECS
                        if not s.name.startswith("estimator") and s.name not in TORQUE_STD_ONLY)
_MODEL_NAMES = tuple(s.name for s in SIM_MODEL_SPECS)


def _mid_range() -> dict[str, float]:
    r = load_description().ranges
    return {n: 0.5 * (r[n][0] + r[n][1]) for n in JOINT_NAMES}


SIM_SPECS = (
    Spec("rate_hz", 1000.0, "integration rate: one fixed step of 1/rate_hz per tick (real time) "
         "or per command (lockstep); joint_states are published every step", "Hz", 1.0, 10000.0),
    Spec("method", "rk4", "fixed-step solver: rk4 (the paper's) or semi_implicit_euler",
         choices=METHODS),
    Spec("damping", DEFAULT_DAMPING, "viscous damping of every joint (damping.<joint> >= 0 "
         "overrides one); refused beyond the solver's stability (the finger DIP joints' "
         "~1e-7 kg*m^2 bound it: ~3e-4 at 1 kHz)", "N*m*s/rad", 0.0, 1000.0),
    *(Spec(f"damping.{n}", -1.0, f"viscous damping of {n}; -1 = the `damping` value",
           "N*m*s/rad", -1.0, 1000.0) for n in JOINT_NAMES),
    Spec("joint_limits", True, "a 50 Hz spring-damper on each joint beyond its movement range "
         "(config/model.yaml ranges_deg; simulation/passive.py)"),
    *(Spec(f"initial_posture.{n}", x, f"initial angle of {n} (default: mid-range)", "rad",
           -10.0, 10.0) for n, x in _mid_range().items()),
    Spec("command_timeout", 0.1, "real-time mode: no accepted command for this long -> zero "
         "torque, said in /diagnostics; 0 = hold the last command for ever", "s", 0.0, 3600.0),
    Spec("lockstep", False, "true: no timer; every command received advances one step (a refused "
         "one too, with the last accepted torques) and the simulated time is published on "
         "/clock"),
    Spec("max_torque", 500.0, "a command with |effort| above this on any joint is refused",
         "N*m", 0.0, 1e6),
    Spec("command_topic", "joint_commands", "JointState input: effort by joint name (N*m); "
         "joints not named get zero torque"),
    Spec("state_topic", "joint_states", "JointState output: position, velocity, and effort = the "
         "commanded torque applied over the step, stamped with the simulated time"),
    Spec("qos_depth", 1000, "history depth of commands and states (1 s at 1 kHz)", "messages",
         1, 100000),
    Spec("executor", "events", "rclpy executor: events or single", choices=EXECUTORS),
    Spec("diagnostics_period", 1.0, "time between /diagnostics messages; 0 = none", "s",
         0.0, 3600.0),
)

SPECS = (*SIM_MODEL_SPECS, *SIM_SPECS, *REALTIME_SPECS)


@dataclass(frozen=True)
class ArmSimSettings:
    """The validated parameters of one arm_sim."""

    arm: ArmModel
    sim: SimSettings
    q0: np.ndarray
    rate_hz: float
    command_timeout: float
    lockstep: bool
    max_torque: float
    command_topic: str
    state_topic: str
    qos_depth: int
    executor: str
    diagnostics_period: float

    @classmethod
    def from_params(cls, p: Params) -> ArmSimSettings:
        values: dict[str, Any] = p.values(_MODEL_NAMES)
        values["estimator"] = DEFAULT_ESTIMATOR  # ModelRequest's other half: unused here
        req = ModelRequest.from_values(values)
        try:
            arm = build_model(req.kind, req.body_size, **req.build_kwargs())
        except ValueError as exc:
            raise ParameterError("model", str(exc)) from None
        base = p.value("damping")
        damping = {"*": base}
        for n in JOINT_NAMES:
            c = p.value(f"damping.{n}")
            if c != -1.0:
                if c < 0.0:
                    raise ParameterError(f"damping.{n}", f"{c!r}: must be >= 0, or -1 for `damping`")
                damping[n] = c
        rate = p.value("rate_hz")
        sim = SimSettings(1.0 / rate, p.value("method"), damping, p.value("joint_limits"))
        q0 = np.array([p.value(f"initial_posture.{n}") for n in JOINT_NAMES])
        for n, x in zip(JOINT_NAMES, q0, strict=True):
            if not math.isfinite(x):
                raise ParameterError(f"initial_posture.{n}", f"must be finite, got {x!r}")
        settings = cls(arm, sim, q0, rate, p.value("command_timeout"), p.value("lockstep"),
                       p.value("max_torque"), p.topic("command_topic"), p.topic("state_topic"),
                       p.value("qos_depth"), p.value("executor"), p.value("diagnostics_period"))
        p.distinct_topics(("command_topic", "state_topic"),
                          {"/diagnostics": "diagnostics topic", "/clock": "clock topic",
                           "~/config": "node's config topic"})
        return settings
