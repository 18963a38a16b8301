"""Input checks for joint_states: why a sample is dropped, and the cached name -> index map.

A rejected sample is dropped, counted under its reason and warned about (rate-limited);
the node keeps running and the next good sample is processed normally.

Stamp jumps (stream_node.py) are judged against this node's system clock only in the rare
branch where a sample jumps by more than max_stamp_gap (or is the first one):
- more than FUTURE_TOLERANCE_S ahead of the clock -> rejected (stamp_in_future): a corrupt
  stamp or unsynchronised clocks, never a pause. Rejected samples do not become the
  reference, so the good stream continues with its history intact.
- a jump back while the previous sample was live (its stamp within LIVE_WINDOW_S of the
  clock) to a stamp older than LIVE_WINDOW_S -> rejected (stamp_not_increasing): a live
  source cannot go back in time. A replayed source (stamps older than that) jumping back
  is a restart (bag loop): accepted, estimator reset. Nothing here can lock a stream out:
  a sample is only refused against a reference that is itself close to the clock.
"""

from __future__ import annotations

import time
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
TOO_MANY_NAMES = "too_many_names"  # more than MAX_NAMES names (bounded work and memory)
STAMP_INVALID = "stamp_invalid"  # negative, or nanosec outside [0, 1e9)
STAMP_IN_FUTURE = "stamp_in_future"  # more than FUTURE_TOLERANCE_S ahead of this node's clock
NO_IMU = "no_imu"  # the shoulder comes from an Imu (imu_topic) and none has arrived yet
#: a position far outside its joint's range (forearm_dynamics/ranges.py): degrees as radians
ANGLE_OUT_OF_RANGE = "angle_out_of_range"

#: Names a message may carry (the model's 20 and others, ignored). A real robot has tens;
#: the limit bounds the per-message work and the name-list cache (16 lists) at ~1 MB.
MAX_NAMES = 1024
#: A stamp this far ahead of the node's system clock is refused (see the module docstring).
#: Generous, so that two machines' clocks a little apart never lock a stream out.
FUTURE_TOLERANCE_S = 60.0
#: A previous stamp within this of the clock marks the stream as live (see the docstring).
LIVE_WINDOW_S = 1.0

