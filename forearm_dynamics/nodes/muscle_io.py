"""muscle_node's bytes: (q, q̇, τ) read from a joint_torques message in one numpy call, and
muscle_forces / muscle_reserves written into CDR templates, never as Python messages.

Why a module of its own: it is the node's per-sample encoding (the callback's other half is
the muscle model and the QP), kept apart from the ROS plumbing and the status reporting so each
can be read and tested alone. It adds no codec: it reuses codec/jointstate_cdr.py (the parser,
verified against rclpy's deserialiser once per shape; OutputTemplate and StdTemplate made by
rclpy's serialiser), as torque_node does.

Input: a known shape's bytes are copied into the plan's aligned buffer (input_plans.py); every
float64 field of a CDR JointState sits at an offset = 4 (mod 8) from the buffer's start (8-aligned
from the payload), so one float64 view of the buffer from byte 4 covers position, velocity and
effort, and one `take` with a combined index writes the model's (3, 20) state. The three takes
and three finiteness sums this replaces were ~10 % of the node's own time (measured in process:
`python -m benchmarks.muscle_node --sections callback`).
Output: one OutputTemplate (names = muscles) and one StdTemplate (names = joints) per frame_id,
at most std_output.CACHE of them (std_output.PerFrame, the oldest dropped first).
"""

from __future__ import annotations

import numpy as np

from ..codec.jointstate_cdr import OutputTemplate, StdTemplate
from . import validation as v
from .std_output import PerFrame

NO_EFFORT = "no_effort"  # a JointState without torques (not a torque node's output)
NO_VELOCITY = "no_velocity"
READERS = 16  # input shapes (as InputPlans keeps)
_F64 = 8
_PAYLOAD = 4


class StateReader:
    """(q, q̇, τ) of input plans, one `take` per message; a shape without efforts or
    velocities carries its Rejection (every message of it refused without looking again)."""

    def __init__(self, input_topic: str, n_joints: int):
        self.state = np.zeros((3, n_joints))  # rows: q, q̇, τ (model joint order)
        self._flat = self.state.reshape(-1)
        self._topic = input_topic
        self._readers: dict[int, tuple[object, tuple[np.ndarray, np.ndarray] | v.Rejection]] = {}

    def read(self, plan) -> None:
        """Fill `state` from the bytes just copied into plan.buf (Rejection if the shape lacks
        efforts or velocities)."""
        hit = self._readers.get(id(plan))
        if hit is None or hit[0] is not plan:  # a plan dropped and its id reused: not ours
            if len(self._readers) >= READERS:
                self._readers.pop(next(iter(self._readers)))
            hit = self._readers[id(plan)] = (plan, self._reader(plan))
        r = hit[1]
        if isinstance(r, v.Rejection):
            raise r
        view, index = r
        view.take(index, out=self._flat)

    def _reader(self, plan) -> tuple[np.ndarray, np.ndarray] | v.Rejection:
        lay = plan.layout
        n = len(lay.names)
        if lay.n_eff != n:
            return v.Rejection(NO_EFFORT, f"{self._topic}: {lay.n_eff} efforts for {n} names: not "
                               "joint torques (the torque node's output)")
        if lay.n_vel != n:
            return v.Rejection(NO_VELOCITY, f"{self._topic}: no velocities (the muscles' "
                               "force-velocity needs them)")
        # n > 0 here (match_fields refused empty names), so parse_layout 8-aligned all three
        offs = (lay.pos_off, lay.vel_off, lay.eff_off)
        view = np.frombuffer(plan.buf, dtype=np.float64, count=(lay.size - _PAYLOAD) // _F64,
                             offset=_PAYLOAD)
        index = np.concatenate([(o - _PAYLOAD) // _F64 + plan.index for o in offs])
        return view, index


class OutputTemplates(PerFrame):
    """Per frame_id: (muscle_forces template, muscle_reserves template)."""

    def __init__(self, muscle_names, joint_names):
        self.muscle_names = tuple(muscle_names)
        self.joint_names = tuple(joint_names)
        super().__init__(lambda frame: (OutputTemplate(self.muscle_names, frame),
                                        StdTemplate(self.joint_names, frame)))

    def rename(self, muscle_names) -> None:
        """A rebuilt model: templates of other muscle names are dropped."""
        if tuple(muscle_names) != self.muscle_names:
            self.muscle_names = tuple(muscle_names)
            self.clear()
