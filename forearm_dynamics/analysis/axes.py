"""The two readings of "the joint torque was measured about an axis parallel to the ulna".

- **generalised** (the headline): the generalised force of MoBL's pro_sup coordinate, i.e.
  the moment the radioulnar joint transmits, about MoBL's own (oblique) pro/sup axis. It is
  the only component an actuator (the pronator and supinator muscles, or a prosthesis
  motor) must produce: the other components of the joint wrench are carried by the joint's
  constraint (bone contact, interosseous membrane, ligaments) and do no work on pro/sup
  motion, so no muscle has to supply them. It is also what the simplified models output
  (their generalised force about their own axis), so the comparison is like for like.
- **ulna_axis**: the whole wrench the ulna transmits to the radius (actuated + constraint
  moments) as a moment about the line through the radioulnar joint origin (on MoBL's pro/sup
  axis) parallel to the ulna's long axis (the ulna frame's y axis, 6.94 deg from MoBL's
  pro/sup axis): the paper's wording, "about an axis parallel to the ulna segment", read
  literally. It mixes in constraint moment (perpendicular to the pro/sup axis) that no
  actuator produces, and unlike a generalised force it depends on which parallel line is
  taken: through="ulna_origin" (the elbow centre, on the ulna itself) gives another answer,
  reported beside it.

The wrench is Pinocchio's (data.f after rnea: the spatial force transmitted by each joint),
from the anatomical model that equals the OpenSim reference to 1e-11 N·m; its projection on
the pro/sup axis is the generalised force again (checked and reported).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..anthropometry import resolve_body_size
from ..builders import build_tree
from ..description import JOINT_NAMES, load_description
from ..dynamics import ArmModel

READINGS = ("generalised", "ulna_axis")
PRO_SUP = JOINT_NAMES.index("pro_sup")
LINES = ("radioulnar_origin", "ulna_origin")  # the point the ulna-parallel line runs through
ULNA_LONG_AXIS = np.array([0.0, 1.0, 0.0])  # ulna frame; MoBL's ulna frame y runs along the bone


def ulna_axis_torques(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, body_size=50,
                      desc=None, through: str = "radioulnar_origin") -> tuple[np.ndarray, float]:
    """(N, 20) anatomical torques with the pro/sup column replaced by the joint wrench's
    moment about the ulna's long axis; and max |wrench . pro/sup axis - generalised force|."""
    if through not in LINES:
        raise ValueError(f"through must be one of {LINES}, got {through!r}")
    desc = desc or load_description()
    m = ArmModel(build_tree("anatomical", desc, resolve_body_size(body_size)))
    model, data = m.model, m.data
    jid = model.getJointId("pro_sup")
    parent = model.parents[jid]
    axis_local = np.asarray(desc.anatomical.radioulnar_axis, float)
    axis_local = axis_local / np.linalg.norm(axis_local)
    out = np.empty((q.shape[0], 20))
    worst = 0.0
    for k in range(q.shape[0]):
        tau = pin.rnea(model, data, q[k], qd[k], qdd[k])
        pin.forwardKinematics(model, data, q[k])
        r_joint = data.oMi[jid].rotation
        moment = r_joint @ data.f[jid].angular  # world axes, about the radioulnar origin
        r_parent = data.oMi[parent].rotation
        worst = max(worst, abs(moment @ (r_parent @ axis_local) - tau[PRO_SUP]))
        if through == "ulna_origin":  # move the moment to the elbow centre (ulna frame origin)
            lever = data.oMi[jid].translation - data.oMi[parent].translation
            moment = moment + np.cross(lever, r_joint @ data.f[jid].linear)
        out[k] = tau
        out[k, PRO_SUP] = moment @ (r_parent @ ULNA_LONG_AXIS)
    return out, worst


def axis_angle_deg(desc=None) -> float:
    desc = desc or load_description()
    a = np.asarray(desc.anatomical.radioulnar_axis, float)
    return float(np.degrees(np.arccos(abs(a @ ULNA_LONG_AXIS) / np.linalg.norm(a))))
