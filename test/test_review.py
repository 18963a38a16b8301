"""The reviewer's questions: statistics, torque readings, scoring windows, leave-one-out
folds, bodies; and that tables.md quotes results.json."""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy import stats

from forearm_dynamics.analysis.axes import PRO_SUP, ulna_axis_torques
from forearm_dynamics.analysis.heldout import BODIES, MIRROR_GROUPS, lomo_folds, neutral_start
from forearm_dynamics.analysis.report import tables_markdown
from forearm_dynamics.analysis.review import window_samples
from forearm_dynamics.analysis.review_report import REVIEW_TABLES, claims_table
from forearm_dynamics.analysis.statistics import cluster_bootstrap_mean, clusters_of, paired
from forearm_dynamics.anthropometry import resolve_body_size
from forearm_dynamics.builders import build_tree
from forearm_dynamics.description import load_description
from forearm_dynamics.dynamics import ArmModel
from forearm_dynamics.movements import movement_library

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "paper"


def test_cluster_bootstrap_resamples_whole_clusters():
    clusters = np.repeat(np.arange(13), 5)
    # every cluster has the same mean: any resample of whole clusters gives that mean exactly
    v = np.tile([0.1, 0.2, 0.3, 0.4, 0.5], 13)
    lo, hi = cluster_bootstrap_mean(v, clusters)
    assert lo == pytest.approx(0.3, abs=1e-12) and hi == pytest.approx(0.3, abs=1e-12)
    # clusters that differ: the CI is wide and holds the mean; NaNs are dropped
    w = np.repeat(np.linspace(-1, 1, 13), 5)
    w[3] = np.nan
    lo, hi = cluster_bootstrap_mean(w, clusters)
    assert lo < np.nanmean(w) < hi and hi - lo > 0.3


def test_paired_counts_wins_and_matches_scipy():
    rng = np.random.default_rng(1)
    b = rng.uniform(0.1, 1.0, 65)
    a = b - 0.05 + rng.normal(0, 0.01, 65)
    a[0] = np.nan  # a left-out movement drops the pair
    row = paired(a, b, np.repeat(np.arange(1, 14), 5))
    ok = np.isfinite(a)
    assert row["n"] == 64 and row["wins_a"] + row["wins_b"] + row["ties"] == 64
    assert row["wins_a"] == int((a[ok] < b[ok]).sum())
    assert row["mean_difference"] == pytest.approx(float(np.mean(a[ok] - b[ok])))
    assert row["wilcoxon_p"] == pytest.approx(stats.wilcoxon(a[ok], b[ok]).pvalue)
    lo, hi = row["ci95_mean_difference"]
    assert lo < row["mean_difference"] < hi < 0


def test_clusters_are_the_hand_movements():
    c = clusters_of(range(1, 66))
    assert list(c[:6]) == [1, 1, 1, 1, 1, 2] and len(set(c)) == 13


def test_transition_window_is_the_movement():
    w = window_samples("transition", 1000.0)
    m = movement_library()[0]
    t = m.sample_times(1000.0)[w]
    assert t[0] == pytest.approx(m.hold_before) and t[-1] == pytest.approx(m.hold_before + m.transition)
    q = m.evaluate(m.sample_times(1000.0))[0][:, PRO_SUP]
    assert np.all(q[: w.start] == q[0]) and np.all(q[w.stop:] == q[-1])  # outside it: holds
    with pytest.raises(ValueError, match="window must be one of"):
        window_samples("middle", 1000.0)


def test_wrench_on_the_prosup_axis_is_the_generalised_force():
    m = movement_library()[3]  # pronation with the elbow flexing
    q, qd, qdd = (x[::50] for x in m.evaluate(m.sample_times(1000.0)))
    out, worst = ulna_axis_torques(q, qd, qdd)
    assert worst < 1e-12
    ref = ArmModel(build_tree("anatomical", load_description(), resolve_body_size(50)))
    tau = ref.inverse_dynamics(q, qd, qdd)
    assert np.abs(np.delete(out - tau, PRO_SUP, axis=1)).max() < 1e-12
    assert np.abs(out[:, PRO_SUP] - tau[:, PRO_SUP]).max() > 1e-3  # the readings really differ


