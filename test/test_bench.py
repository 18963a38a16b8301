"""`make bench` harness in its tiny mode (--quick): the JSON has the documented keys and sane,
self-consistent values. Timing targets are the benchmark's business, not asserted here."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import pytest
import rosproc

pytestmark = [pytest.mark.ros, pytest.mark.slow]

PERCENTILES = ("n", "p50", "p99", "p99_9", "max", "mean")
ROOT = Path(__file__).resolve().parents[1]  # `python -m benchmarks` runs from the repository
#: A section another benchmark wrote before (e.g. benchmarks/estimation.py): must be kept.
FOREIGN = {"estimation": {"note": "written by another benchmark", "value": 1.5}}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "results.json"
    out.write_text(json.dumps({**FOREIGN, "sections": {"estimation": {"command": "x"}}}))
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks", "--quick", "--out", str(out),
         "--domain", str(rosproc.domain_id())],
        env=rosproc.ros_env(), cwd=ROOT, capture_output=True, text=True, timeout=180,
        check=False)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "## torque path" in proc.stdout  # the table
    return json.loads(out.read_text()), proc.stderr


@pytest.fixture(scope="module")
def results(run):
    return run[0]


@pytest.fixture(scope="module")
def bench_stderr(run):
    return run[1]


def test_run_description(results, bench_stderr) -> None:
    assert results["mode"] == "quick" and results["schema"] == 1
    # asked for the domain this session holds: the benchmark moved to a free one, said so,
    # and ran there (every section below needed its nodes to find each other)
    assert results["domain_id"] != rosproc.domain_id() and 0 < results["domain_id"] < 102
    assert (f"benchmarks: ROS domain {rosproc.domain_id()} is in use by another forearm_dynamics "
            f"run on this machine; using {results['domain_id']}") in bench_stderr
    assert results["command"].endswith(f"--domain {rosproc.domain_id()}") and "--quick" in results["command"]
    started = time.mktime(time.strptime(results["started"][:19], "%Y-%m-%dT%H:%M:%S"))
    assert 0 < time.time() - started < 3600  # this run's, not a stale file's
    assert results["machine"]["cores"] == os.cpu_count()
    assert results["machine"]["python"] == platform.python_version()
    assert len(results["machine"]["loadavg_start"]) == len(results["machine"]["loadavg_end"]) == 3
    assert results["versions"]["forearm_dynamics"] == metadata.version("forearm_dynamics")
    assert results["versions"]["numpy"] == metadata.version("numpy")


def test_other_sections_are_kept(results) -> None:
    """Sections are written independently: another benchmark's section survives this run."""
    assert results["estimation"] == FOREIGN["estimation"]
    assert results["sections"]["estimation"] == {"command": "x"}
    for key in ("compute", "torque_path", "choices", "recorder", "offline", "goals"):
        assert results["sections"][key] == {"command": results["command"],
                                            "started": results["started"]}, key


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
    t, n = tp["variants"]["torque_node"], tp["variants"]["null_echo_node"]
    assert tp["ratio_to_null"] == pytest.approx({
        "latency_p50": t["latency_ms"]["p50"] / n["latency_ms"]["p50"],
        "latency_p99": t["latency_ms"]["p99"] / n["latency_ms"]["p99"],
        "callback_p50": t["callback_us"]["p50"] / n["callback_us"]["p50"],
        "callback_p99": t["callback_us"]["p99"] / n["callback_us"]["p99"],
        "cpu": t["node_process"]["cpu_percent"] / n["node_process"]["cpu_percent"]})


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
    goals, t = results["goals"], results["torque_path"]["variants"]["torque_node"]
    assert goals["lost_0"]["value"] == t["lost"] and goals["lost_0"]["met"] == (t["lost"] == 0)
    p99 = t["latency_ms"]["p99"]
    assert goals["latency_p99_ms_lt_1"] == {"target": "< 1 ms", "value": p99, "met": p99 < 1.0}
    ratio = results["compute"]["per_sample"]["ratio_p50"]
    assert goals["per_sample_id_ratio_le_1.3"]["value"] == ratio
    assert goals["per_sample_id_ratio_le_1.3"]["met"] == (ratio <= 1.3)
    cpu = t["node_process"]["cpu_percent"]
    assert goals["cpu_percent_lt_50"]["value"] == cpu and goals["cpu_percent_lt_50"]["met"] == (cpu < 50)
