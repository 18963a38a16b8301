"""Peer: an rclpy node inside a process that is not a node itself (a test, a benchmark, a
harness), on a domain of its choosing, with its own Context and EventsExecutor.

Why its own Context: several peers in one process (a test session's modules, a benchmark's
parts) never share state, and closing one leaves the others running.

Why close() shuts the executor down: until an EventsExecutor is shut down it holds the
handle of every node it has spun, so destroy_node() only marks the node, and the node and
its endpoints stay discoverable for as long as the process lives (a test module's closed
peer answered in the next module's domain: test_processes).

Spin it from the calling thread (spin_for, spin_until) or from a thread of its own
(spin_in_background): a benchmark that publishes from its own loop wants the latter.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class Peer:
    """This process's node `name` on ROS domain `domain`; close() when done."""

    def __init__(self, name: str, domain: int):
        import rclpy
        from rclpy.experimental import EventsExecutor

        self.domain = domain
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.closed = False
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(deadline - time.monotonic(), 0.0)))

    def spin_until(self, predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
        """Spin until predicate() is true; False on timeout."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def spin_in_background(self) -> None:
        """Spin from a daemon thread of its own until close()."""
        def spin() -> None:
            while not self._stop.is_set() and self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)

        self._thread = threading.Thread(target=spin, name=f"peer_{self.node.get_name()}",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Leave the graph now (see the module docstring); a second call does nothing."""
        if self.closed:
            return
        self.closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()
        self.context.try_shutdown()
