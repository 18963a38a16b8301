"""joint_torques_std's templates per frame_id: the σ of every joint_torques message, as raw
JointState CDR bytes with the same header (stamp, frame_id) and names; position and velocity
empty, effort = one standard deviation (N·m) of each torque (forearm_dynamics/uncertainty,
docs/uncertainty.md). Serialised once per frame_id by rclpy (jointstate_cdr.StdTemplate);
per sample only the stamp and the effort are written.
"""

from __future__ import annotations

from ..codec.jointstate_cdr import StdTemplate

CACHE = 8  # templates, one per frame_id: at most this many kept (the oldest dropped first)


class PerFrame:
    """Templates made once per frame_id (bytes key) by `make(frame_id: str)`, at most CACHE of
    them, the oldest dropped first: the one bounded cache of every node's output templates
    (torque_node's joint_torques and joint_torques_std, muscle_node's two outputs)."""

    def __init__(self, make):
        self._make = make
        self._by_frame: dict[bytes, object] = {}

    def get(self, frame_id: bytes):
        t = self._by_frame.get(frame_id)
        if t is None:
            if len(self._by_frame) >= CACHE:
                self._by_frame.pop(next(iter(self._by_frame)))
            t = self._by_frame[frame_id] = self._make(frame_id.decode("utf-8"))
        return t

    def clear(self) -> None:
        self._by_frame.clear()


class StdTemplates(PerFrame):
    """One StdTemplate per frame_id (as the torque output's templates)."""

    def __init__(self, joint_names):
        self.joint_names = tuple(joint_names)
        super().__init__(lambda frame: StdTemplate(self.joint_names, frame))
