"""Forward dynamics of the forearm-hand models: the virtual arm (ROS-free core).

    from forearm_dynamics.dynamics import build_model
    from forearm_dynamics.simulation import simulate
    arm = build_model("segmented", 50)
    res = simulate(arm, q0, qd0, lambda t, q, qd: tau, dt=1e-3, method="rk4", duration=1.5)

simulator.py: ArmSimulator (state + one step, command held over the step), simulate();
integrators.py: RK4 (the paper's solver) and semi-implicit Euler; passive.py: damping
and joint-limit springs with their documented defaults. Used by the arm_sim node.
"""

from .integrators import METHODS
from .passive import (
    DEFAULT_DAMPING,
    LIMIT_DAMPING_RATIO,
    LIMIT_FREQUENCY_HZ,
    effective_inertia,
    joint_bounds,
    limit_gains,
    neutral_posture,
)
from .simulator import ArmSimulator, SimResult, SimSettings, simulate, total_energy

__all__ = ["DEFAULT_DAMPING", "LIMIT_DAMPING_RATIO", "LIMIT_FREQUENCY_HZ", "METHODS",
           "ArmSimulator", "SimResult", "SimSettings", "effective_inertia", "joint_bounds", "limit_gains",
           "neutral_posture", "simulate", "total_energy"]
