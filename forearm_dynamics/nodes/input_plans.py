"""What a stream node does with input bytes of each shape, found once per shape.

A JointState's shape (frame_id, names, field counts, hence every offset) is parsed by the
hand-written CDR parser (codec/jointstate_cdr.py) and checked against rclpy's deserialiser
once; after that a message of that shape is read through numpy views at fixed offsets.
Shapes the parser cannot vouch for go the generic way (rclpy's deserialiser), and a shape
whose names or counts are wrong carries its Rejection, so every such message is refused
without parsing it again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..codec.jointstate_cdr import Layout, NotMine, aligned_buffer, parse_layout, verify_layout
from . import validation as v

PLAN_CACHE = 16  # shapes (like NameMatcher's name lists); oldest dropped first


@dataclass(frozen=True)
class InputPlan:
    """What the node does with input bytes of one shape (cached per shape).

    layout None: the generic path (rclpy's deserialiser, then the node's `_ingest`).
    Otherwise `buf` receives a copy of each message and `pos`/`vel` are views on it; `index`
    maps model joints to message slots, or `rejection` says why every message of this shape
    is dropped.
    """

    layout: Layout | None
    buf: memoryview | None = None  # of an aligned_buffer
    pos: np.ndarray | None = None
    vel: np.ndarray | None = None  # None: no velocities in the message
    index: np.ndarray | None = None
    rejection: v.Rejection | None = None
    held: np.ndarray | None = None  # model joints this shape lacks, held (missing_joints: hold)


GENERIC = InputPlan(None)


class InputPlans:
    """The plans of the last PLAN_CACHE shapes seen, and the shapes the parser got wrong."""

    def __init__(self, names: v.NameMatcher):
        self._names = names
        self._plans: list[InputPlan] = []  # known shapes, newest last
        self._refused: list[Layout] = []  # shapes the parser got wrong: generic path

    def find(self, data: bytes) -> InputPlan:
        """The plan for this message's shape: a cached one, a new one, or GENERIC."""
        for plan in reversed(self._plans):
            if plan.layout.matches(data):
                return plan
        try:
            lay = parse_layout(data, max_names=v.MAX_NAMES)
        except NotMine:
            return GENERIC  # not little-endian plain CDR, or not a JointState
        if any(r.matches(data) for r in self._refused):
            return GENERIC
        try:
            verify_layout(lay, data)
        except Exception:  # noqa: BLE001 - NotMine, or bytes rclpy cannot read either
            self._refused = [*self._refused[-(PLAN_CACHE - 1):], lay]
            return GENERIC
        plan = self._make(lay)
        self._plans = [*self._plans[-(PLAN_CACHE - 1):], plan]
        return plan

    def _make(self, lay: Layout) -> InputPlan:
        try:
            index = v.match_fields(self._names, list(lay.names), lay.n_pos, lay.n_vel, lay.n_eff)
        except v.Rejection as r:
            return InputPlan(lay, rejection=r)
        buf = aligned_buffer(lay.size)
        return InputPlan(lay, buf=memoryview(buf), pos=lay.array(buf, "position"),
                         vel=lay.array(buf, "velocity") if lay.n_vel else None, index=index,
                         held=self._names.held)