REASONS = (
    EMPTY,
    MISSING_JOINT,
    DUPLICATE_NAME,
    LENGTH_MISMATCH,
    NON_FINITE,
    STAMP_MISSING,
    STAMP_NOT_INCREASING,
    NON_FINITE_TORQUE,
    TOO_MANY_NAMES,
    STAMP_INVALID,
    STAMP_IN_FUTURE,
    NO_IMU,
    ANGLE_OUT_OF_RANGE,
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
    held: np.ndarray | None = None  # model joints absent from the message, held (hold mode)


class NameMatcher:
    """Name list -> index map, cached per distinct list so the steady state costs one compare."""

    def __init__(self, joint_names: Sequence[str], cache_size: int = 16, hold: bool = False,
                 aliases: dict[str, str] | None = None, external: frozenset[str] = frozenset()):
        """hold: a model joint absent from a message is held (missing_joints: hold; the
        caller writes its posture), instead of the message being refused (reject).
        aliases: other names a message may give a model joint (the shoulder's model-file
        names: elv_angle -> shoulder_elevation_plane). external: model joints another input
        supplies (the shoulder from an Imu): never required, and a message's value for
        them is overwritten by the caller (their index points at slot 0)."""
        self.joint_names = tuple(joint_names)
        self.hold = hold
        self.aliases = dict(aliases or {})
        self.external = frozenset(external)
        self.held: np.ndarray | None = None  # the held joints of the last matched list
        self._cache: OrderedDict[tuple[str, ...], NameMatch] = OrderedDict()
        self._cache_size = cache_size
        self._last_names: list[str] | None = None
        self._last: NameMatch | None = None

    def match(self, names: list[str]) -> np.ndarray:
        """Index array for `names`, or raise Rejection."""
        if names != self._last_names:
            if len(names) > MAX_NAMES:  # before any copy: never cached
                raise Rejection(TOO_MANY_NAMES, f"{len(names)} names (at most {MAX_NAMES})")
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
        self.held = m.held
        return m.index

    def _build(self, names: tuple[str, ...]) -> NameMatch:
        if not names:
            return NameMatch(None, Rejection(EMPTY, "message has no joint names"))
        slots: dict[str, int] = {}
        dups = []
        for i, given in enumerate(names):
            n = self.aliases.get(given, given)
            if n in slots:
                dups.append(n if n == given else f"{given} (= {n})")
            slots[n] = i
        if dups:
            return NameMatch(None, Rejection(DUPLICATE_NAME, f"names repeated: {sorted(set(dups))}"))
        missing = [n for n in self.joint_names if n not in slots and n not in self.external]
        if missing and (not self.hold or len(missing) == len(self.joint_names)):
            hint = ("" if self.hold else "; a sensor that measures only some joints: "
                    "missing_joints:=hold holds the others at hold_posture.<joint>")
            return NameMatch(None, Rejection(
                MISSING_JOINT, f"{len(missing)} model joint(s) missing: {missing[:5]}"
                + (" ..." if len(missing) > 5 else "") + hint
            ))
        index = np.array([slots.get(n, 0) for n in self.joint_names], dtype=np.intp)
        held = np.array([i for i, n in enumerate(self.joint_names)
                         if n not in slots and n not in self.external], dtype=np.intp)
        return NameMatch(index, None, held if len(held) else None)

    def nonfinite_detail(self, field: str, values: np.ndarray) -> str:
        """Which joints hold NaN/inf (slow path, only for the warning text)."""
        bad = [self.joint_names[i] for i in np.flatnonzero(~np.isfinite(values))]
        return f"{field} of {bad[:5]}" + (" ..." if len(bad) > 5 else "") if bad else field


# -- stamps (called by stream_node only on its rare paths) ------------------------------------
def bad_stamp(sec: int, nanosec: int) -> Rejection:
    """Why a stamp that is zero, negative or has nanosec >= 1e9 is refused."""
    if sec == 0 and nanosec == 0:
        return Rejection(STAMP_MISSING, "header.stamp is zero")
    return Rejection(STAMP_INVALID, f"header.stamp sec={sec} nanosec={nanosec} is not a valid time")


def check_jump(t_ns: int, last_ns: int | None) -> None:
    """A first sample, or one more than max_stamp_gap from the previous: raise if impossible."""
    now = time.time_ns()
    ahead = t_ns - now
    if ahead > FUTURE_TOLERANCE_S * 1e9:
        raise Rejection(STAMP_IN_FUTURE, f"header.stamp is {ahead / 1e9:.1f} s ahead of this node's "
                        f"clock (> {FUTURE_TOLERANCE_S:g} s): corrupt stamp or clocks not synchronised")
    live = LIVE_WINDOW_S * 1e9
    if last_ns is not None and t_ns < last_ns and abs(now - last_ns) < live and now - t_ns > live:
        raise Rejection(STAMP_NOT_INCREASING, f"stamp {(last_ns - t_ns) / 1e9:.3f} s before the "
                        "previous sample of a live stream")


def flush_suppressed(warned: dict[str, tuple[float, int]], logger, every_s: float) -> None:
    """Log the rejections a rate-limited warning held back, once its window has passed.

    `warned` maps reason -> (monotonic time of the last warning, rejections suppressed since).
    """
    now = time.monotonic()
    for reason, (last, suppressed) in list(warned.items()):
        if suppressed and now - last >= every_s:
            logger.warning(f"rejected sample [{reason}]: {suppressed} more in the last "
                           f"{now - last:.1f} s (counts in /diagnostics)")
            warned[reason] = (now, 0)


def match_fields(names: NameMatcher, msg_names, n_pos: int, n_vel: int, n_eff: int) -> np.ndarray:
    """Index of the model joints in `msg_names`; raise Rejection for bad names or lengths."""
    index = names.match(msg_names)
    n = len(msg_names)
    if n_pos != n:
        raise Rejection(LENGTH_MISMATCH, f"{n_pos} positions for {n} names")
    if n_vel not in (0, n):
        raise Rejection(LENGTH_MISMATCH, f"{n_vel} velocities for {n} names (0 or {n})")
    if n_eff not in (0, n):  # unused, but a malformed message is not trusted
        raise Rejection(LENGTH_MISMATCH, f"{n_eff} efforts for {n} names (0 or {n})")
    return index
