"""Passive joint torques of the virtual arm: viscous damping and joint-limit springs.

Both are explicit forces integrated by the same fixed-step solver as the rest of the arm,
so both are bounded by that solver's stability. That bound is what sets the defaults: the
distal finger phalanges have inertias of ~1e-7 kg·m² (5th-percentile men: the smallest
eigenvalue of the joint-space mass matrix is 7.4e-8 kg·m²), and a viscous damper c on such
a joint has the time constant I/c, which explicit RK4 at dt = 1 ms follows only while
dt·λ_max(M⁻¹C) < 2.785. So:

- DEFAULT_DAMPING = 1e-7 N·m·s/rad on every joint: small for every joint of every arm.
  A uniform damping cannot be "small" by one number for an elbow (effective inertia
  0.042 kg·m², 50th-percentile man) and a fingertip (1.3e-7 kg·m²; female 5th: 5.5e-8):
  its time constant m/c is 0.5-2 s on the DIP joints (they stop ringing within a few
  movements) and ~5 days on the elbow. 5e-5 (tried first) made the fingertips
  over-damped (5 ms), so that a controller that does not know the damping missed finger
  movements by 0.1 rad (examples/closed_loop.py: computed torque at 5 Hz; 2e-4 rad with
  1e-7). Larger damping (a real joint's: ~1e-3 to 1 N·m·s/rad) is accepted up to
  `STABILITY_MARGIN` of the solver's bound (checked at the neutral posture) and refused
  beyond it, with the joint named: about 3e-4 N·m·s/rad on the DIP joints at 1 kHz.
- Joint limits (the movement ranges of config/model.yaml, `Joint.lower/upper`) are a
  spring-damper acting only beyond the range. Its stiffness is not one number in N·m/rad
  (a spring stiff enough for the elbow would make the DIP joint unstable, one soft enough
  for the DIP would let the elbow sink through): each joint's spring has the natural
  frequency LIMIT_FREQUENCY_HZ = 50 Hz on the joint's effective inertia 1/(M⁻¹)_jj at the
  neutral posture, k_j = (2π·50)² / (M⁻¹)_jj, with damping ratio LIMIT_DAMPING_RATIO = 0.3,
  c_j = 2·0.3·(2π·50) / (M⁻¹)_jj. For the 50th-percentile man: elbow 4188 N·m/rad (its
  3.3 N·m of gravity push it 0.8 mrad past a limit), wrist flexion 257, DIP joints
  0.013-0.023 N·m/rad. With every joint in its limit at once the coupled system has
  dt·√λ_max(M⁻¹K) = 0.85 and dt·λ_max(M⁻¹C) = 1.38 (5th-percentile man, upper limits):
  inside both solvers' stability regions; with damping ratio 0.7 it was 3.2 and RK4 blew up
  (test_simulation.test_limits_stable_with_every_joint_pushed_out). `limit_gains` gives
  the numbers for any model; `ArmSimulator.describe()` states them.
  The limit torque never pulls the joint into the limit (a leaving joint is not held back:
  the damper only brakes, it does not stick).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..dynamics import ArmModel

DEFAULT_DAMPING = 1e-7  # N·m·s/rad, every joint (see the module docstring)
LIMIT_FREQUENCY_HZ = 50.0  # Hz, natural frequency of every joint's limit spring
LIMIT_DAMPING_RATIO = 0.3
#: Real-axis stability bound of dt·λ for each method (RK4: 2.785; semi-implicit Euler: 2),
#: and the fraction of it accepted at the neutral posture (the mass matrix changes with q).
STABILITY_BOUND = {"rk4": 2.785, "semi_implicit_euler": 2.0}
STABILITY_MARGIN = 0.75


def neutral_posture(arm: ArmModel) -> np.ndarray:
    """Mid-range of every joint (rad), joint_names order."""
    return 0.5 * (joint_bounds(arm)[0] + joint_bounds(arm)[1])


def joint_bounds(arm: ArmModel) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of every joint in rad: the movement ranges the model was built with."""
    lo = np.array([j.lower for j in arm.tree.joints], dtype=float)
    hi = np.array([j.upper for j in arm.tree.joints], dtype=float)
    return lo, hi


def mass_matrix(arm: ArmModel, q: np.ndarray) -> np.ndarray:
    """The joint-space mass matrix M(q) (kg·m²), symmetric."""
    data = arm.model.createData()
    m = pin.crba(arm.model, data, np.asarray(q, dtype=float))
    return np.triu(m) + np.triu(m, 1).T


def effective_inertia(arm: ArmModel, q=None) -> np.ndarray:
    """1/(M⁻¹)_jj (kg·m²): the inertia joint j's own torque sees when the others move freely
    (default posture: neutral). What a spring or a PD gain on joint j must be scaled by."""
    q = neutral_posture(arm) if q is None else q
    return 1.0 / np.diag(np.linalg.inv(mass_matrix(arm, q)))


