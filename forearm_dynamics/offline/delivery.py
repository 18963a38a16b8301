"""Delivery: what reached the recorder, how late, and how busy the machine was.

joint_states without a joint_torques of the same header stamp are lost (those received in
the bag's last tail_grace_s are left out and counted: their answers may have arrived after
the recorder stopped); the one-way latency is the joint_torques' log (receive) time minus
that stamp. Latency measures the machine as much as the code, so it travels with the load
average it was measured under (MachineLoad).

Why the answers after a run of lost ones are measured (behind_after_loss_ms): a node that
falls further behind its input than its queue holds (qos_depth samples; 1 s at 1 kHz by
default) loses the oldest samples to DDS, uncounted by the node, and the first answer after
them is about a queue's length late (the demo beside a dd + fsync loop on 2 CPUs, with a /proc
sampler also running: 2 370-4 371 samples lost in runs whose next answers came 1.1-1.2 s
late; benchmarks/pipeline_disk_load.py). Lost answers with prompt answers next to them have
another cause (a rejected sample, an answer lost on the way), so the lag tells the two apart
(overflow_note).
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
    lost_runs: int = 0  # runs of consecutive lost joint_states (in stamp order)
    # the latest first answer after a run, beyond the median latency (ms; NaN: none answered)
    behind_after_loss_ms: float = float("nan")


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


#: without the node's queue depth, a lag after lost answers worth naming (s): far above the
#: spread of a working pipeline's latency (p99 2.6 ms quiet, 415 ms beside a disk writer)
LAG_NOTE_S = 0.5


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
        if d.lost:
            _after_loss(d, considered, lost, torques)
    if len(answered[0]):
        lat = (answered[1] - answered[0]) / 1e6
        p50, p99 = np.percentile(lat, [50, 99])
        d.latency_ms = {"p50": float(p50), "p99": float(p99), "max": float(lat.max())}
        if np.isfinite(d.behind_after_loss_ms):
            d.behind_after_loss_ms = max(0.0, d.behind_after_loss_ms - float(p50))
    return d


def _after_loss(d: Delivery, stamps: np.ndarray, lost: np.ndarray, torques: JointSeries) -> None:
    """lost_runs, and the largest latency (ms, not yet less the median) of the first answered
    joint_state after each run of lost ones (runs in stamp order; `lost` as delivery() found)."""
    order = np.argsort(stamps, kind="stable")
    stamps, lost = stamps[order], lost[order]
    starts = np.flatnonzero(lost & ~np.concatenate(([False], lost[:-1])))
    d.lost_runs = len(starts)
    answered = np.flatnonzero(~lost)
    nxt = np.searchsorted(answered, starts)  # the first answered one after each run's start
    nxt = answered[nxt[nxt < len(answered)]]
    if len(nxt):
        t = np.argsort(torques.stamp_ns, kind="stable")
        pos = t[np.searchsorted(torques.stamp_ns[t], stamps[nxt])]
        lat = (torques.log_ns[pos] - stamps[nxt]) / 1e6
        d.behind_after_loss_ms = float(lat.max())


def overflow_note(d: Delivery, queue_depth: int | None, load: MachineLoad) -> str:
    """Why answers were lost when their neighbours say the node was behind ("" otherwise): the
    first answers after the lost runs came at least half the node's queue late (its config
    states the queue; an older bag's does not, and then a lag of LAG_NOTE_S is told as is)."""
    behind = d.behind_after_loss_ms / 1e3
    rate = d.rate_hz.get("joint_states", float("nan"))
    if not (d.lost and np.isfinite(behind)):
        return ""
    text = (f"the first answers after the {d.lost_runs} run(s) of lost ones came up to "
            f"{behind:.2f} s later than usual")
    if queue_depth is None or not (np.isfinite(rate) and rate > 0.0):
        return f"{text} (the bag's config does not state the node's queue)" \
            if behind >= LAG_NOTE_S else ""
    queue_s = queue_depth / rate
    if behind < 0.5 * queue_s:
        return ""
    return (f"{text}, about what the torque node's input queue holds ({queue_depth} samples = "
            f"{queue_s:.2f} s at {rate:.0f} Hz): the node fell behind its input and DDS dropped "
            f"the oldest samples; the machine did not give the nodes the CPU they need "
            f"({load.describe()}): free it, or deepen the queue (torque_node qos_depth: every "
            "sample kept, answered later)")


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
