"""docs/reliability.md's whole-pipeline disk-writer row is the committed benchmark output
(benchmarks/pipeline_disk_load.py), and the runs it reports are consistent: the quiet run lost
nothing, and a run that lost samples failed check_bag."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from benchmarks import pipeline_disk_load as bench

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]

RESULT = ROOT / "benchmarks" / "pipeline_disk_load.json"


def test_reliability_row_is_the_committed_output() -> None:
    res = json.loads(RESULT.read_text(encoding="utf-8"))
    doc = (ROOT / "docs" / "reliability.md").read_text(encoding="utf-8")
    assert bench.reliability_row(res) in doc, "rerun python -m benchmarks.pipeline_disk_load"
    changed = copy.deepcopy(res)
    changed["runs"][-1]["lost"] += 1
    assert bench.reliability_row(changed) not in doc


def test_the_runs_are_consistent() -> None:
    res = json.loads(RESULT.read_text(encoding="utf-8"))
    quiet, *loaded = res["runs"]
    assert quiet["writer_mb_per_s"] is None and quiet["lost"] == 0 and quiet["exit_code"] == 0
    assert loaded and all(r["writer_mb_per_s"] for r in loaded)
    for r in res["runs"]:
        assert "error" not in r, r.get("error")
        assert (r["exit_code"] == 1) == bool(r["lost"] or r["failures"]), r
