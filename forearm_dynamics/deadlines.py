"""Deadline accounting of a stream node's outputs, per reason, with the worst lateness.

An output misses its deadline when it is published more than `deadline_ms` after its
reference time:

- one output per input: the input's arrival. rclpy hands the callback no receive time
  (the EventsExecutor refuses message-info callbacks in these wheels), so arrival is the
  callback's entry, and the time the input waited before it (transport, the executor's
  queue, a starved process) is added when the input's stamp is on this machine's clock
  (0 <= entry - stamp < LIVE_STAMP_S: a live source; a bag's recorded stamps are not).
  Reason `queued` if that wait was the larger part, else `compute` (the callback itself:
  validation, estimation, RNEA, the DDS write).
- a timer at output_rate_hz: the scheduled (absolute) time of the output. Reason
  `timer_late` if the tick came late by more than the callback took, else `compute`;
  periods dropped because the node was more than the backlog behind are `dropped`.

A miss never changes what is published: the output goes out late and is counted (an input
is never skipped to catch up; a dropped timer period is counted, never silent).
"""

from __future__ import annotations

REASONS_INPUT = ("queued", "compute")
REASONS_TIMER = ("timer_late", "compute", "dropped")
LIVE_STAMP_S = 10.0
_LIVE_NS = round(LIVE_STAMP_S * 1e9)


class Deadlines:
    """Counters for one node; `deadline_ns` 0 = not counted."""

    def __init__(self, deadline_ms: float, reasons: tuple[str, ...]):
        self.deadline_ms = deadline_ms
        self.deadline_ns = round(deadline_ms * 1e6)
        self.checked = 0
        self.missed = dict.fromkeys(reasons, 0)
        self.worst_ns = 0  # the largest reference -> output time among the misses
        # the largest live wait since take_behind(), counted or not: how far behind its
        # input the node is (stream_node warns when that nears its queue's length)
        self.behind_ns = 0

    def check_input(self, wait_ns: int, compute_ns: int) -> None:
        """One output per input: `wait_ns` = callback entry - input stamp (system clock)."""
        if not 0 <= wait_ns < _LIVE_NS:
            wait_ns = 0  # not a live stamp: the wait before the callback is unknown
        elif wait_ns > self.behind_ns:
            self.behind_ns = wait_ns
        d = self.deadline_ns
        if not d:
            return
        self.checked += 1
        total = wait_ns + compute_ns
        if total > d:
            self.missed["queued" if wait_ns > compute_ns else "compute"] += 1
            self.worst_ns = max(self.worst_ns, total)

    def check_timer(self, tick_late_ns: int, compute_ns: int) -> None:
        """A timer output: `tick_late_ns` = callback entry - scheduled time."""
        d = self.deadline_ns
        if not d:
            return
        self.checked += 1
        total = tick_late_ns + compute_ns
        if total > d:
            self.missed["timer_late" if tick_late_ns > compute_ns else "compute"] += 1
            self.worst_ns = max(self.worst_ns, total)

    def dropped(self, periods: int, late_ns: int) -> None:
        if not self.deadline_ns or periods <= 0:
            return
        self.checked += periods
        self.missed["dropped"] += periods
        self.worst_ns = max(self.worst_ns, late_ns)

    def take_behind(self) -> int:
        """The largest live wait (ns) since the last call; starts afresh."""
        out, self.behind_ns = self.behind_ns, 0
        return out

    @property
    def missed_total(self) -> int:
        return sum(self.missed.values())

    def values(self) -> dict[str, str]:
        """/diagnostics key-values (totals since start)."""
        if not self.deadline_ns:
            return {"deadline_ms": "0 (not counted)"}
        return {
            "deadline_ms": f"{self.deadline_ms:g}",
            "deadline_checked_total": str(self.checked),
            "deadline_missed_total": str(self.missed_total),
            **{f"deadline_missed.{k}": str(n) for k, n in self.missed.items()},
            "deadline_worst_ms": f"{self.worst_ns / 1e6:.3f}",
        }

    def summary(self) -> str:
        """One line for the shutdown summary."""
        if not self.deadline_ns:
            return "deadline: not counted (deadline_ms 0)"
        why = ", ".join(f"{k} {n}" for k, n in self.missed.items() if n)
        frac = self.missed_total / self.checked if self.checked else 0.0
        return (f"deadline {self.deadline_ms:g} ms: missed {self.missed_total} of {self.checked} "
                f"({100 * frac:.3f} %)" + (f" ({why}); worst {self.worst_ns / 1e6:.3f} ms" if why else ""))
