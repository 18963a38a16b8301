"""Hostile joint_states against a real torque_node process over loopback DDS.

Each bad sample sits in a constant-acceleration stream: good g0 (after a pause: warm-up),
g1, the bad sample(s), g2. For each: the node keeps running; nothing is published from
the bad sample; the reason is counted in /diagnostics exactly once per bad sample and
shows in the log (rate-limited); and g2 gets the exact torque of a real acceleration
estimate across the gap, i.e. the bad sample left the estimator untouched.
test_torque_node.py already covers one NaN position, one inf velocity, a short position,
a short velocity, a missing and a duplicated joint, an equal and a slightly earlier stamp,
a zero stamp and a message without names; this file covers the rest of the matrix.
"""

from __future__ import annotations

import math
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from faultkit import (
    GRAVITY,
    MODEL,
    MS,
    POSTURE,
    TorqueHarness,
    cdr_stamp,
    joint_state,
    stamp_of,
    start_feeder,
)
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from forearm_dynamics import JOINT_NAMES
from forearm_dynamics.nodes import validation as v
from forearm_dynamics.nodes.common import stream_qos

pytestmark = [pytest.mark.faults, pytest.mark.ros]

RNG = np.random.default_rng(3)
V0, ACC = RNG.uniform(-1, 1, 20), RNG.uniform(-15, 15, 20)
HOUR = 3600 * 1_000_000_000
BAD_Q = POSTURE + 0.25  # a bad sample's positions: any reply carrying them is a leak


@pytest.fixture(scope="module")
def h(module_procs):
    harness = TorqueHarness(module_procs)
    harness.diag.fresh(lambda d: "received_total" in d)  # every test starts from known counts
    yield harness
    harness.close()
    assert harness.proc.stop(signal.SIGINT) == 0, harness.proc.output()[-3000:]
    assert "Traceback" not in harness.proc.output()


def ramp(t0: int, t_ns: int):
    """q, qd of the constant-acceleration stream at stamp t_ns (stream starts at t0)."""
    t = (t_ns - t0) / 1e9
    return POSTURE + V0 * t + 0.5 * ACC * t * t, V0 + ACC * t


def expect(reply: JointState, t0: int, qdd) -> None:
    q, qd = ramp(t0, stamp_of(reply))
    assert list(reply.name) == list(JOINT_NAMES)
    np.testing.assert_allclose(reply.position, q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reply.velocity, qd, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reply.effort, MODEL.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-8)


# -- the bad samples (g1 = the good sample before; its stamp in ns) -------------------------
def _field(field: str, value: float, where: str):
    def make(g1: int, t0: int):
        t = g1 + MS // 2
        q, qd = ramp(t0, t)
        arrays = {"position": list(BAD_Q), "velocity": list(qd), "effort": list(GRAVITY)}
        if field == "effort":  # effort is not an input: the sample is good apart from it
            arrays["position"] = list(q)
        idx = {"first": [0], "last": [19], "all": list(range(20))}[where]
        for i in idx:
            arrays[field][i] = value
        return [joint_state(t, arrays["position"], arrays["velocity"], effort=arrays["effort"])]
    return make


