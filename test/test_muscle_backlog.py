"""muscle_node's own input queue (nodes/muscle_backlog.py) without ROS: what it counts.

A fake reader hands (bytes, info) as rclpy's take_message(raw=True) does. The queue must keep
every sample in order, drop only past its limit (oldest first) and count each drop, and
count the samples missing between the publication sequence numbers it sees: those the
executor handed (one each, numbers unknown) are not missing, a DDS queue overflow is, a
restarted writer (numbers from 1 again) is not."""

from __future__ import annotations

import pytest

from forearm_dynamics.nodes.muscle_backlog import InputBacklog

pytestmark = pytest.mark.unit


class Reader:
    def __init__(self):
        self.waiting: list[int] = []

    def publish(self, *seqs: int) -> None:
        self.waiting += seqs

    def take(self):
        if not self.waiting:
            return None
        s = self.waiting.pop(0)
        return f"s{s}".encode(), {"publication_sequence_number": s}


def test_every_sample_kept_in_order_and_delivered_ones_are_no_gap():
    r = Reader()
    b = InputBacklog(r.take, limit=100)
    r.publish(1, 2, 3)
    assert b.drain() == 3
    b.delivered()  # seq 4, handed by the executor
    b.delivered()  # seq 5
    r.publish(6, 7)
    b.drain()
    assert list(b.pending) == [b"s1", b"s2", b"s3", b"s6", b"s7"]
    assert b.gaps == 0 and b.dropped == 0 and b.drained == 5
    assert b.drain() == 0  # nothing waiting


def test_a_reader_overflow_is_counted_as_gaps():
    r = Reader()
    b = InputBacklog(r.take, limit=100)
    r.publish(1, 2)
    b.drain()
    b.delivered()  # 3
    r.publish(10, 11)  # 4..9 never reached the node (the DDS queue dropped them)
    b.drain()
    assert b.gaps == 6
    v = b.period_values()
    assert v["input_gaps_total"] == "6" and v["backlog_samples"] == "4"


def test_a_restarted_writer_is_followed_not_counted():
    r = Reader()
    b = InputBacklog(r.take, limit=100)
    r.publish(500, 501)
    b.drain()
    r.publish(1, 2, 3)  # torque_node restarted
    b.drain()
    assert b.gaps == 0


def test_past_the_limit_the_oldest_are_dropped_and_counted():
    r = Reader()
    b = InputBacklog(r.take, limit=4)
    r.publish(*range(1, 8))
    b.drain()
    assert list(b.pending) == [b"s4", b"s5", b"s6", b"s7"]
    assert b.dropped == 3 and b.gaps == 0
    assert b.period_values()["backlog_max_samples"] == "4"
    assert b.max_total == 4
