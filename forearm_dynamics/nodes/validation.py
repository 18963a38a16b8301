"""Input checks for joint_states: why a sample is dropped, and the cached name -> index map.

A rejected sample is dropped, counted under its reason and warned about (rate-limited);
the node keeps running and the next good sample is processed normally.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# Rejection reasons (keys of the /diagnostics counters).
EMPTY = "empty"  # no names at all
MISSING_JOINT = "missing_joint"  # a model joint is not in the message
DUPLICATE_NAME = "duplicate_name"
LENGTH_MISMATCH = "length_mismatch"  # position != names, or velocity neither empty nor names
NON_FINITE = "non_finite"  # NaN/inf in a position or velocity the model uses
STAMP_MISSING = "stamp_missing"  # header.stamp is zero: nothing to differentiate against
STAMP_NOT_INCREASING = "stamp_not_increasing"  # equal to or (slightly) before the last one
NON_FINITE_TORQUE = "non_finite_torque"  # finite inputs but absurd values overflowed

REASONS = (
    EMPTY,
    MISSING_JOINT,
    DUPLICATE_NAME,
    LENGTH_MISMATCH,
    NON_FINITE,
    STAMP_MISSING,
    STAMP_NOT_INCREASING,
    NON_FINITE_TORQUE,
)


class Rejection(Exception):
    """A sample the node drops; `reason` is one of REASONS."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class NameMatch:
    """Where each model joint sits in a message's name list, or why the list is refused."""

    index: np.ndarray | None  # (nv,) intp, model joint i -> message slot index[i]
    rejection: Rejection | None


class NameMatcher:
    """Name list -> index map, cached per distinct list so the steady state costs one compare."""

    def __init__(self, joint_names: Sequence[str], cache_size: int = 16):
        self.joint_names = tuple(joint_names)
        self._cache: OrderedDict[tuple[str, ...], NameMatch] = OrderedDict()
        self._cache_size = cache_size
        self._last_names: list[str] | None = None
        self._last: NameMatch | None = None

    def match(self, names: list[str]) -> np.ndarray:
        """Index array for `names`, or raise Rejection."""
        if names != self._last_names:
            key = tuple(names)
            found = self._cache.get(key)
            if found is None:
                found = self._build(key)
                self._cache[key] = found
                if len(self._cache) > self._cache_size:
                    self._cache.popitem(last=False)
            self._last_names, self._last = list(names), found
        m = self._last
        if m.rejection is not None:
            raise m.rejection
        return m.index

    def _build(self, names: tuple[str, ...]) -> NameMatch:
        if not names:
            return NameMatch(None, Rejection(EMPTY, "message has no joint names"))
        slots: dict[str, int] = {}
        dups = []
        for i, n in enumerate(names):
            if n in slots:
                dups.append(n)
            slots[n] = i
        if dups:
            return NameMatch(None, Rejection(DUPLICATE_NAME, f"names repeated: {sorted(set(dups))}"))
        missing = [n for n in self.joint_names if n not in slots]
        if missing:
            return NameMatch(None, Rejection(
                MISSING_JOINT, f"{len(missing)} model joint(s) missing: {missing[:5]}"
                + (" ..." if len(missing) > 5 else "")
            ))
        index = np.array([slots[n] for n in self.joint_names], dtype=np.intp)
        return NameMatch(index, None)

    def nonfinite_detail(self, field: str, values: np.ndarray) -> str:
        """Which joints hold NaN/inf (slow path, only for the warning text)."""
        bad = [self.joint_names[i] for i in np.flatnonzero(~np.isfinite(values))]
        return f"{field} of {bad[:5]}" + (" ..." if len(bad) > 5 else "") if bad else field
