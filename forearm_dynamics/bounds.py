"""The largest joint torque a human-speed movement can give, per DOF group, from the model.

Why: check_bag without markers compares the recorded torques with a reference computed
from the same angles, so wrong angles (units) or an estimator amplifying noise pass it.
A bound from physics does not depend on that reference. For a joint j,

    tau_j = g-term_j(q) + sum_k M_jk(q) qdd_k + c_j(q, qd)

and over a human-speed movement (the ASSUMPTION, stated: every joint at most OMEGA_MAX
rad/s and ALPHA_MAX rad/s^2, fast voluntary movement: peak elbow speeds in fast reaching
are ~10 rad/s, finger tapping ~15-20 rad/s) each term is bounded per posture:
- gravity in ANY direction (a moving humerus turns it): |g| |v_j| where v_j is the gravity
  torque per unit gravity along x, y, z (three RNEA calls: it is linear in g);
- inertia: ALPHA_MAX sum_k |M_jk| (the worst signs of qdd);
- velocity product: the largest |c_j| over corners of the speed box (sampled).
The bound is the largest sum over postures sampled uniformly within the joints' ranges
(seeded, so the number is reproducible), times MARGIN for the postures not sampled.
A DOF group's bound is the largest of its joints'.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pinocchio as pin

#: the human-speed assumption (see the module docstring)
OMEGA_MAX = 15.0  # rad/s (860 deg/s)
ALPHA_MAX = 500.0  # rad/s^2
#: postures sampled, speed corners per posture, margin for what sampling misses
POSTURES = 400
CORNERS = 8
MARGIN = 1.25

GROUPS = {"elbow": ("elbow_flexion",), "pro_sup": ("pro_sup",),
          "wrist": ("wrist_flexion", "wrist_deviation"), "thumb": ("thumb_",), "fingers": ("index_",
          "middle_", "ring_", "little_")}


def group_of(joint: str) -> str:
    for g, keys in GROUPS.items():
        if any(joint == k or (k.endswith("_") and joint.startswith(k)) for k in keys):
            return g
    return joint


@dataclass(frozen=True)
class TorqueBounds:
    joint_names: tuple[str, ...]
    per_joint: np.ndarray  # (J,) N·m
    per_group: dict[str, float]  # N·m
    assumption: str

    def of(self, joint: str) -> float:
        return self.per_group[group_of(joint)]


def torque_bounds(arm) -> TorqueBounds:
    """The bound for an ArmModel (cached per model description: kind, size, side, payload)."""
    return _bounds(arm.model, arm.joint_names, repr(arm), _limits(arm))


def _limits(arm) -> tuple[tuple[float, ...], tuple[float, ...]]:
    m = arm.model
    return tuple(m.lowerPositionLimit.tolist()), tuple(m.upperPositionLimit.tolist())


@lru_cache(maxsize=8)
def _bounds(model: pin.Model, names: tuple[str, ...], key: str, limits) -> TorqueBounds:
    del key  # the cache key only
    model = pin.Model(model)
    data = model.createData()
    g = float(np.linalg.norm(model.gravity.linear))
    lo, hi = (np.array(x) for x in limits)
    rng = np.random.default_rng(30)
    nv = model.nv
    z = np.zeros(nv)
    best = np.zeros(nv)
    for _ in range(POSTURES):
        q = rng.uniform(lo, hi)
        v = np.empty((3, nv))
        for a in range(3):
            model.gravity = pin.Motion(np.eye(3)[a], np.zeros(3))
            v[a] = pin.rnea(model, data, q, z, z)
        grav = g * np.linalg.norm(v, axis=0)
        model.gravity = pin.Motion(np.zeros(3), np.zeros(3))
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        inertia = ALPHA_MAX * np.abs(mass).sum(axis=1)
        c = np.zeros(nv)
        for _k in range(CORNERS):
            qd = OMEGA_MAX * rng.choice((-1.0, 1.0), nv)
            c = np.maximum(c, np.abs(pin.rnea(model, data, q, qd, z)))
        np.maximum(best, grav + inertia + c, out=best)
    per_joint = MARGIN * best
    groups: dict[str, float] = {}
    for n, b in zip(names, per_joint, strict=True):
        groups[group_of(n)] = max(groups.get(group_of(n), 0.0), float(b))
    text = (f"human speed: |qd| <= {OMEGA_MAX:g} rad/s, |qdd| <= {ALPHA_MAX:g} rad/s^2 per joint, "
            f"gravity in any direction; max over {POSTURES} postures in range x {MARGIN:g}")
    return TorqueBounds(names, per_joint, groups, text)
