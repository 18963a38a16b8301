"""Pipeline statistics for /diagnostics: rates, compute time, latency, rejections.

compute = callback entry to publish() returned (validation, estimation, RNEA, publish);
publish = the part of it spent inside publish() (the DDS write, synchronous); own =
compute - publish per sample (what the node itself does: validation, estimation, RNEA);
latency = receive time (system clock) - header stamp, i.e. one-way from the publisher
when both run on this machine. Both are per period (p50, p99, max).

Samples go into preallocated ring buffers (no allocation per message); percentiles are
computed once per diagnostics period over the samples of that period, in one numpy call
(the timer runs on the executor thread: while it works, samples wait). numpy's percentile
costs ~8 ms on its first call (lazy set-up), so it is warmed up at import instead of in
the first period of a stream (that was a ~10 ms latency spike in every run).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

_QUANTILES = (50, 99, 100)
np.percentile(np.zeros((4, 2), dtype=np.int64), _QUANTILES, axis=1)  # warm-up, see above


class PipelineStats:
    """Counters and per-period timing samples of one node's input -> output pipeline."""

    def __init__(self, reasons: Iterable[str], window: int = 16384):
        self.received = 0
        self.published = 0
        self.warmup = 0  # published before the estimator had enough history
        self.rejected = dict.fromkeys(reasons, 0)
        self.resets: dict[str, int] = {"stamp_gap": 0, "stamp_jump_back": 0}
        self._compute_ns = np.zeros(window, dtype=np.int64)
        self._latency_ns = np.zeros(window, dtype=np.int64)
        self._publish_ns = np.zeros(window, dtype=np.int64)
        self._n = 0  # samples recorded this period
        self._window = window
        self._period_start = time.monotonic()
        self._received_at_start = 0
        self._published_at_start = 0
        self._rejected_at_start = 0

    def record(self, compute_ns: int, latency_ns: int, publish_ns: int = 0) -> None:
        i = self._n % self._window
        self._compute_ns[i] = compute_ns
        self._latency_ns[i] = latency_ns
        self._publish_ns[i] = publish_ns
        self._n += 1

    def status(self, name: str, hardware_id: str = "") -> DiagnosticStatus:
        """Summary of the period since the last call; starts a new period."""
        now = time.monotonic()
        span = max(now - self._period_start, 1e-9)
        n = min(self._n, self._window)
        in_rate = (self.received - self._received_at_start) / span
        out_rate = (self.published - self._published_at_start) / span
        total_rejected = sum(self.rejected.values())
        new_rejected = total_rejected - self._rejected_at_start
        if n:
            compute, publish = self._compute_ns[:n], self._publish_ns[:n]
            rows = np.stack((compute, self._latency_ns[:n], publish, compute - publish))
            q = np.percentile(rows, _QUANTILES, axis=1) / 1e3  # (quantile, row)
            (c50, l50, p50, o50), (c99, l99, p99, o99), (cmax, lmax, pmax, omax) = q.tolist()
        else:
            c50 = c99 = cmax = l50 = l99 = lmax = p50 = p99 = pmax = float("nan")
            o50 = o99 = omax = float("nan")
        values = {
            "input_rate_hz": f"{in_rate:.1f}",
            "output_rate_hz": f"{out_rate:.1f}",
            "compute_us_p50": f"{c50:.1f}",
            "compute_us_p99": f"{c99:.1f}",
            "compute_us_max": f"{cmax:.1f}",
            "publish_us_p50": f"{p50:.1f}",
            "publish_us_p99": f"{p99:.1f}",
            "publish_us_max": f"{pmax:.1f}",
            "own_us_p50": f"{o50:.1f}",
            "own_us_p99": f"{o99:.1f}",
            "own_us_max": f"{omax:.1f}",
            "latency_us_p50": f"{l50:.1f}",
            "latency_us_p99": f"{l99:.1f}",
            "latency_us_max": f"{lmax:.1f}",
            "received_total": str(self.received),
            "processed_total": str(self.published),
            "warmup_total": str(self.warmup),
            "rejected_total": str(total_rejected),
            **{f"rejected.{k}": str(v) for k, v in self.rejected.items()},
            **{f"reset.{k}": str(v) for k, v in self.resets.items()},
            # the machine, not the node: latency on a loaded machine is read against it
            "load_average_1min": load_average_1min(),
        }
        if new_rejected:
            level, message = DiagnosticStatus.WARN, f"{new_rejected} sample(s) rejected"
        elif self.received == self._received_at_start:
            level, message = DiagnosticStatus.OK, "no input"
        else:
            level, message = DiagnosticStatus.OK, f"{out_rate:.0f} Hz"
        self._period_start = now
        self._received_at_start = self.received
        self._published_at_start = self.published
        self._rejected_at_start = total_rejected
        self._n = 0
        return DiagnosticStatus(
            level=level,
            name=name,
            message=message,
            hardware_id=hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )


def load_average_1min() -> str:
    try:
        return f"{os.getloadavg()[0]:.2f}"
    except OSError:  # not every platform has it
        return "nan"


def diagnostic_array(status: DiagnosticStatus, stamp) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [status]
    return msg
