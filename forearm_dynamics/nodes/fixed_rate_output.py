"""torque_node's fixed-rate output (output_rate_hz > 0): a timer publishes at that rate,
each output stamped with its publication time and computed from the estimator's prediction
to that time.

Deadlines are absolute (k periods from the first). An rcl timer skips the periods it was
late for (under load: ~5 % of them at 1 kHz), so it ticks at twice the rate and `_on_tick`
publishes when the next deadline is due: a late output is caught up one per tick (never a
burst, never a stale value) unless more than _MAX_BACKLOG_S behind. When no input came for
input_timeout s, or the input's stamps are that far behind this node's clock, nothing is
published (`_skip` says why once; /diagnostics counts it).

A mixin of TorqueNode: it uses the node's estimator bundle (`live`), output message
(`out`, `pub`), statistics and deadlines, and the state `compute` leaves
(`_have_state`, `_last_in_ns`, `_state_t_ns`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from . import validation as v

_time_ns = time.time_ns
_monotonic_ns = time.monotonic_ns
#: how late (s) the output may fall behind its deadlines and still catch up, at most one
#: output per tick (twice the rate); a longer stall drops the periods
_MAX_BACKLOG_S = 0.05


class FixedRateOutput:
    """The timer, its deadlines and why it is silent."""

    def start_fixed_rate_output(self) -> None:
        self._period_ns = round(1e9 / self.output_rate_hz)
        self._due_ns = 0
        self._max_backlog_ns = max(round(_MAX_BACKLOG_S * 1e9), 2 * self._period_ns)
        self.create_timer(0.5 / self.output_rate_hz, self._on_tick)

    def _on_tick(self) -> None:
        """Publish if the deadline is due: deadlines are k periods apart, whatever the ticks."""
        now = _monotonic_ns()
        due = self._due_ns
        if now < due:
            return
        late = now - due
        if late > self._max_backlog_ns:  # too far behind: drop, start again from now
            if due:
                self.timer_skipped["late"] += late // self._period_ns
                self.deadlines.dropped(late // self._period_ns, late)
            due = now
        self._due_ns = due + self._period_ns
        if not self._on_timer():
            self._due_ns = now + self._period_ns  # silent: resume on time, no catching up
        else:
            self.deadlines.check_timer(now - due, _monotonic_ns() - now)

    def _on_timer(self) -> bool:
        """One output stamped now (system clock), from the estimate predicted to now."""
        now = _time_ns()
        if not self._have_state:
            self._skip("no_input", "no input yet")
            return False
        if now - self._last_in_ns > self.input_timeout_ns:
            self._skip("input_timeout", f"no input for {(now - self._last_in_ns) / 1e9:.3f} s "
                       f"(> input_timeout): not publishing")
            return False
        if now - self._state_t_ns > self.input_timeout_ns:
            self._skip("stamps_behind", f"input stamps {(now - self._state_t_ns) / 1e9:.3f} s behind "
                       "this node's clock (> input_timeout): not publishing")
            return False
        t_start = time.perf_counter_ns()
        b = self.live.in_use
        est = b.estimator
        # with a delay, the output is the (smoothed) estimate delay_s back, stamped so
        stamp = max(now - round(getattr(est, "delay_s", 0.0) * 1e9), self._last_out_ns + 1)
        est.predict(stamp)  # from the last update's estimate, whatever was predicted before
        np.copyto(self.q, est.q)
        np.copyto(self.qd, est.qd)
        tau = b.torques(self.q, self.qd, est.qdd)
        if not math.isfinite(tau.sum()):
            self.stats.rejected[v.NON_FINITE_TORQUE] += 1
            return False
        np.copyto(self.effort, tau)
        sec, nsec = divmod(stamp, 1_000_000_000)
        self.out.pack_stamp(sec, nsec)
        self.pub.publish(self.out.payload())
        self._last_out_ns = stamp
        self.stats.published += 1
        if self._silent is not None:
            self.get_logger().info("input back: publishing again")
            self._silent = None
        self.after_output(sec, nsec)
        t_end = time.perf_counter_ns()
        self.stats.record(t_end - t_start, now - self._state_t_ns, 0)
        return True

    def _skip(self, key: str, why: str) -> None:
        self.timer_skipped[key] += 1
        if self._silent != key:
            if key != "no_input":
                self.get_logger().warning(why)
            self._silent = key
