"""check_bag NEW --baseline OLD: are two runs' joint_torques the same, stamp by stamp?

A bag replay test records a session once (the baseline), replays it through a new build
of the node and compares. Samples are matched by header stamp (the replay keeps the
recorded stamps); for each DOF (by joint name) the max and RMS of |new - old| effort over
the matched samples; unmatched samples on either side are counted and named by their
first stamps. Verdict: a difference above the tolerance, a NaN where the other has a
number, or any unmatched sample -> failure (exit 1: the data differ or were lost).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..bag.reader import Bag, open_bag
from ..codec.jointstate import read_joint_series
from ..errors import UsageError

TOPIC = "joint_torques"


@dataclass
class RegressionReport:
    new: str
    baseline: str
    joint_names: tuple[str, ...]
    tolerance: float
    matched: int
    unmatched_new: int  # new samples whose stamp the baseline does not have
    unmatched_baseline: int
    max_diff: np.ndarray  # (J,) N·m; inf where one side is NaN
    rms_diff: np.ndarray  # (J,)
    first_unmatched: list[int] = field(default_factory=list)  # stamps (ns), a few
    duplicates: int = 0
    failures: list[str] = field(default_factory=list)

    def worst(self) -> tuple[float, str]:
        if not len(self.max_diff):
            return float("nan"), ""
        j = int(np.argmax(self.max_diff))
        return float(self.max_diff[j]), self.joint_names[j]


def _efforts(bag: Bag, names: tuple[str, ...] | None = None
             ) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """(stamps (N,), effort (N, J), names): columns by joint name; `names` defaults to the
    first message's order (the node's model order). NaN where a joint has no effort."""
    s = read_joint_series(bag, TOPIC, names, effort=True)
    return s.stamp_ns, s.effort, s.joint_names


def compare(new_path, baseline_path, tolerance: float = 1e-6) -> RegressionReport:
    if not (tolerance >= 0 and math.isfinite(tolerance)):
        raise UsageError(f"--tolerance must be a finite number >= 0, got {tolerance}")
    new_bag, old_bag = open_bag(new_path), open_bag(baseline_path)
    a_s, a, names = _efforts(new_bag)
    b_s, b, _ = _efforts(old_bag, names)
    dup = (len(a_s) - len(np.unique(a_s))) + (len(b_s) - len(np.unique(b_s)))
    a_u, ia = np.unique(a_s, return_index=True)
    b_u, ib = np.unique(b_s, return_index=True)
    common, ja, jb = np.intersect1d(a_u, b_u, assume_unique=True, return_indices=True)
    x, y = a[ia[ja]], b[ib[jb]]
    with np.errstate(invalid="ignore"):
        d = np.abs(x - y)
    one_nan = np.isnan(x) != np.isnan(y)
    d = np.where(np.isnan(x) & np.isnan(y), 0.0, np.where(one_nan, np.inf, d))
    if len(common):
        max_diff = d.max(axis=0)
        with np.errstate(invalid="ignore", over="ignore"):
            rms = np.sqrt((d ** 2).mean(axis=0))
    else:
        max_diff = rms = np.full(len(names), np.nan)
    only_new = np.setdiff1d(a_u, common, assume_unique=True)
    only_old = np.setdiff1d(b_u, common, assume_unique=True)
    rep = RegressionReport(str(new_path), str(baseline_path), names, tolerance, len(common),
                           len(only_new), len(only_old), max_diff, rms,
                           sorted([*only_new[:3].tolist(), *only_old[:3].tolist()]), dup)
    rep.failures = verdicts(rep)
    for b_ in (new_bag, old_bag):
        if not b_.info.complete:
            rep.failures.append(f"{b_.path} is truncated ({b_.info.problem}): only its complete "
                                "chunks were compared")
    return rep


def verdicts(rep: RegressionReport) -> list[str]:
    out = []
    if rep.matched == 0:
        out.append("no joint_torques stamp in common: not a replay of the baseline")
        return out
    value, dof = rep.worst()
    if value > rep.tolerance:
        out.append(f"max |difference| {value:.3g} N·m > tolerance {rep.tolerance:g} at DOF {dof}")
    if rep.unmatched_new or rep.unmatched_baseline:
        out.append(f"unmatched samples: {rep.unmatched_new} only in the new bag, "
                   f"{rep.unmatched_baseline} only in the baseline (first stamps "
                   f"{', '.join(str(s) for s in rep.first_unmatched[:3])})")
    if rep.duplicates:
        out.append(f"{rep.duplicates} joint_torques with a duplicate stamp")
    return out


def format_report(rep: RegressionReport) -> list[str]:
    lines = [(f"regression: {rep.new} vs baseline {rep.baseline}: {rep.matched} samples matched by "
             f"stamp, {rep.unmatched_new} only in new, {rep.unmatched_baseline} only in baseline; "
             f"tolerance {rep.tolerance:g} N·m"),
             f"{'DOF':<22} {'max |diff| N·m':>15} {'RMS diff N·m':>14}"]
    for j, n in enumerate(rep.joint_names):
        lines.append(f"{n:<22} {rep.max_diff[j]:>15.3e} {rep.rms_diff[j]:>14.3e}")
    lines += [f"FAIL: {f}" for f in rep.failures]
    lines.append("PASS (identical within tolerance)" if not rep.failures else
                 f"FAIL ({len(rep.failures)} problem(s))")
    return lines


def to_dict(rep: RegressionReport) -> dict:
    def num(x):
        x = float(x)
        return x if math.isfinite(x) else None

    return {"new": rep.new, "baseline": rep.baseline, "tolerance_nm": rep.tolerance,
            "matched": rep.matched, "unmatched_new": rep.unmatched_new,
            "unmatched_baseline": rep.unmatched_baseline, "duplicates": rep.duplicates,
            "max_diff_nm": {n: num(v) for n, v in zip(rep.joint_names, rep.max_diff, strict=True)},
            "rms_diff_nm": {n: num(v) for n, v in zip(rep.joint_names, rep.rms_diff, strict=True)},
            "failures": rep.failures}
