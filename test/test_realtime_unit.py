"""The ROS-free parts of real-time scheduling and deadline accounting (no processes)."""

from __future__ import annotations

import os
import threading

import pytest

from forearm_dynamics import realtime
from forearm_dynamics.deadlines import REASONS_INPUT, REASONS_TIMER, Deadlines
from forearm_dynamics.nodes.params import ParameterError
from forearm_dynamics.nodes.scheduling import parse_cpus

pytestmark = pytest.mark.unit
MS = 1_000_000


@pytest.mark.parametrize(("text", "cpus"), [("", ()), ("1", (1,)), ("0,2", (0, 2)),
                                            ("2-4", (2, 3, 4)), (" 3, 0-1 ", (0, 1, 3)),
                                            ([1, 0, 1], (0, 1))])
def test_cpu_lists_in_taskset_syntax_or_integers(text, cpus):
    assert parse_cpus("cpu_affinity", text) == cpus


@pytest.mark.parametrize("bad", ["a", "3-1", "1-x", [-1], [True], 1.5])
def test_bad_cpu_lists_are_refused_naming_the_parameter(bad):
    with pytest.raises(ParameterError, match="cpu_affinity"):
        parse_cpus("cpu_affinity", bad)


def test_priority_out_of_range_is_refused():
    with pytest.raises(ValueError, match="1-99"):
        realtime.RealtimeRequest(priority=100)
    assert not realtime.RealtimeRequest().wanted
    assert realtime.RealtimeRequest(cpu_affinity=(0,)).wanted


def test_threads_read_from_proc_name_policy_priority():
    ready, stop = threading.Event(), threading.Event()

    def named():
        realtime.set_thread_name("a (b) c")  # parentheses and spaces in comm
        ready.set()
        stop.wait()

    t = threading.Thread(target=named)
    t.start()
    try:
        ready.wait(5)
        mine = {x.tid: x for x in realtime.read_threads()}
        assert mine[t.native_id].name == "a (b) c"
        assert mine[t.native_id].policy == realtime.read_thread(os.getpid(), os.getpid()).policy
        assert all(x.policy in ("normal", "fifo", "rr", "batch", "idle") for x in mine.values())
    finally:
        stop.set()
        t.join()


def test_apply_nothing_changes_nothing_and_reads_back():
    before = realtime.read_threads()
    state = realtime.apply(realtime.RealtimeRequest())
    assert state.warnings == []
    assert [(t.tid, t.policy, t.priority) for t in state.threads if t.tid in {b.tid for b in before}] \
        == [(t.tid, t.policy, t.priority) for t in before]
    assert state.describe()["requested_priority"] == 0
    assert tuple(sorted(os.sched_getaffinity(0))) == state.cpus


def test_cpus_this_process_may_not_use_are_one_warning_and_nothing_changes():
    cpus = os.sched_getaffinity(0)
    state = realtime.apply(realtime.RealtimeRequest(cpu_affinity=(max(cpus) + 64,)))
    assert len(state.warnings) == 1 and "not available" in state.warnings[0]
    assert os.sched_getaffinity(0) == cpus


def test_throttling_is_stated():
    text = realtime.throttling()
    assert "us" in text or text == "unknown"


def test_input_deadline_reasons_and_worst():
    d = Deadlines(1.0, REASONS_INPUT)
    d.check_input(100_000, 200_000)  # 0.3 ms: on time
    d.check_input(5 * MS, 100_000)  # waited 5 ms: queued
    d.check_input(0, 2 * MS)  # its own 2 ms: compute
    d.check_input(-10**18, 3 * MS)  # a recorded (not live) stamp: the wait is unknown
    d.check_input(10**18, 200_000)  # far past stamp: not live, on time on its own
    assert d.checked == 5
    assert d.missed == {"queued": 1, "compute": 2}
    assert d.worst_ns == 5 * MS + 100_000
    v = d.values()
    assert v["deadline_missed_total"] == "3" and v["deadline_worst_ms"] == "5.100"
    assert "missed 3 of 5" in d.summary() and "queued 1, compute 2" in d.summary()


def test_timer_deadline_reasons_and_dropped_periods():
    d = Deadlines(1.0, REASONS_TIMER)
    d.check_timer(300_000, 100_000)
    d.check_timer(2 * MS, 100_000)
    d.check_timer(100_000, 3 * MS)
    d.dropped(60, 60 * MS)
    assert d.missed == {"timer_late": 1, "compute": 1, "dropped": 60}
    assert d.checked == 63 and d.worst_ns == 60 * MS


def test_deadline_zero_counts_nothing():
    d = Deadlines(0.0, REASONS_INPUT)
    d.check_input(10 * MS, 10 * MS)
    assert d.checked == 0 and d.values() == {"deadline_ms": "0 (not counted)"}
    assert "not counted" in d.summary()


def test_how_far_behind_is_the_largest_live_wait_per_take():
    """stream_node warns from it; a recorded stamp (not live) says nothing of the node, and
    deadline_ms 0 (nothing counted) still measures it."""
    for deadline_ms in (1.0, 0.0):
        d = Deadlines(deadline_ms, REASONS_INPUT)
        d.check_input(300 * MS, 100_000)
        d.check_input(700 * MS, 100_000)
        d.check_input(10**18, 100_000)  # a recorded stamp: not live
        d.check_input(-5 * MS, 100_000)  # a stamp ahead of this clock: not live
        assert d.take_behind() == 700 * MS
        assert d.take_behind() == 0  # afresh
        d.check_input(2 * MS, 0)
        assert d.take_behind() == 2 * MS
