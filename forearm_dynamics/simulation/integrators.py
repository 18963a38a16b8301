"""Fixed-step integrators of q̈ = f(t, q, q̇) for revolute joints (q and q̇ both in R^nv).

Every joint of the models is a 1-DOF revolute, so the configuration space is R^nv and
`q + dt·q̇` is the exact Lie-group integration (pin.integrate does the same additions);
no quaternion renormalisation is needed.

- "rk4": the classical 4th-order Runge–Kutta, the solver the paper ran its Simulink models
  with (fixed step, 1 ms). The acceleration is evaluated at t, t+dt/2 (twice) and t+dt.
- "semi_implicit_euler" (symplectic Euler): q̇ₖ₊₁ = q̇ₖ + dt·f(tₖ, qₖ, q̇ₖ), qₖ₊₁ = qₖ + dt·q̇ₖ₊₁.
  One evaluation per step, first order, but its energy error stays bounded instead of
  drifting — the usual choice of game and robot simulators.

The step functions evaluate the operations in a fixed order with no parallel reduction,
so the same inputs give the same outputs bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Accel = Callable[[float, np.ndarray, np.ndarray], np.ndarray]

METHODS = ("rk4", "semi_implicit_euler")


def rk4_step(f: Accel, t: float, q: np.ndarray, qd: np.ndarray, dt: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """One classical RK4 step of the second-order system; returns new (q, qd)."""
    h = 0.5 * dt
    a1 = f(t, q, qd)
    q2, v2 = q + h * qd, qd + h * a1
    a2 = f(t + h, q2, v2)
    q3, v3 = q + h * v2, qd + h * a2
    a3 = f(t + h, q3, v3)
    q4, v4 = q + dt * v3, qd + dt * a3
    a4 = f(t + dt, q4, v4)
    s = dt / 6.0
    q_new = q + s * (qd + 2.0 * v2 + 2.0 * v3 + v4)
    qd_new = qd + s * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return q_new, qd_new


def semi_implicit_euler_step(f: Accel, t: float, q: np.ndarray, qd: np.ndarray, dt: float
                             ) -> tuple[np.ndarray, np.ndarray]:
    """One symplectic Euler step: velocity first, then position with the new velocity."""
    qd_new = qd + dt * f(t, q, qd)
    return q + dt * qd_new, qd_new


STEPPERS = {"rk4": rk4_step, "semi_implicit_euler": semi_implicit_euler_step}


def stepper(method: str):
    try:
        return STEPPERS[method]
    except KeyError:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}") from None


__all__ = ["METHODS", "rk4_step", "semi_implicit_euler_step", "stepper"]
