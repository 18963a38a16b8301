"""joint_torques_std's templates per frame_id: the σ of every joint_torques message, as raw
JointState CDR bytes with the same header (stamp, frame_id) and names; position and velocity
empty, effort = one standard deviation (N·m) of each torque (forearm_dynamics/uncertainty,
docs/uncertainty.md). Serialised once per frame_id by rclpy (jointstate_cdr.StdTemplate);
per sample only the stamp and the effort are written.
"""

from __future__ import annotations

from ..codec.jointstate_cdr import StdTemplate

CACHE = 8  # templates, one per frame_id (as the torque output's)


class StdTemplates:
    """One StdTemplate per frame_id (bytes key, as the torque output's templates)."""

    def __init__(self, joint_names):
        self.joint_names = tuple(joint_names)
        self._by_frame: dict[bytes, StdTemplate] = {}

    def get(self, frame_id: bytes) -> StdTemplate:
        t = self._by_frame.get(frame_id)
        if t is None:
            if len(self._by_frame) >= CACHE:
                self._by_frame.pop(next(iter(self._by_frame)))
            t = StdTemplate(self.joint_names, frame_id.decode("utf-8"))
            self._by_frame[frame_id] = t
        return t