def _lengths(kind: str):
    def make(g1: int, t0: int):
        m = joint_state(g1 + MS // 2, BAD_Q)
        if kind == "position_longer":
            m.position = [*m.position, 0.0]
        elif kind == "position_empty":
            m.position = []
        elif kind == "velocity_longer":
            m.velocity = [*m.velocity, 0.0]
        elif kind == "effort_shorter":
            m.effort = [0.0] * 19
        elif kind == "effort_longer":
            m.effort = [0.0] * 21
        elif kind == "names_only":
            m.position, m.velocity = [], []
        return [m]
    return make


def _names(kind: str):
    def make(g1: int, t0: int):
        t = g1 + MS // 2
        names, q = list(JOINT_NAMES), list(BAD_Q)
        if kind == "unknown":
            names = [f"joint_{i}" for i in range(20)]
        elif kind == "wrong_case":
            names = [n.upper() for n in names]
        elif kind == "missing_last":
            names, q = names[:-1], q[:-1]
        elif kind == "duplicate_extra":
            names, q = [*names, "gripper", "gripper"], [*q, 0.0, 0.0]
        elif kind.startswith("count_"):
            n = int(kind.removeprefix("count_"))
            names = [f"extra_{i}" for i in range(n - 20)] + names
            q = [0.0] * (n - 20) + q
            if kind == "count_1024":  # the limit itself is fine: a good sample on the ramp
                q_good, qd_good = ramp(t0, t)
                return [joint_state(t, q[:-20] + list(q_good), [0.0] * (n - 20) + list(qd_good),
                                    names)]
        return [joint_state(t, q, None, names)]
    return make


def _default_message(g1: int, t0: int):
    return [JointState()]


def _stamps(kind: str):
    def make(g1: int, t0: int):
        if kind == "equal_x100":
            return [joint_state(g1, BAD_Q) for _ in range(100)]
        if kind == "backwards_x50":
            return [joint_state(g1 - k * MS, BAD_Q) for k in range(1, 51)]
        if kind == "forward_2h":
            return [joint_state(g1 + 2 * HOUR, BAD_Q)]
        if kind == "back_2h_live":
            return [joint_state(g1 - 2 * HOUR, BAD_Q)]
        m = joint_state(g1 + MS // 2, BAD_Q)
        if kind == "nanosec_overflow":
            m.header.stamp.nanosec = 1_500_000_000
        elif kind == "negative":
            m.header.stamp.sec = -5
        return [m]
    return make


# case -> (make bad samples, rejection reason or None when the sample is good)
CASES = {
    "nan/position/first": (_field("position", math.nan, "first"), v.NON_FINITE),
    "inf/position/last": (_field("position", math.inf, "last"), v.NON_FINITE),
    "-inf/position/all": (_field("position", -math.inf, "all"), v.NON_FINITE),
    "nan/velocity/all": (_field("velocity", math.nan, "all"), v.NON_FINITE),
    "inf/velocity/first": (_field("velocity", math.inf, "first"), v.NON_FINITE),
    "-inf/velocity/last": (_field("velocity", -math.inf, "last"), v.NON_FINITE),
    # effort is not an input (joint_state_broadcaster fills missing interfaces with NaN):
    # the sample is answered from its position and velocity, the NaN never reaches the output
    "nan/effort/all": (_field("effort", math.nan, "all"), None),
    "inf/effort/first": (_field("effort", math.inf, "first"), None),
    "-inf/effort/last": (_field("effort", -math.inf, "last"), None),
    # finite but absurd: the torque overflows; the estimator restarts (next sample: warm-up)
    "huge/velocity": (_field("velocity", 1e300, "all"), v.NON_FINITE_TORQUE),
    "length/position_longer": (_lengths("position_longer"), v.LENGTH_MISMATCH),
    "length/position_empty": (_lengths("position_empty"), v.LENGTH_MISMATCH),
    "length/velocity_longer": (_lengths("velocity_longer"), v.LENGTH_MISMATCH),
    "length/effort_shorter": (_lengths("effort_shorter"), v.LENGTH_MISMATCH),
    "length/effort_longer": (_lengths("effort_longer"), v.LENGTH_MISMATCH),
    "empty/default_message": (_default_message, v.EMPTY),
    "empty/names_only": (_lengths("names_only"), v.LENGTH_MISMATCH),
    "names/unknown": (_names("unknown"), v.MISSING_JOINT),
    "names/wrong_case": (_names("wrong_case"), v.MISSING_JOINT),
    "names/missing_last": (_names("missing_last"), v.MISSING_JOINT),
    "names/duplicate_extra": (_names("duplicate_extra"), v.DUPLICATE_NAME),
    "names/100000": (_names("count_100000"), v.TOO_MANY_NAMES),
    "names/1025": (_names("count_1025"), v.TOO_MANY_NAMES),
    "names/1024": (_names("count_1024"), None),
    "stamp/equal_x100": (_stamps("equal_x100"), v.STAMP_NOT_INCREASING),
    "stamp/backwards_x50": (_stamps("backwards_x50"), v.STAMP_NOT_INCREASING),
    "stamp/forward_2h": (_stamps("forward_2h"), v.STAMP_IN_FUTURE),
    "stamp/back_2h_live": (_stamps("back_2h_live"), v.STAMP_NOT_INCREASING),
    "stamp/nanosec_overflow": (_stamps("nanosec_overflow"), v.STAMP_INVALID),
    "stamp/negative": (_stamps("negative"), v.STAMP_INVALID),
}


@pytest.mark.parametrize("case", list(CASES))
def test_hostile_sample(h, case: str) -> None:
    make, reason = CASES[case]
    h.peer.spin_for(0.0)
    before = dict(h.diag.values)
    mark = len(h.proc.output())
    t0 = h.stamp(500 * MS)  # a pause: the estimator restarts (warm-up), as documented
    g0, g1, g2 = t0, t0 + MS, t0 + 2 * MS
    h.t_ns = g2
    bad = make(g1, t0)
    good = [joint_state(t, *ramp(t0, t)) for t in (g0, g1)]
    replies = h.exchange([*good, *bad, joint_state(g2, *ramp(t0, g2))])

    accepted = reason is None
    want = [g0, g1, *([stamp_of(b) for b in bad] if accepted else []), g2]
    assert [stamp_of(r) for r in replies] == want, "a reply that belongs to no good sample"
    assert not any(np.allclose(r.position[:20], BAD_Q) for r in replies)
    expect(replies[0], t0, np.zeros(20))  # warm-up after the pause
    for r in replies[1:-1]:
        expect(r, t0, ACC)
    # g2: a real estimate across the bad sample(s); after an overflow the estimator restarted
    expect(replies[-1], t0, np.zeros(20) if reason == v.NON_FINITE_TORQUE else ACC)
    assert h.proc.running()

    n_bad = 0 if accepted else len(bad)
    diag = h.diag.fresh(lambda d: int(d["received_total"]) >= int(before["received_total"]) + 3 + len(bad))
    rejected = int(diag["rejected_total"]) - int(before["rejected_total"])
    assert rejected == n_bad, diag
    if reason is not None:
        assert int(diag[f"rejected.{reason}"]) - int(before.get(f"rejected.{reason}", 0)) == n_bad
        deadline = time.monotonic() + 15  # a warning held back by the rate limit is flushed
        while f"rejected sample [{reason}]" not in h.log_since(mark):
            assert time.monotonic() < deadline, h.log_since(mark)
            h.peer.spin_for(0.1)
    assert int(diag["processed_total"]) - int(before["processed_total"]) == 3 + len(bad) - n_bad


def test_replayed_stream_jumping_back_is_a_restart(h) -> None:
    """The counterpart of back_2h_live: a source replaying old stamps (a bag) that jumps
    back is restarting, not lying; it is answered after an estimator reset."""
    h.peer.spin_for(1.5)  # the live stream before stopped > LIVE_WINDOW_S ago (a switch of source)
    before = dict(h.diag.values)
    t0 = time.time_ns() - 24 * HOUR  # yesterday's recording
    first = [t0, t0 + MS, t0 + 2 * MS]
    again = [t0 - 10_000 * MS + k * MS for k in range(3)]  # the replay loops
    msgs = [joint_state(t, *ramp(t0, t)) for t in first]
    msgs += [joint_state(t, *ramp(again[0], t)) for t in again]
    replies = h.exchange(msgs)
    assert [stamp_of(r) for r in replies] == first + again
    expect(replies[0], t0, np.zeros(20))  # the replay starts: warm-up
    expect(replies[2], t0, ACC)
    expect(replies[3], again[0], np.zeros(20))  # restarted: warm-up
    expect(replies[5], again[0], ACC)
    diag = h.diag.fresh(lambda d: int(d["processed_total"]) >= int(before["processed_total"]) + 6)
    assert int(diag["reset.stamp_jump_back"]) == int(before["reset.stamp_jump_back"]) + 2
    assert int(diag["rejected_total"]) == int(before["rejected_total"])
    h.t_ns = time.time_ns()


def _log_total(text: str, reason: str) -> int:
    """Rejections of `reason` the log accounts for: one per line plus every 'N more'."""
    total = 0
    for line in text.splitlines():
        if f"rejected sample [{reason}]" not in line:
            continue
        more = re.search(r"\+(\d+) more since|: (\d+) more in the last", line)
        total += 1 if more is None or more.group(1) else 0
        total += int(next(g for g in more.groups() if g)) if more else 0
    return total


def _resume(h) -> None:
    """The next good samples after a burst are answered with exact torques."""
    t0 = h.stamp(500 * MS)
    h.t_ns = t0 + 2 * MS
    replies = h.exchange([joint_state(t, *ramp(t0, t)) for t in (t0, t0 + MS, t0 + 2 * MS)])
    assert [stamp_of(r) for r in replies] == [t0, t0 + MS, t0 + 2 * MS]
    expect(replies[2], t0, ACC)


def test_burst_of_10000_bad_messages(h, procs, tmp_path) -> None:
    """10 000 NaN samples as fast as they can be sent: every one that arrives is refused
    and counted; the log says so in a few lines whose counts add up to the same number."""
    h.peer.spin_for(0.0)
    before = dict(h.diag.values)
    mark = len(h.proc.output())
    q = POSTURE.copy()
    q[4] = math.nan
    feeder, stamps_file, log = start_feeder(procs, tmp_path, h.domain, count=10_000, rate_hz=0,
                                            position=q, step_ns=10_000, drain=120.0)
    t_start = time.monotonic()
    h.peer.spin_until(lambda: feeder.poll() is not None, 240)
    assert feeder.returncode == 0, log.read_text()
    burst_s = time.monotonic() - t_start
    sent = [int(s) for s in stamps_file.read_text().split()]
    assert len(sent) == 10_000
    h.t_ns = max(h.t_ns, sent[-1])
    _resume(h)
    diag = h.diag.fresh()
    received = int(diag["received_total"]) - int(before["received_total"]) - 3
    refused = int(diag[f"rejected.{v.NON_FINITE}"]) - int(before[f"rejected.{v.NON_FINITE}"])
    assert refused == received >= 1000, (refused, received)  # >= depth: KEEP_LAST keeps the last
    assert int(diag["processed_total"]) - int(before["processed_total"]) == 3
    assert not set(sent) & {stamp_of(r) for r in h.replies}
    deadline = time.monotonic() + 5  # wait for the held-back count to be flushed
    while _log_total(h.log_since(mark), v.NON_FINITE) < refused and time.monotonic() < deadline:
        h.peer.spin_for(0.1)
    text = h.log_since(mark)
    lines = [ln for ln in text.splitlines() if f"[{v.NON_FINITE}]" in ln]
    assert _log_total(text, v.NON_FINITE) == refused, lines
    assert len(lines) <= 3 + burst_s + (time.monotonic() - t_start), lines  # about 1 line/s
    print(f"burst of 10000 NaN samples: {received} reached the node, {refused} refused, "
          f"{len(lines)} log lines")


def test_burst_of_10000_good_messages(h, procs, tmp_path) -> None:
    """10 000 good samples at once: the node survives and answers every sample it receives
    (exact torques); beyond the 1000-deep queues DDS drops the oldest (KEEP_LAST), which a
    real-time controller wants: stale samples are worth nothing. Then it serves normally."""
    h.peer.spin_for(0.0)
    before = dict(h.diag.values)
    h.replies.clear()
    feeder, stamps_file, log = start_feeder(procs, tmp_path, h.domain, count=10_000, rate_hz=0,
                                            step_ns=10_000, drain=120.0)
    h.peer.spin_until(lambda: feeder.poll() is not None, 240)
    assert feeder.returncode == 0, log.read_text()
    sent = [int(s) for s in stamps_file.read_text().split()]
    assert "all acknowledged" in log.read_text(), log.read_text()
    # a hang guard: the node answers the last sample once it has it (the feeder's writer saw
    # it acknowledged)
    assert h.peer.spin_until(lambda: any(stamp_of(r) == sent[-1] for r in h.replies), 120)
    burst = list(h.replies)
    h.t_ns = max(h.t_ns, sent[-1])
    _resume(h)
    diag = h.diag.fresh()
    received = int(diag["received_total"]) - int(before["received_total"]) - 3
    assert int(diag["processed_total"]) - int(before["processed_total"]) == received + 3
    assert int(diag["rejected_total"]) == int(before["rejected_total"])
    assert received >= 1000  # the last qos_depth samples always get through
    assert {stamp_of(r) for r in burst} <= set(sent)
    for r in burst:
        np.testing.assert_allclose(r.effort, GRAVITY, rtol=0, atol=1e-9)
    assert h.proc.running()
    print(f"burst of 10000 good samples: {received} reached the node and were answered, "
          f"{len(burst)} answers reached the test's subscriber")


def test_5khz_input_for_10s(procs, tmp_path) -> None:
    """50 000 samples at 5 kHz: every one answered, exact torques. The node runs with
    qos_depth 5000 = 1 s of input, the sizing rule of config/nodes/torque_node.yaml at 5 kHz.
    The feeder sends bursts of 2 500 (0.5 s at 5 kHz, half the queue) and waits for the
    last answer of each before the next: on a machine too busy to sustain 5 kHz the test
    takes longer instead of overflowing the queue (how fast the node is: make bench)."""
    fast = TorqueHarness(procs, "-p", "qos_depth:=5000")
    try:
        got: dict[int, bytes] = {}
        fast.peer.node.create_subscription(JointState, "joint_torques",
                                           lambda raw: got.__setitem__(cdr_stamp(raw), raw),
                                           stream_qos(5000), raw=True)
        before = fast.diag.fresh()
        feeder, stamps_file, log = start_feeder(procs, tmp_path, fast.domain, count=50_000,
                                                rate_hz=5000.0, depth=5000, burst=2500)
        fast.peer.spin_until(lambda: feeder.poll() is not None, 300)  # a bound, not a target
        assert feeder.returncode == 0, log.read_text()
        sent = [int(s) for s in stamps_file.read_text().split()]
        assert len(sent) == 50_000
        fast.peer.spin_until(lambda: sent[-1] in got, 20)
        diag = fast.diag.fresh()
        received = int(diag["received_total"]) - int(before["received_total"])
        processed = int(diag["processed_total"]) - int(before["processed_total"])
        # Completeness from the feeder's own subscriber: it paces the bursts by the answers,
        # so it keeps up; this test process's reader may fall more than the node's output
        # depth behind on a loaded machine, and then the node's writer drops old answers for
        # it alone (a slow reader, not a lost sample)
        answered = {int(s) for s in Path(str(stamps_file) + ".answers").read_text().split()}
        missing = [s for s in sent if s not in answered]
        assert received == processed == 50_000, (received, processed, fast.domain, before, diag)
        assert not missing, f"{len(missing)} of 50000 samples unanswered"
        checked = [s for s in sent[::97] if s in got]
        assert len(checked) > 0.5 * len(sent[::97])
        for s in checked:
            np.testing.assert_allclose(deserialize_message(got[s], JointState).effort, GRAVITY,
                                       rtol=0, atol=1e-9)
        elapsed = log.read_text().split()[-1]
        print(f"5 kHz for 10 s: 50000 sent in {elapsed} s, {received} received, "
              f"{len(got)} answered")
    finally:
        fast.close()
        assert fast.proc.stop(signal.SIGINT) == 0
