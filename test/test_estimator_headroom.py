"""The estimator's headroom on the real corpus's tuning half (benchmarks/estimator_headroom.py,
issue 29): the oracles are what they say (never worse than what they choose from), it reads
only the tuning half, and docs/estimation.md quotes the committed output."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from benchmarks import estimator_headroom as headroom
from benchmarks.corpus import half_of, load

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]



def test_the_oracles_are_never_worse_than_what_they_choose_from() -> None:
    rec = load(headroom.HALF)[0]
    assert half_of(rec.source, rec.subject) == "tuning"
    rows = headroom.score_recording(rec)
    assert [r["dof"] for r in rows] == list(rec.measured)
    for r in rows:
        q = r["qdd"]
        two, three = q["oracle_model_filter"], q["oracle_model_filter_butterworth"]
        assert two <= min(q["filter_alone"], q["model_alone"]) + 1e-9, r
        assert three <= min(two, 1.0) + 1e-9, r  # the Butterworth alone is in its set: ratio 1
        assert all(v > 0 for v in (*q.values(), *r["tau"].values())), r


def test_it_reads_the_tuning_half_only() -> None:
    res = json.loads(headroom.OUT.read_text(encoding="utf-8"))
    assert res["half"] == headroom.HALF == "tuning"
    halves = {(s["source"], s["subject"]): half_of(s["source"], s["subject"]) for s in res["series"]}
    assert halves and set(halves.values()) == {"tuning"}, halves


def test_docs_quote_the_committed_output() -> None:
    res = json.loads(headroom.OUT.read_text(encoding="utf-8"))
    doc = (ROOT / "docs" / "estimation.md").read_text(encoding="utf-8")
    assert headroom.docs_line(res) in doc, "run python benchmarks/estimator_headroom.py --line"
    changed = copy.deepcopy(res)
    changed["tau"]["default"]["worst"] += 0.01
    assert headroom.docs_line(changed) not in doc
