"""PipelineStats (nodes/diagnostics.py): the /diagnostics figures of a period, from known
samples: percentiles, rates' counters, rejection totals, level and message."""

from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticStatus

from forearm_dynamics.nodes.diagnostics import PipelineStats

pytestmark = pytest.mark.unit


def values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_one_period_of_known_samples() -> None:
    stats = PipelineStats(["name_unknown", "not_finite"])
    for i in range(1, 101):  # compute 1..100 µs, latency 2..200 µs, publish 0.4 i µs
        stats.record(compute_ns=i * 1000, latency_ns=2 * i * 1000, publish_ns=400 * i)
    stats.received, stats.published, stats.warmup = 103, 100, 2
    stats.rejected["not_finite"] = 3
    stats.resets["stamp_gap"] = 1
    st = stats.status("torque_node: pipeline", "hw")
    v = values(st)
    # numpy's linear percentiles of 1..100: p50 50.5, p99 99.01, max 100
    assert (v["compute_us_p50"], v["compute_us_p99"], v["compute_us_max"]) == ("50.5", "99.0", "100.0")
    assert (v["latency_us_p50"], v["latency_us_p99"], v["latency_us_max"]) == ("101.0", "198.0", "200.0")
    assert (v["publish_us_p50"], v["publish_us_max"]) == ("20.2", "40.0")
    assert (v["own_us_p50"], v["own_us_max"]) == ("30.3", "60.0")  # compute - publish
    assert (v["received_total"], v["processed_total"], v["warmup_total"]) == ("103", "100", "2")
    assert (v["rejected_total"], v["rejected.not_finite"], v["rejected.name_unknown"]) == ("3", "3", "0")
    assert (v["reset.stamp_gap"], v["reset.stamp_jump_back"]) == ("1", "0")
    assert float(v["input_rate_hz"]) > float(v["output_rate_hz"]) > 0  # 103 vs 100 in one span
    assert st.level == DiagnosticStatus.WARN and st.message == "3 sample(s) rejected"
    assert (st.name, st.hardware_id) == ("torque_node: pipeline", "hw")

    # the next period has no samples: no timing figures, totals kept, "no input"
    nxt = stats.status("torque_node: pipeline")
    w = values(nxt)
    assert w["compute_us_p50"] == w["latency_us_p99"] == "nan"
    assert (w["received_total"], w["rejected_total"]) == ("103", "3")
    assert float(w["input_rate_hz"]) == float(w["output_rate_hz"]) == 0.0
    assert nxt.level == DiagnosticStatus.OK and nxt.message == "no input"


def test_ring_keeps_the_last_window_of_a_period() -> None:
    stats = PipelineStats([], window=8)
    for i in range(1, 101):
        stats.record(compute_ns=i * 1000, latency_ns=0)
    stats.received = stats.published = 100
    v = values(stats.status("x"))
    assert (v["compute_us_p50"], v["compute_us_max"]) == ("96.5", "100.0")  # samples 93..100
    st = stats.status("x")
    assert st.message == "no input"
