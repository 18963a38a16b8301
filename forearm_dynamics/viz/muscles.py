"""The forearm's strongest muscle, from muscle_node's `muscle_forces` (issue 31: "arm_viz may
colour the forearm by its strongest muscle"), without ROS.

`muscle_forces` is a sensor_msgs/JointState: name = the muscles, position = activation
(0..1). The strongest is the forearm muscle with the highest activation: a muscle that
crosses the elbow, pro/sup or the wrist in the shipped model (its `spans`; 36 of the 48:
the hand's intrinsic muscles RI, LU_RB, UI_UB and OP are not forearm muscles), or any
muscle the shipped model does not name (a user's own model: muscle_node's `muscle_model`).
arm_viz draws it only beside torques of about the same time (MAX_SKEW_NS): a muscle node
that stopped or fell behind leaves the forearm in its torque colours, not in stale ones.
"""

from __future__ import annotations

import json
from functools import lru_cache

import numpy as np

FOREARM_JOINTS = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
#: muscle_forces farther than this from the drawn torques' stamp are not drawn (0.5 s)
MAX_SKEW_NS = 500_000_000


@lru_cache(maxsize=1)
def shipped_hand_muscles() -> frozenset[str]:
    """The shipped model's muscles that cross none of FOREARM_JOINTS (the hand's own)."""
    from ..muscles.model import DEFAULT_FILE

    doc = json.loads(DEFAULT_FILE.read_text(encoding="utf-8"))
    return frozenset(m["name"] for m in doc["muscles"]
                     if not set(m["spans"]) & set(FOREARM_JOINTS))


def strongest(names, activations, exclude: frozenset[str] | None = None
              ) -> tuple[str, float] | None:
    """(name, activation clipped to 0..1) of the most activated muscle not in exclude (the
    shipped model's hand muscles by default), or None if there is none with a finite
    activation."""
    exclude = shipped_hand_muscles() if exclude is None else exclude
    a = np.asarray(activations, float)
    if len(a) != len(names):
        raise ValueError(f"muscle_forces carries {len(names)} names and {len(a)} activations")
    cols = [i for i, n in enumerate(names) if n not in exclude]
    sub = a[cols] if cols else a[:0]
    if not np.isfinite(sub).any():
        return None
    k = int(np.nanargmax(np.where(np.isfinite(sub), sub, np.nan)))
    return names[cols[k]], float(np.clip(sub[k], 0.0, 1.0))
