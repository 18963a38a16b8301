"""muscle_node's input backlog: the samples it is behind on, held by the node, not by DDS.

Why: the input is best effort (the torque path must never wait for the muscles) and the DDS
reader keeps at most 5 000 samples (Fast DDS's max_samples, whatever the depth: 5 s at
1 kHz). On a shared 2-core machine the node, at nice 10 below the torque path, can fall
behind for longer than that: in benchmarks/muscle_node.py's chain at load 2-4 it lost 2 203
of 97 500 samples when its backlog reached that ceiling. Nothing was wrong with the samples;
the reader's queue was simply full while the node was still working through older ones.

So while the node works, it takes what has arrived out of the DDS reader every DRAIN_NS
(`InputBacklog.drain`: rcl's take, the raw bytes, ~µs each) into a queue of its own, bounded
by `backlog_limit` samples (a parameter: memory, ~1 KB a sample), and answers them in order.
Nothing is skipped or decimated: a sample leaves the queue only answered, or, past the
limit, dropped oldest-first and counted (`backlog_dropped_total`, a warning). The executor
still hands the node each sample it did not take itself; the node answers at most
BUDGET_NS of queued samples per callback and then returns (its timers, /diagnostics and the
config subscription run in between) and resumes on the next sample or its resume timer.

Visible in /diagnostics: `backlog_samples` (queued now), `backlog_max_samples` (the most
queued during the period), `drained_total` (samples taken by the node itself),
`backlog_dropped_total`, and `input_gaps_total`: samples missing between the publication
sequence numbers of the samples the drain took (the executor hands the others without their
sequence numbers; each is counted as one in between), so a sample the DDS queue dropped in
a stall longer than its 5 s shows up there, not only in a benchmark. A second writer on the
input topic (sequence numbers of two writers interleaved) makes that count meaningless; a
restarted writer (numbers starting again) is followed.
"""

from __future__ import annotations

import time
from collections import deque

DRAIN_NS = 5_000_000  # take what has arrived at least this often while working (5 ms)
BUDGET_NS = 50_000_000  # queued samples answered per callback before it returns (50 ms)
_perf_ns = time.perf_counter_ns


class InputBacklog:
    """The node's own queue of samples taken from the DDS reader (see the module docstring).

    take: a callable returning (bytes, info dict) or None when nothing is waiting (rclpy's
    Subscription.handle.take_message(msg_type, raw=True))."""

    def __init__(self, take, limit: int):
        self._take = take
        self.limit = int(limit)
        self.pending: deque[bytes] = deque()
        self.drained = 0
        self.dropped = 0
        self.gaps = 0
        self.max_period = 0
        self.max_total = 0
        self.last_drain = _perf_ns()
        self._next_seq: int | None = None  # the sequence number the next sample should have

    def delivered(self) -> None:
        """The executor handed one sample (its sequence number unknown: one in between)."""
        if self._next_seq is not None:
            self._next_seq += 1

    def drain(self) -> int:
        """Take every sample waiting in the DDS reader into the queue; returns how many."""
        take, q, n = self._take, self.pending, 0
        while True:
            got = take()
            if got is None:
                break
            data, info = got
            seq = info.get("publication_sequence_number") if isinstance(info, dict) else None
            if seq is not None:
                nxt = self._next_seq
                if nxt is not None and seq > nxt:
                    self.gaps += seq - nxt
                self._next_seq = seq + 1  # a restarted writer (seq < nxt) is followed
            q.append(data)
            n += 1
        if n:
            self.drained += n
            over = len(q) - self.limit
            if over > 0:
                for _ in range(over):
                    q.popleft()
                self.dropped += over
            if len(q) > self.max_period:
                self.max_period = len(q)
                self.max_total = max(self.max_total, self.max_period)
        self.last_drain = _perf_ns()
        return n

    def period_values(self) -> dict[str, str]:
        """The /diagnostics values; starts a new period for backlog_max_samples."""
        out = {"backlog_samples": str(len(self.pending)),
               "backlog_max_samples": str(self.max_period),
               "backlog_max_samples_total": str(self.max_total),
               "backlog_limit": str(self.limit), "drained_total": str(self.drained),
               "backlog_dropped_total": str(self.dropped), "input_gaps_total": str(self.gaps)}
        self.max_period = len(self.pending)
        return out
