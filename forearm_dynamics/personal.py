"""One person's arm from the generic right arm: the side, and an object held in the hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .payload import Payload
from .tree import SIDES, KinematicTree, Link, mirror_tree, weld


def check_side(side) -> str:
    """"right" or "left" (any case, spaces ignored); anything else is a ValueError."""
    s = side.strip().lower() if isinstance(side, str) else side
    if s not in SIDES:
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    return s


def personalise(tree: KinematicTree, side: str, payload: Payload | None) -> KinematicTree:
    """Weld the payload to the right carpus (hand frame = carpus frame), then mirror if left.

    Welding before mirroring is what makes the payload's numbers side-independent: the
    user's (x toward the thumb, y toward the elbow, z dorsal) are mirrored with the hand.
    """
    if tree.side != "right":
        raise ValueError("personalise starts from the right arm the builders make")
    if payload is not None:
        body = Link("payload", payload.mass, np.zeros(3), payload.inertia.copy(), "object")
        tree = weld(tree, "payload_weld", "carpus", payload.com, body)
        tree = replace(tree, payload=payload)
    return mirror_tree(tree) if check_side(side) == "left" else tree


__all__ = ["check_side", "personalise"]
