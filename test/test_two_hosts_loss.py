"""Two hosts and a lossy link (issue 23): torque_node in host A, trajectory_publisher +
bag_recorder in host B, 10 movements at 1 kHz (15 000 samples), N % of A's incoming UDP
(or of both directions) dropped at random by nftables. Correctness only; the timing of the
same runs is benchmarks/two_hosts.py's (docs/two-hosts.md "Measured").

- Reliable (the default QoS): nothing lost, every torque right (check_bag exits 0 on B's bag).
  The link's losses are repaired; what a reliable KEEP_LAST reader cannot keep is what its
  process falls behind by past its depth (1 s at 1 kHz, docs/two-hosts.md), and a shared
  machine gives no process that at normal priority (a second `make test` beside this one:
  torque_node 1.7 s behind, 1 382 of 15 000 lost at 1 % loss both ways). So in these cases
  the torque node and B's recorder, the two readers the claim is about, run at SCHED_FIFO
  50 (their realtime_priority parameter, docs/realtime.md), and the test checks they did.
- Best-effort input: the loss is counted and is the input's (every sample the node got was
  answered, every answer reached B over the reliable output), the link's drops show in it,
  and never a wrong torque (check_bag on B's bag, loss allowed: exit 0).

`make test-hosts` (root). ~45 s per case.
"""

from __future__ import annotations

import pytest
import rosproc

from benchmarks.two_host_run import Case, hostkit, run_case

pytestmark = pytest.mark.hosts

_why = hostkit.can_make_hosts()
if _why:
    pytest.skip(_why, allow_module_level=True)

MOVEMENTS = 10
SAMPLES = 1500 * MOVEMENTS

CASES = (
    Case("reliable_0", 0),
    Case("reliable_1", 1),
    Case("reliable_5", 5),
    Case("reliable_1_both", 1, both=True),
    Case("reliable_lossy_profile_5_both", 5, both=True, profile=True),
    Case("best_effort_1", 1, best_effort=True),
    Case("best_effort_5", 5, best_effort=True),
    Case("best_effort_5_both", 5, both=True, best_effort=True),
)


def _why_failed(r: dict) -> str:
    keep = ("case", "exits", "sent", "node_received", "node_processed", "lost", "packets_dropped",
            "missing_before_first_answer", "node_input_matched_ns", "first_input_ns",
            "udp", "longest_missing_run", "loadavg_start", "drained", "check_bag_exit", "scheduling")
    return (f"{ {k: r.get(k) for k in keep} }\ncheck_bag: {r['check_bag_tail']}\n"
            f"node: {r['node_log_tail']}")


#: Samples a lossy best-effort link may drop before the first answer (test_loss_case); a
#: discovery race loses tens to hundreds. Measured at 5 % both ways (best_effort_5_both, CI
#: and 26 runs on one machine, 2026-12-07): the first answer came after 0 lost samples in
#: 23 runs, 1 in 2, 3 in 2. Three in a row is 1.25e-4 a run by independent drops, so the
#: start is lossier than the rest, cause not found: each sample was its own datagram and
#: reached A's interface (an AF_PACKET capture of 10 runs), and the node's input was matched
#: >= 4 s before the stream. 5 keeps a race apart from that.
FIRST_DROPS_BEST_EFFORT = 5
#: the readers of a reliable case at FIFO 50 (see the module docstring); root runs this tier
REALTIME = ("-p", "realtime_priority:=50")


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_loss_case(case: Case, tmp_path):
    domain = rosproc.test_domain(102, 139)
    rt = () if case.best_effort else REALTIME
    r = run_case(case, MOVEMENTS, domain, tmp_path, node_args=rt, recorder_args=rt)
    why = _why_failed(r)
    assert r["exits"] == {"publisher": 0, "recorder": 0, "node": 0}, why
    if rt:  # what each got, in its own words (realtime.apply reads it back from /proc)
        for who, line in r["scheduling"].items():
            assert line and line.startswith("scheduling: fifo 50 (") and " 0 of " not in line, \
                f"{who}: {line}\n{why}"
    # the publisher sent its samples (a tick later than 0.5 s skips some: then fewer) and B's
    # own recording holds every one: the count every loss below is measured against
    assert 0.9 * SAMPLES <= r["sent"] <= SAMPLES and r["inputs_recorded"] == r["sent"], why
    # the hosts found each other first: the node's input was matched before B's first sample
    # (its log line comes at or after the match; same clock as the stamps) ...
    assert r["node_input_matched_ns"] is not None and r["first_input_ns"] is not None, why
    assert r["node_input_matched_ns"] < r["first_input_ns"], why
    # ... so no sample is lost to discovery (a race loses the first tens to hundreds at 1 kHz).
    # A best-effort case's link drops the first ones too: up to FIRST_DROPS_BEST_EFFORT
    allowed = FIRST_DROPS_BEST_EFFORT if case.best_effort and case.loss else 0
    assert r["missing_before_first_answer"] <= allowed, why
    # B's recording holds an answer for every sample the node processed before it stopped
    # (the last answers' repairs waited for, not a fixed grace: two_host_run._drain)
    assert r["drained"], why
    if case.loss:  # the rule really dropped packets: at least half its share of the samples
        assert r["packets_dropped"] >= 0.5 * case.loss / 100 * r["sent"], why
    else:
        assert r["packets_dropped"] == 0, why
    delivery = r["check"]["delivery"]
    assert r["node_processed"] == r["node_received"], why  # every sample in was answered
    assert r["torques"] == r["unique"], why  # and once
    if not case.best_effort:
        assert r["lost"] == 0 and delivery["lost"] == 0, why
        assert r["node_received"] == r["sent"], why
        assert r["check_bag_exit"] == 0, why  # every torque right
        return
    # best effort: what is lost is what the node's input lost (the reliable output to B lost
    # nothing), it is at least half the link's share (the loss is real and counted), the
    # stream works (most samples answered; the link's share is the benchmark's figure), and
    # every torque recorded is right
    assert r["lost"] == r["sent"] - r["node_received"], why
    assert delivery["lost"] <= r["lost"], why  # check_bag counts it too (but the last 0.1 s)
    assert r["lost"] >= 0.5 * case.loss / 100 * r["sent"], why
    assert r["lost"] < 0.5 * r["sent"], why
    assert r["check_bag_exit"] == 0, why