def limit_gains(arm: ArmModel, frequency_hz: float = LIMIT_FREQUENCY_HZ,
                damping_ratio: float = LIMIT_DAMPING_RATIO) -> tuple[np.ndarray, np.ndarray]:
    """(stiffness N·m/rad, damping N·m·s/rad) of each joint's limit spring-damper."""
    m = effective_inertia(arm)
    w = 2.0 * math.pi * frequency_hz
    return w * w * m, 2.0 * damping_ratio * w * m


def damping_vector(arm: ArmModel, damping: float | Mapping[str, float] | np.ndarray) -> np.ndarray:
    """Per-joint viscous damping (N·m·s/rad) from one number, a {joint: c} mapping (joints
    not named get DEFAULT_DAMPING; key "*" sets every joint first) or an (nv,) array."""
    names = arm.joint_names
    if isinstance(damping, Mapping):
        base = float(damping.get("*", DEFAULT_DAMPING))
        out = np.full(len(names), base)
        unknown = sorted(set(damping) - set(names) - {"*"})
        if unknown:
            raise ValueError(f"damping names unknown joint(s) {unknown}; joints: {', '.join(names)}")
        for k, c in damping.items():
            if k != "*":
                out[names.index(k)] = float(c)
    else:
        out = np.broadcast_to(np.asarray(damping, dtype=float), (len(names),)).copy()
    bad = [names[i] for i in np.flatnonzero(~np.isfinite(out) | (out < 0.0))]
    if bad:
        raise ValueError(f"damping must be finite and >= 0 N·m·s/rad; not so for {', '.join(bad)}")
    return out


def check_stability(arm: ArmModel, damping: np.ndarray, dt: float, method: str) -> None:
    """Refuse damping the explicit solver would blow up on (ValueError naming the joint)."""
    if not np.any(damping):
        return
    minv = np.linalg.inv(mass_matrix(arm, neutral_posture(arm)))
    # M⁻¹C is similar to the symmetric C^½ M⁻¹ C^½: real, non-negative eigenvalues.
    s = np.sqrt(damping)
    lam = float(np.linalg.eigvalsh(s[:, None] * minv * s[None, :]).max())
    limit = STABILITY_MARGIN * STABILITY_BOUND[method]
    if lam * dt > limit:
        worst = int(np.argmax(damping * np.diag(minv)))
        c_max = limit / (dt * float(np.diag(minv)[worst]))
        raise ValueError(
            f"damping too large for {method} at dt={dt:g} s: dt*lambda_max(M^-1 C) = {lam * dt:.3g} "
            f"> {limit:.3g}; the stiffest joint is {arm.joint_names[worst]} "
            f"(damping {damping[worst]:.3g}, about {c_max:.2g} N·m·s/rad is stable there)")


@dataclass(frozen=True)
class PassiveJoints:
    """Damping and limit torques, evaluated without allocation per call but the result."""

    damping: np.ndarray  # (nv,) N·m·s/rad
    lower: np.ndarray  # (nv,) rad
    upper: np.ndarray
    limit_stiffness: np.ndarray | None  # (nv,) N·m/rad; None = no limits
    limit_damping: np.ndarray | None

    def __post_init__(self):
        object.__setattr__(self, "_neg_damping", -self.damping)

    def torque(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """-c·qd, plus beyond a limit -k·(q - limit) - c_l·qd, never pulling into the limit.

        Called at every solver stage (4 per RK4 step), so the common case (no joint beyond
        its range) is three numpy calls: the penetration is q - clip(q, lower, upper)."""
        tau = self._neg_damping * qd
        if self.limit_stiffness is None:
            return tau
        pen = q - np.clip(q, self.lower, self.upper)
        if pen.any():
            lim = -self.limit_stiffness * pen - self.limit_damping * qd * (pen != 0.0)
            # pushing out of the limit only: sign opposite to the penetration (or zero)
            lim = np.where(pen > 0.0, np.minimum(lim, 0.0), np.maximum(lim, 0.0))
            tau += lim
        return tau


def make_passive(arm: ArmModel, damping, joint_limits: bool) -> PassiveJoints:
    lo, hi = joint_bounds(arm)
    k = c = None
    if joint_limits:
        k, c = limit_gains(arm)
    return PassiveJoints(damping_vector(arm, damping), lo, hi, k, c)


__all__ = ["DEFAULT_DAMPING", "LIMIT_DAMPING_RATIO", "LIMIT_FREQUENCY_HZ", "PassiveJoints",
           "check_stability", "damping_vector", "effective_inertia", "joint_bounds",
           "limit_gains", "make_passive", "mass_matrix", "neutral_posture"]
