"""Delivery: what reached the recorder, how late, and how busy the machine was.

joint_states without a joint_torques of the same header stamp are lost (those received in
the bag's last tail_grace_s are left out and counted: their answers may have arrived after
the recorder stopped); the one-way latency is the joint_torques' log (receive) time minus
that stamp. Latency measures the machine as much as the code, so it travels with the load
average it was measured under (MachineLoad).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..codec.jointstate import JointSeries


@dataclass
class Delivery:
    joint_states: int = 0
    joint_torques: int = 0
    considered: int = 0  # joint_states old enough to have been answered before the end
    lost: int = 0
    loss_pct: float = float("nan")
    lost_stamps_ns: list[int] = field(default_factory=list)  # the first 20 lost stamps
    tail_grace_s: float = 0.0
    tail_left_out: int = 0  # joint_states received in the last tail_grace_s: not judged
    tail_answered: int = 0  # ... of which answered anyway
    unmatched_torques: int = 0
    latency_ms: dict[str, float] = field(default_factory=dict)
    rate_hz: dict[str, float] = field(default_factory=dict)
    max_gap_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class MachineLoad:
    """How busy the machine was: latency is the machine's as much as the code's.

    during_run: 1-minute load averages the torque node put in its /diagnostics (recorded in
    the bag), if any; now: os.getloadavg() when check_bag ran (same machine or not).
    """

    cpus: int | None = None
    now: tuple[float, float, float] | None = None
    during_run: list[float] = field(default_factory=list)

    @classmethod
    def measure(cls, during_run: list[float] | None = None) -> MachineLoad:
        try:
            now = tuple(round(x, 2) for x in os.getloadavg())
        except OSError:  # not every platform has it
            now = None
        return cls(os.cpu_count(), now, list(during_run or []))

    def describe(self) -> str:
        parts = []
        if self.during_run:
            v = np.asarray(self.during_run)
            parts.append(f"load average {np.median(v):.1f} (1 min, median over the run; max "
                         f"{v.max():.1f}) from the torque node's /diagnostics")
        if self.now is not None:
            parts.append(f"load average now {self.now[0]:.1f} / {self.now[1]:.1f} / "
                         f"{self.now[2]:.1f} (1/5/15 min)")
        cpus = f" on {self.cpus} CPUs" if self.cpus else ""
        return ("; ".join(parts) + cpus) if parts else "load average unknown"

    def peak(self) -> float:
        """The highest known 1-minute load average (NaN if none)."""
        vals = list(self.during_run) + ([self.now[0]] if self.now else [])
        return max(vals) if vals else float("nan")


def _rate_and_gap(log_ns: np.ndarray) -> tuple[float, float]:
    if len(log_ns) < 2:
        return float("nan"), float("nan")
    t = np.sort(log_ns)
    return (len(t) - 1) / ((t[-1] - t[0]) / 1e9), float(np.diff(t).max() / 1e6)


def delivery(states: JointSeries | None, torques: JointSeries, grace_s: float) -> Delivery:
    d = Delivery(joint_torques=len(torques))
    rate, gap = _rate_and_gap(torques.log_ns)
    d.rate_hz["joint_torques"], d.max_gap_ms["joint_torques"] = rate, gap
    answered = torques.stamp_ns, torques.log_ns
    if states is not None and len(states):
        d.joint_states = len(states)
        d.rate_hz["joint_states"], d.max_gap_ms["joint_states"] = _rate_and_gap(states.log_ns)
        end = max(states.log_ns.max(), torques.log_ns.max() if len(torques) else 0)
        judged = states.log_ns <= end - round(grace_s * 1e9)
        considered = states.stamp_ns[judged]
        d.tail_grace_s = grace_s
        d.tail_left_out = int((~judged).sum())
        d.tail_answered = int(np.isin(states.stamp_ns[~judged], torques.stamp_ns).sum())
        d.considered = len(considered)
        lost = ~np.isin(considered, torques.stamp_ns)
        d.lost = int(lost.sum())
        d.lost_stamps_ns = [int(s) for s in np.sort(considered[lost])[:20]]
        d.loss_pct = 100.0 * d.lost / d.considered if d.considered else float("nan")
        matched = np.isin(torques.stamp_ns, states.stamp_ns)
        d.unmatched_torques = int((~matched).sum())
        answered = torques.stamp_ns[matched], torques.log_ns[matched]
    if len(answered[0]):
        lat = (answered[1] - answered[0]) / 1e6
        p50, p99 = np.percentile(lat, [50, 99])
        d.latency_ms = {"p50": float(p50), "p99": float(p99), "max": float(lat.max())}
    return d


def old_stamps_note(d: Delivery, old_stamps_latency_s: float) -> str | None:
    """A replay of an old recording: its stamps are far older than any answer can take, so the
    latency says how old the recording is, not how fast the node is; name the fix (restamp)."""
    p50 = d.latency_ms.get("p50", float("nan"))
    if not (np.isfinite(p50) and p50 > old_stamps_latency_s * 1e3):
        return None
    return (f"latency is meaningless here: the input stamps were {p50 / 1e3:.1f} s old on "
            "arrival (a replay of an old recording); replay it with "
            "`bag_player --ros-args -p restamp:=true` (stamps shifted to now, spacing "
            "kept) to measure the node's latency")
