"""The torque node's worker thread: builds requested models and publishes configs off the
executor thread, so a live parameter change never stalls the 1 kHz callback for a build.

It is given two callables, not the node: `build(request)` and `announce(bundle, stamp_ns)`;
what they do (build a bundle, publish a config message) is the node's business.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from ..realtime import make_normal, set_thread_name
from .torque_config import ModelBundle, ModelRequest


class ModelBuilder:
    """One worker thread that builds requested bundles; the newest request wins."""

    def __init__(self, build: Callable[[ModelRequest], None],
                 announce: Callable[[ModelBundle, int], None]):
        self._build = build
        self._publish = announce
        self._cv = threading.Condition()
        self._request: ModelRequest | None = None
        self._announcements: list[tuple[ModelBundle, int]] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="model_builder", daemon=True)
        self._thread.start()
        self.native_id: int = self._thread.native_id  # set once started


    def submit(self, request: ModelRequest) -> None:
        with self._cv:
            self._request = request
            self._cv.notify()

    def announce(self, bundle: ModelBundle, stamp_ns: int) -> None:
        """Publish `bundle`'s config as applied from `stamp_ns` (off the executor thread)."""
        with self._cv:
            self._announcements.append((bundle, stamp_ns))
            self._cv.notify()

    def stop(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        # A helper: named for top -H and /proc, and at normal priority whatever its creator
        # had (a real-time thread would start it at FIFO; docs/realtime.md).
        set_thread_name("model_builder")
        make_normal()
        while True:
            with self._cv:
                while self._request is None and not self._announcements and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
                announcements, self._announcements = self._announcements, []
                request, self._request = self._request, None
            for bundle, stamp_ns in announcements:
                self._publish(bundle, stamp_ns)
            if request is None:
                continue
            # Measured (benchmarks/torque_node_rate.py, 2 loaded cores): a build (~2-5 ms)
            # delays the samples that arrive meanwhile by ~2 ms (p50) whatever is tried:
            # sys.setswitchinterval(1e-5 or 1e-3) during the build only made it slower
            # (request -> first new sample ~8 ms instead of ~4 ms), and this thread at nice
            # 19 was worse still (it holds the GIL while descheduled). So: plain.
            self._build(request)
