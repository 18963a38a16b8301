"""`make bench` harness in its tiny mode (--quick): the JSON has the documented keys and sane,
self-consistent values. Timing targets are the benchmark's business, not asserted here."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import rosproc

PERCENTILES = ("n", "p50", "p99", "p99_9", "max", "mean")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "results.json"
    proc = subprocess.run(
        [sys.executable, "-m", "forearm_dynamics.bench", "--quick", "--out", str(out),
         "--domain", str(rosproc.domain_id())],
        env=rosproc.ros_env(), capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "## torque path" in proc.stdout  # the table
    return json.loads(out.read_text())


def test_top_level_keys(results) -> None:
    for key in ("schema", "mode", "command", "started", "wall_time_s", "domain_id", "machine",
                "versions", "compute", "torque_path", "choices", "recorder", "offline", "goals"):
        assert key in results, key
    assert results["mode"] == "quick"
    assert results["machine"]["cores"] >= 1 and results["machine"]["python"]


def test_compute_floor(results) -> None:
    ps = results["compute"]["per_sample"]
    for call in ("inverse_dynamics", "bare_rnea"):
        assert set(PERCENTILES) <= set(ps[call])
        assert 0 < ps[call]["p50"] <= ps[call]["p99"] <= ps[call]["max"]
    assert ps["ratio_p50"] == pytest.approx(ps["inverse_dynamics"]["p50"] / ps["bare_rnea"]["p50"])
    assert ps["ratio_p99"] > 0


def test_torque_path_counts_are_consistent(results) -> None:
    tp = results["torque_path"]
    assert set(tp["variants"]) == {"null_echo_node", "torque_node"}  # no recorder variant in quick
    for name, r in tp["variants"].items():
        assert r["sent"] == r["expected"] == 1500, name  # one movement, 1.5 s at 1 kHz
        assert r["received"] == r["unique"] + r["duplicates"]
        assert r["lost"] == max(r["sent"] - r["unique"], 0)
        assert 0 <= r["loss_fraction"] <= 1
        assert r["rate_hz"] > 0 and r["input_rate_hz"] > 0
        lat = r["latency_ms"]
        assert set(PERCENTILES) <= set(lat) and lat["n"] == r["received"]
        assert 0 < lat["p50"] <= lat["p99"] <= lat["p99_9"] <= lat["max"]
        cb = r["callback_us"]
        assert cb["periods"] >= 1 and 0 < cb["p50"] <= cb["p99"] <= cb["p99_worst_period"]
        node = r["node_process"]
        assert node["cpu_percent"] > 0 and node["peak_rss_mb"] > 0
        assert node["rss_start_mb"] > 0 and node["rss_end_mb"] <= node["peak_rss_mb"] + 1e-9
        assert r["exit_codes"][name] == 0, r["exit_codes"]
    assert set(tp["ratio_to_null"]) == {"latency_p50", "latency_p99", "callback_p50",
                                        "callback_p99", "cpu"}
    assert all(v > 0 for v in tp["ratio_to_null"].values())


def test_recorder_counts_are_consistent(results) -> None:
    rec = results["recorder"]
    assert rec["topics"] == 4 and rec["exit_code"] == 0 and rec["bag_bytes"] > 0
    assert rec["steps"] and rec["sustained_msgs_per_s"] > 0
    for s in rec["steps"]:
        assert s["written"] + s["dropped"] == s["sent"] > 0
        assert s["offered_msgs_per_s"] > 0 and s["written_msgs_per_s"] > 0
    assert rec["nominal_dropped"] == rec["steps"][0]["dropped"]
    assert 0 <= rec["max_rate_kept_up_msgs_per_s"] <= max(s["offered_msgs_per_s"] for s in rec["steps"])


def test_offline_and_goals(results) -> None:
    off = results["offline"]
    assert off["reproduce_paper"]["skipped"]  # quick mode
    for kind in ("anatomical", "solid", "segmented"):
        b = off["batch"][kind]
        assert b["samples"] == 97500 and b["samples_per_s"] > 0
    assert results["choices"]["skipped"]
    for g in results["goals"].values():
        assert {"target", "value", "met"} <= set(g)
