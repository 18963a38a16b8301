"""The paper's comparison, end to end: reproduce_paper as a user runs it, and its physics."""

import json
import subprocess
import sys

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.analysis.comparison import Trials, compare, reference_filtered
from forearm_dynamics.analysis.placement import Placement, objective
from forearm_dynamics.description import load_description
from forearm_dynamics.reference import load_reference


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    pytest.importorskip("matplotlib")  # reproduce_paper draws figures; the other tests do not
    out = tmp_path_factory.mktemp("paper")
    r = subprocess.run([sys.executable, "-m", "forearm_dynamics.cli.reproduce_paper", "--out", str(out)],
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    return out, json.loads((out / "results.json").read_text())


def test_outputs_exist(paper):
    out, res = paper
    for name in ("results.json", "tables.md", "fig3.png", "fig4.png", "fig5.png", "placement_surface.png"):
        assert (out / name).stat().st_size > 1000, name
    assert set(res["models"]) == {"anatomical", "solid", "segmented"}
    assert set(res["models"]["segmented"]) == {"p5", "p50", "p95"}
    mv = res["models"]["segmented"]["p50"]["movements"]
    assert [m["id"] for m in mv] == list(range(1, 66))
    assert set(mv[0]) >= {"id", "name", "elbow", "nrmse", "nrmse_global", "rmse"}
    assert res["wall_time_s"] > 0  # reported (how long is the benchmark's business, not a test's)


def test_anatomical_against_itself_is_exact(paper):
    _, res = paper
    for size in ("p5", "p50", "p95"):
        s = res["models"]["anatomical"][size]["summary"]
        assert all(s[g]["rmse"]["max"] < 1e-9 for g in s)


def test_segmented_beats_solid_at_pro_sup(paper):
    _, res = paper
    for size in ("p5", "p50", "p95"):
        seg = res["models"]["segmented"][size]["summary"]["pro_sup"]["nrmse"]["mean"]
        sol = res["models"]["solid"][size]["summary"]["pro_sup"]["nrmse"]["mean"]
        assert seg < 0.1 * sol


def test_default_placement_is_the_optimum(paper):
    """The shipped default must be as good as what the search finds now (within rounding)."""
    _, res = paper
    pl = res["placement"]
    best = next(v for v in pl["variants"] if v["label"].startswith("both"))
    s = load_description().simplified
    default = Placement(s.split, tuple(s.axis_offset_proximal), tuple(s.axis_offset_distal))
    trials = Trials.sample(pl["rate_hz"])
    ref = reference_filtered(load_reference(), trials, 50)
    assert objective(default, ref, trials) <= best["objective"] * 1.01


def test_hand_errors_vanish_when_the_forearm_is_still():
    """With elbow and pro/sup still, the hand is identical in all models: no hand error."""
    trials = Trials.sample(100.0, movement_ids=[22, 23, 27, 28])  # close/open hand, elbow still
    ref = reference_filtered(load_reference(), trials, 50)
    e = compare(build_model("solid"), ref, trials)
    assert np.nanmax(e.rmse[:, 2:]) < 1e-9
