"""The sensor numbers in README and docs/estimation.md come from the committed benchmark
output (benchmarks/results.json, key estimation_zoo): the docs hold the tables
benchmarks/estimation_zoo.py --table prints, and README's ratios are those numbers."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def section() -> dict:
    return json.loads((ROOT / "benchmarks" / "results.json").read_text(encoding="utf-8"))["estimation_zoo"]


def ratios(sec: dict, sensor: str, groups) -> list[float]:
    s = next(x for x in sec["sensors"] if x["sensor"] == sensor)
    rows = {r["estimator"]: r["groups"] for r in s["rows"]}
    return [rows["kalman"][g] / rows["baseline"][g] for g in groups]


def test_docs_hold_the_benchmark_tables() -> None:
    import estimation_zoo

    text = (ROOT / "docs" / "estimation.md").read_text(encoding="utf-8")
    assert estimation_zoo.tables(section()) in text


def test_readme_ratios_are_the_benchmarks() -> None:
    sec = section()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    mocap = ratios(sec, "mocap_ik_100hz", ("elbow", "pro_sup")) + ratios(sec, "mocap_ik_250hz",
                                                                          ("elbow", "pro_sup"))
    assert f"{min(mocap):.2f}–{max(mocap):.2f} × causal" in readme
    glove = ratios(sec, "glove_90hz", ("thumb", "fingers"))
    assert f"{min(glove):.2f}–{max(glove):.2f} ×" in readme
    assert f"{ratios(sec, 'camera_30hz', ('elbow',))[0]:.2f} ×" in readme
    assert f"{ratios(sec, 'encoder_1khz', ('elbow',))[0]:.2f} ×" in readme
    assert not sec["targets"]["worse_than_baseline"]
