"""docs/reliability.md's disk-writer row is the committed benchmark output
(benchmarks/recorder_disk_stall.py), and the benchmark counted every message it sent."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from benchmarks import recorder_disk_stall as bench

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]

RESULT = ROOT / "benchmarks" / "recorder_disk_stall.json"


def test_reliability_row_is_the_committed_output() -> None:
    res = json.loads(RESULT.read_text(encoding="utf-8"))
    doc = (ROOT / "docs" / "reliability.md").read_text(encoding="utf-8")
    assert bench.reliability_row(res) in doc, "rerun python -m benchmarks.recorder_disk_stall"
    changed = copy.deepcopy(res)
    changed["disk_writer"]["steps"][0]["written"] -= 1
    assert bench.reliability_row(changed) not in doc
    for name in ("quiet", "disk_writer"):
        step = res[name]["steps"][0]
        assert step["sent"] == step["written"] + step["dropped"] and res[name]["exit_code"] == 0