def test_ulna_axis_moment_at_rest_is_the_gravity_moment_of_the_radius_subtree():
    """At rest the ulna holds the radius + hand against gravity: the moment it transmits about
    the radioulnar origin is -(c - o) x m g, with the subtree's mass and COM (summed here body
    by body from Pinocchio's placements, not from its joint forces)."""
    desc = load_description()
    arm = ArmModel(build_tree("anatomical", desc, resolve_body_size(50)))
    q = movement_library()[12].start.copy()
    q[0], q[1] = 0.7, 0.4
    z = np.zeros(20)
    out, _ = ulna_axis_torques(q[None], z[None], z[None])
    model, data = arm.model, arm.data
    pin.forwardKinematics(model, data, q)
    jid = model.getJointId("pro_sup")
    sub = [i for i in range(jid, model.njoints) if _descends(model, i, jid)]
    mass = sum(model.inertias[i].mass for i in sub)
    com = sum(model.inertias[i].mass * data.oMi[i].act(model.inertias[i].lever) for i in sub) / mass
    o = data.oMi[jid].translation
    g = np.array(desc.gravity)
    moment = -np.cross(com - o, mass * g)
    u = data.oMi[model.parents[jid]].rotation @ np.array([0.0, 1.0, 0.0])
    assert out[0, PRO_SUP] == pytest.approx(moment @ u, abs=1e-12)


def _descends(model, i, root):
    while i > 0:
        if i == root:
            return True
        i = model.parents[i]
    return False


def test_lomo_folds_hold_out_one_movement_and_its_mirror():
    folds = lomo_folds()
    assert len(folds) == 13
    assert sorted(h for g in MIRROR_GROUPS for h in g) == list(range(1, 14))
    tested = []
    lib = movement_library()
    for f in folds:
        assert len(f["test"]) == 5
        hands = {lib[i - 1].hand_number for i in f["train"]}
        assert not hands & set(f["excluded_from_fit"]) and f["held_out"] in f["excluded_from_fit"]
        assert len(f["train"]) == 5 * (13 - len(f["excluded_from_fit"]))
        tested += f["test"]
    assert sorted(tested) == list(range(1, 66))
    assert neutral_start("oblique") == (0.5, (0.0, 0.0), (0.0, 0.0))


def test_bodies_are_not_scaled_copies():
    ratios = [resolve_body_size(b) for b in BODIES.values()]
    spread = [abs(r.forearm - r.hand_length) + abs(r.mass - r.forearm ** 3) for r in ratios]
    assert sum(s > 0.1 for s in spread) >= 4


def test_tables_quote_results_json(paper_results):
    tables = (RESULTS / "tables.md").read_text(encoding="utf-8")
    assert tables == tables_markdown(paper_results)
    for key, fn in REVIEW_TABLES.items():
        assert fn(paper_results) in tables, key
    assert claims_table(paper_results) in tables


def test_results_carry_every_review_section(paper_results):
    rv = paper_results["review"]
    assert set(rv["cases"]) == {"generalised/whole", "generalised/transition", "ulna_axis/whole",
                                "ulna_axis/transition"}
    c = rv["cases"]["generalised/whole"]
    # the review's headline case is the headline table's numbers
    for name, s in c["summary"].items():
        assert s["prosup_nrmse"]["mean"] == pytest.approx(
            paper_results["models"][name]["p50"]["summary"]["pro_sup"]["nrmse"]["mean"], rel=1e-9)
    assert len(paper_results["lomo"]["variants"]["oblique"]["folds"]) == 13
    assert set(paper_results["body_proportions"]) == set(BODIES)
    assert rv["axes"]["wrench_on_prosup_axis_minus_generalised_max_nm"] < 1e-9


def test_docs_paper_is_generated_from_results(paper_results):
    from forearm_dynamics.analysis.paper_doc import paper_markdown

    doc = (ROOT / "docs" / "paper.md").read_text(encoding="utf-8")
    assert doc == paper_markdown(paper_results)
    assert "**Verdict.**" in doc and "**The headline uses reading 1**" in doc


def test_thumb_base_cases_move_the_thumb():
    from forearm_dynamics.analysis.sensitivity import _hand, cases

    desc = load_description()
    thumb = [c for c in cases() if c.get("hand", "").startswith("thumb")]
    assert {c["hand"] for c in thumb} == {"thumb_cmc_position", "thumb_cmc_palmar", "thumb_angle"}
    for c in thumb:
        h = _hand(desc, c["hand"], c["k"]).hand
        moved = (not np.allclose(h.thumb_cmc_fraction, desc.hand.thumb_cmc_fraction)
                 or h.thumb_angle != desc.hand.thumb_angle)
        assert moved, c["case"]
