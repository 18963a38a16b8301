"""Joint angles against the joints' physiological ranges: the one check every input path calls.

Why: the commonest mistake with joint angles is their unit (degrees read as radians, or
radians converted to radians a second time), and nothing downstream can see it: inverse
dynamics of 90 "rad" of elbow flexion gives finite torques, and a reference computed from
the same angles agrees with them (issue 30: elbow angles of 3 375-7 919 deg, torques of
1 490 N·m, check_bag PASS). The ranges are config/model.yaml `ranges_deg` (README table:
AAOS, elbow from the paper); a joint's width w = upper - lower. Three bands:

- inside, or outside by at most WARN_FRACTION x w: fine (people and sensors exceed the
  textbook ranges a little);
- moderately outside (beyond that, but not far): warned once per joint;
- far outside: |q| > 2*pi (no joint of the model turns a full circle: such a value is
  never an angle in radians), or outside the range by more than FAR_WIDTHS x w. Refused,
  with a line that names units. Degrees read as radians are far outside for any joint
  angle beyond 2.1-6.3 deg (thumb CMC flexion 2.1, elbow 6.3): every movement of the library.

Radians converted twice (values 57.3 x too small) stay inside every range; a whole
recording shows it (`tiny_recording`): every angle within +-TINY_RAD while some joint moves
by at least TINY_MOTION_RAD. A neutral-posture hold with that much sensor noise looks the
same (the one false alarm; said in the message).

ROS-free (core): torque_node (per sample, `SampleGuard`), mot_to_bag, bag_torques and
check_bag (whole recordings, `check_recording`) call it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .description import load_description

#: moderately outside: beyond the range by more than this fraction of its width
WARN_FRACTION = 0.25
#: far outside: beyond the range by more than this many widths (or |q| > 2*pi)
FAR_WIDTHS = 3.0
#: a recording whose every angle is within this (rad) = pi degrees, ...
TINY_RAD = math.pi * math.pi / 180.0
#: ... while some joint moves by at least this much (rad): 0.1 deg (a 5.7 deg swing
#: converted twice); a recording of zeros (a test, a held posture) is not flagged
TINY_MOTION_RAD = math.radians(0.1)

UNITS_HINT = ("check units: degrees given as radians? (OpenSim files: inDegrees=yes|no in the "
              "header, mot_to_bag --in-degrees; JointState positions are radians)")
TINY_HINT = ("check units: radians converted to radians twice (or inDegrees=yes on a file in "
             "radians)? A still neutral posture with sensor noise looks the same")


@dataclass(frozen=True)
class AngleRanges:
    """Per joint (in the order given): lower, upper (rad) and the two bands' limits."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def of(cls, joint_names: Sequence[str]) -> AngleRanges:
        """A joint without a range in model.yaml (one a later model adds) gets -pi..pi: only
        |q| > 2*pi is far for it."""
        ranges = load_description().ranges
        lo = np.array([ranges.get(n, (-math.pi, math.pi))[0] for n in joint_names], float)
        hi = np.array([ranges.get(n, (-math.pi, math.pi))[1] for n in joint_names], float)
        return cls(tuple(joint_names), lo, hi)

    @property
    def width(self) -> np.ndarray:
        return self.upper - self.lower

    def warn_limits(self) -> tuple[np.ndarray, np.ndarray]:
        m = WARN_FRACTION * self.width
        return self.lower - m, self.upper + m

    def far_limits(self) -> tuple[np.ndarray, np.ndarray]:
        m = FAR_WIDTHS * self.width
        return np.maximum(self.lower - m, -2 * math.pi), np.minimum(self.upper + m, 2 * math.pi)

    def far(self, q: np.ndarray) -> np.ndarray:
        lo, hi = self.far_limits()
        return (q < lo) | (q > hi)

    def outside(self, q: np.ndarray) -> np.ndarray:
        lo, hi = self.warn_limits()
        return (q < lo) | (q > hi)

    def describe(self, j: int) -> str:
        return (f"range {math.degrees(self.lower[j]):.0f}..."
                f"{math.degrees(self.upper[j]):.0f} deg")


@dataclass
class RangeReport:
    """What a whole recording's angles say: a refusal (one line) or warnings (one per joint)."""

    refusal: str | None = None
    warnings: list[str] = field(default_factory=list)
    far_joints: list[str] = field(default_factory=list)
    tiny: bool = False


def _deg(x: float) -> str:
    return f"{x:.4g} rad ({math.degrees(x):.4g} deg)"


def far_refusal(q: np.ndarray, rng: AngleRanges, source: str,
                use: np.ndarray | None = None) -> str:
    """The one line for angles (N, J) far outside their ranges: the first such joint, its
    largest value and row, how many joints and samples, and units."""
    q = np.atleast_2d(q)
    far = rng.far(q) if use is None else rng.far(q) & use
    cols = np.flatnonzero(far.any(axis=0))
    j = int(cols[0])
    k = int(np.argmax(np.abs(q[:, j])))
    return (f"{source}: {rng.names[j]} is {_deg(float(q[k, j]))} (row {k + 1}), far outside its "
            f"{rng.describe(j)} ({len(cols)} joint(s), {int(far.any(axis=1).sum())} of {len(q)} "
            f"samples far out); {UNITS_HINT}")


