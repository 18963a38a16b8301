"""joint_torques_std: the σ of every joint_torques message, as raw JointState CDR bytes.

Same header (stamp, frame_id) and names as the joint_torques message it belongs to;
position and velocity empty, effort = one standard deviation (N·m) of each torque
(forearm_dynamics/uncertainty, docs/uncertainty.md). Built like the torque output
(jointstate_cdr): the bytes are serialised once per frame_id by rclpy, the layout verified,
and per sample only the stamp and the effort view are written.
"""

from __future__ import annotations

import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from ..codec.jointstate_cdr import STAMP, NotMine, aligned_buffer, verified_layout

CACHE = 8  # templates, one per frame_id (as the torque output's)


class StdTemplate:
    """CDR bytes of a JointState with names and effort only; `effort` a writable view."""

    def __init__(self, joint_names, frame_id: str = ""):
        n = len(joint_names)
        msg = JointState()
        msg.header.frame_id = frame_id
        msg.name = list(joint_names)
        msg.effort = [float(i + 1) for i in range(n)]
        raw = serialize_message(msg)
        lay = verified_layout(raw)
        if lay.names != tuple(joint_names) or lay.n_pos or lay.n_vel or lay.n_eff != n:
            raise NotMine("std template does not hold the joint names")
        self.buf = aligned_buffer(lay.size)
        memoryview(self.buf)[:] = lay.zero_padding(raw)
        self.effort = lay.array(self.buf, "effort")
        self.effort.fill(0.0)
        self._pack = STAMP.pack_into

    def fill(self, sec: int, nsec: int, std: np.ndarray) -> bytes:
        self._pack(self.buf, 4, sec, nsec)
        np.copyto(self.effort, std)
        return self.buf.tobytes()


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
