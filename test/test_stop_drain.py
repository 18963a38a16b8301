"""The drain after a stop signal (nodes/common.spin's `drain`, bag_recorder's drain_on_stop):
the callbacks already queued run until the node's progress stops moving, never past the
cap. The executor here is a stand-in (a queue of pending callbacks); the recorder's whole
stop is test_bag_recorder.py and test_stop_signals.py on real processes."""

from __future__ import annotations

import time

import pytest
import rclpy

from forearm_dynamics.nodes import common

pytestmark = pytest.mark.unit


class Queue:
    """spin_once runs one pending callback (a write), or waits its timeout when none is."""

    def __init__(self, pending: int, refill: bool = False):
        self.pending, self.refill, self.written = pending, refill, 0

    def spin_once(self, timeout_sec: float) -> None:
        if self.pending or self.refill:
            self.pending = max(self.pending - 1, 0)
            self.written += 1
        else:
            time.sleep(timeout_sec)


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    yield ctx
    rclpy.shutdown(context=ctx)


def test_the_drain_writes_what_is_queued_then_stops(context, monkeypatch) -> None:
    monkeypatch.setattr(common.rclpy, "ok", lambda: context.ok())
    q = Queue(500)
    t0 = time.monotonic()
    common._drain(q, 2.0, lambda: q.written)
    assert q.written == 500 and q.pending == 0
    assert time.monotonic() - t0 < 2 * common.DRAIN_IDLE_S + 0.5  # one idle wait, then out


class TimerFirst(Queue):
    """A timer's callback (no write) runs before each tenth message, as the recorder's flush
    and discovery timers do between its readers' callbacks."""

    turns = 0

    def spin_once(self, timeout_sec: float) -> None:
        self.turns += 1
        if self.turns % 10 != 1:
            super().spin_once(timeout_sec)


def test_a_timer_turn_does_not_end_the_drain(context, monkeypatch) -> None:
    monkeypatch.setattr(common.rclpy, "ok", lambda: context.ok())
    q = TimerFirst(300)
    common._drain(q, 2.0, lambda: q.written)
    assert q.written == 300 and q.pending == 0


def test_the_drain_ends_at_its_cap_when_messages_keep_coming(context, monkeypatch) -> None:
    monkeypatch.setattr(common.rclpy, "ok", lambda: context.ok())
    q = Queue(0, refill=True)
    t0 = time.monotonic()
    common._drain(q, 0.2, lambda: q.written)
    assert 0.2 <= time.monotonic() - t0 < 1.0 and q.written > 0


def test_no_drain_without_a_context(monkeypatch) -> None:
    monkeypatch.setattr(common.rclpy, "ok", lambda: False)
    q = Queue(5)
    common._drain(q, 2.0, lambda: q.written)
    assert q.written == 0