def check_recording(q: np.ndarray, joint_names: Sequence[str], *, source: str,
                    measured: Sequence[bool] | None = None,
                    as_given: np.ndarray | None = None) -> RangeReport:
    """Angles (N, J) rad of a recording; `measured` leaves held joints out. The refusal
    names `source` (file, topic), the first far joint and its value, and units.
    `as_given`: the angles before a coordinate map's zero offsets (a file's own values,
    scaled to rad): the radians-twice rule looks at those (full-body pro_sup_r is offset by
    -90 deg, so tiny values of the file are not tiny after the map)."""
    q = np.atleast_2d(np.asarray(q, float))
    rng = AngleRanges.of(joint_names)
    use = np.ones(len(joint_names), bool) if measured is None else np.asarray(measured, bool)
    rep = RangeReport()
    if not use.any() or q.size == 0:
        return rep
    finite = np.where(np.isfinite(q), q, 0.0)
    if (rng.far(finite) & use).any():
        rep.refusal = far_refusal(finite, rng, source, use)
        rep.far_joints = [joint_names[j] for j in np.flatnonzero((rng.far(finite) & use).any(axis=0))]
        return rep
    qa = (finite if as_given is None else np.atleast_2d(np.asarray(as_given, float)))[:, use]
    if len(q) > 1 and np.abs(qa).max() <= TINY_RAD and np.ptp(qa, axis=0).max() >= TINY_MOTION_RAD:
        rep.tiny = True
        rep.refusal = (f"{source}: every measured angle is within +-{math.degrees(TINY_RAD):.2f} deg "
                       f"while the joints move (largest swing {math.degrees(np.ptp(qa, axis=0).max()):.3f}"
                       f" deg); {TINY_HINT}")
        return rep
    out = rng.outside(finite) & use
    for j in np.flatnonzero(out.any(axis=0)):
        k = int(np.argmax(np.abs(finite[:, j] - 0.5 * (rng.lower[j] + rng.upper[j]))))
        rep.warnings.append(f"{source}: {joint_names[j]} reaches {_deg(finite[k, j])} (row {k + 1}), "
                            f"outside its {rng.describe(j)} by more than "
                            f"{100 * WARN_FRACTION:g} % of it ({int(out[:, j].sum())} samples)")
    return rep


class SampleGuard:
    """Per-sample check of a stream (torque_node): cheap when inside (maximum, minimum,
    subtract on preallocated arrays and one dot: the distance outside the warning band is
    zero; the fastest of the forms measured, ~7 us at load 10 against ~17 for a compare-any),
    a refusal line for a far sample, one warning per joint moderately
    outside (`pending_warnings`), and, over the stream's first `window_s`, the radians-twice
    pattern (`check_window`)."""

    def __init__(self, joint_names: Sequence[str], window_s: float = 1.0):
        self.names = tuple(joint_names)
        self.ranges = AngleRanges.of(joint_names)
        self._lo, self._hi = self.ranges.warn_limits()
        self._buf = np.empty(len(self.names))
        self.warned: set[str] = set()
        self.pending_warnings: list[str] = []
        self.far_count = 0
        self._window_ns = round(window_s * 1e9)
        self._t0: int | None = None
        self._max = np.zeros(len(self.names))
        self._min = np.zeros(len(self.names))
        self._abs = np.zeros(len(self.names))
        self.window_done = False
        self.tiny_warning: str | None = None

    def check(self, q: np.ndarray, held: np.ndarray | None = None) -> str | None:
        """None when every joint is within the warning band; else the refusal line (far),
        or None after queueing a warning for each newly moderately-outside joint."""
        buf = self._buf
        np.maximum(q, self._lo, out=buf)
        np.minimum(buf, self._hi, out=buf)
        np.subtract(q, buf, out=buf)
        if buf.dot(buf) == 0.0:  # NaN never reaches here: the stream node refuses it first
            return None
        far = self.ranges.far(q)
        out = self.ranges.outside(q)
        if held is not None:
            far[held] = False
            out[held] = False
        if far.any():
            self.far_count += 1
            j = int(np.flatnonzero(far)[0])
            return (f"{self.names[j]} is {_deg(float(q[j]))}, far outside its "
                    f"{self.ranges.describe(j)} ({int(far.sum())} joint(s)); {UNITS_HINT}")
        for j in np.flatnonzero(out):
            name = self.names[j]
            if name not in self.warned:
                self.warned.add(name)
                self.pending_warnings.append(
                    f"{name} at {_deg(float(q[j]))}: outside its {self.ranges.describe(j)} by more "
                    f"than {100 * WARN_FRACTION:g} % of it (warned once per joint)")
        return None

    def observe(self, t_ns: int, q: np.ndarray) -> str | None:
        """Over the stream's first window_s: the radians-twice pattern; its line once, else None."""
        if self.window_done:
            return None
        if self._t0 is None:
            self._t0 = t_ns
            self._max[:] = q
            self._min[:] = q
        np.maximum(self._max, q, out=self._max)
        np.minimum(self._min, q, out=self._min)
        if t_ns - self._t0 < self._window_ns:
            return None
        self.window_done = True
        np.maximum(np.abs(self._max), np.abs(self._min), out=self._abs)
        swing = float((self._max - self._min).max())
        if self._abs.max() <= TINY_RAD and swing >= TINY_MOTION_RAD:
            self.tiny_warning = (f"every angle within +-{math.degrees(TINY_RAD):.2f} deg over the first "
                                 f"{self._window_ns / 1e9:g} s while the joints move (swing "
                                 f"{math.degrees(swing):.3f} deg); {TINY_HINT}")
            return self.tiny_warning
        return None
