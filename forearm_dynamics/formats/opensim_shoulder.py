"""The shoulder columns of an OpenSim motion: MoBL-ARMS or full-body angles, found by name.

Kept apart from opensim.py's coordinate map (which maps the 20 joints one column each): the
shoulder is three columns that together turn the humerus, in the sequence of the model
they come from (forearm_dynamics/shoulder.py), so they are found as a set: all three of
one convention and side, or none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import MotionError
from ..shoulder import CONVENTIONS
from .opensim import Motion


@dataclass(frozen=True)
class ShoulderColumns:
    """A motion's shoulder angles (rad), in the convention's public order."""

    convention: str
    names: tuple[str, ...]  # public names (shoulder.CONVENTIONS[...].joint_names)
    columns: tuple[str, ...]  # the file's column labels they came from
    q: np.ndarray  # (N, 3) rad


def _coordinate(label: str) -> str | None:
    """The coordinate a column holds the value of (motion label or states path)."""
    if not label.startswith("/"):
        return label
    parts = [p for p in label.split("/") if p]
    return parts[-2] if len(parts) >= 2 and parts[-1] == "value" else None


def shoulder_columns(m: Motion, side: str = "right") -> tuple[ShoulderColumns | None, str]:
    """The shoulder angles of `m` for the `side` arm (None when the file has no complete set)
    and a note for the user ('' when there is nothing to say).

    A file giving only some of one convention's three angles keeps the humerus welded (the
    note says which are missing); two complete sets are a MotionError naming them.
    """
    scale = math.pi / 180.0 if m.in_degrees else 1.0
    where = {_coordinate(lab): c for c, lab in enumerate(m.labels)}
    found = []
    for conv in CONVENTIONS.values():
        for cols in (conv.joint_names, conv.aliases[side]):
            hit = [n for n in cols if n in where]
            if hit:
                found.append((conv, cols, hit))
    if not found:
        return None, ""
    complete = [(conv, cols) for conv, cols, hit in found if len(hit) == 3]
    if not complete:
        conv, cols, hit = found[0]
        missing = [n for n in cols if n not in hit]
        return None, (f"shoulder ({conv.name}): {', '.join(hit)} without {', '.join(missing)}: the "
                      "humerus' orientation needs all three; it stays welded (vertical, still)")
    if len(complete) > 1:
        raise MotionError(f"{m.path}: two sets of shoulder columns "
                          f"({', '.join(str(list(c)) for _, c in complete)}): give one")
    conv, cols = complete[0]
    idx = [where[n] for n in cols]
    return ShoulderColumns(conv.name, conv.joint_names, tuple(m.labels[i] for i in idx),
                           m.data[:, idx] * scale), ""


__all__ = ["ShoulderColumns", "shoulder_columns"]
