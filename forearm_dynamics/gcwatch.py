"""Garbage collections of a serving process, timed (gc.callbacks), for /diagnostics.

A node spins in the executor's C++ loop and runs Python only in its callbacks, so a
collection that happens while it serves runs inside a callback and delays that output by
its pause. `GcWatch` counts collections per generation and their pauses (total and worst)
while serving (from `serving()`, called once the start-up heap is frozen), at the cost of
two Python calls per collection.
"""

from __future__ import annotations

import gc
import time

_perf_ns = time.perf_counter_ns


class GcWatch:
    def __init__(self) -> None:
        self.collections = [0, 0, 0]
        self.pause_ns_total = 0
        self.pause_ns_max = 0
        self.pauses_over_100us = 0
        self._t0 = 0
        self.startup_pause_ns = 0
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = _perf_ns()
            return
        dt = _perf_ns() - self._t0
        self.collections[info["generation"]] += 1
        self.pause_ns_total += dt
        self.pause_ns_max = max(self.pause_ns_max, dt)
        if dt > 100_000:
            self.pauses_over_100us += 1

    def serving(self) -> None:
        """Count from now on (the start-up collection before gc.freeze() is not serving)."""
        self.startup_pause_ns = self.pause_ns_total
        self.collections = [0, 0, 0]
        self.pause_ns_total = self.pause_ns_max = self.pauses_over_100us = 0

    def close(self) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    def values(self) -> dict[str, str]:
        return {
            "gc.automatic": str(gc.isenabled()).lower(),
            **{f"gc.collections_gen{g}": str(n) for g, n in enumerate(self.collections)},
            "gc.pause_us_total": f"{self.pause_ns_total / 1e3:.0f}",
            "gc.pause_us_max": f"{self.pause_ns_max / 1e3:.1f}",
            "gc.pauses_over_100us": str(self.pauses_over_100us),
            "gc.startup_pause_us": f"{self.startup_pause_ns / 1e3:.0f}",
        }
