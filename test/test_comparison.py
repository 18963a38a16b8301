"""The paper's comparison: its model variants, the error measure, and that the committed
results, the config defaults and the README agree."""

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.analysis.comparison import Trials, compare, reference_filtered
from forearm_dynamics.analysis.errors import movement_errors
from forearm_dynamics.analysis.report import GENERATED, _block, tables_markdown
from forearm_dynamics.analysis.validation import halves
from forearm_dynamics.description import load_description
from forearm_dynamics.movements import movement_library
from forearm_dynamics.reference import load_reference

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results" / "paper"


def _yaml_forearm():
    """Ulna, radius and joint numbers straight from config/model.yaml (not via builders)."""
    import yaml

    raw = yaml.safe_load((ROOT / "config" / "model.yaml").read_text(encoding="utf-8"))["anatomical"]

    def inertia(six):
        xx, yy, zz, xy, xz, yz = six
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])

    ru = np.array(raw["radioulnar"]["origin"])
    axis = np.array(raw["radioulnar"]["axis"]) / np.linalg.norm(raw["radioulnar"]["axis"])
    wrist = ru + np.array(raw["wrist_centre"])
    return raw["ulna"], raw["radius"], ru, axis, wrist, inertia


def _forearm_links(m):
    links = {link.name: link for link in m.tree.links}
    joints = {j.name: j for j in m.tree.joints}
    return links["forearm_proximal"], links["forearm_distal"], joints["pro_sup"]


def test_parallel_axis_is_parallel_and_offset_as_configured():
    m = build_model("segmented", placement="parallel")
    _, _, j = _forearm_links(m)
    *_, wrist, _ = _yaml_forearm()
    e = wrist / np.linalg.norm(wrist)
    assert np.linalg.norm(np.cross(j.axis, e)) < 1e-12
    # distance of the axis from the centreline (through the elbow origin along e)
    d = j.origin - (j.origin @ e) * e
    assert np.linalg.norm(d) == pytest.approx(np.hypot(*m.placement.axis_offset_distal), abs=1e-12)
    assert np.linalg.norm(d) > 0.005  # really off the centreline
    assert m.placement.name == "parallel" and m.placement.split_rule == "radius_inertia"


def test_paper_placement_is_on_the_centreline_with_the_radius_inertia_split():
    """Paper Sec. IV: the distal part matches the radius's inertia about the pro/sup axis."""
    m = build_model("segmented", placement="paper")
    _, distal, j = _forearm_links(m)
    _, radius, _, axis, wrist, inertia = _yaml_forearm()
    e = wrist / np.linalg.norm(wrist)
    assert np.linalg.norm(np.cross(j.axis, e)) < 1e-12
    assert np.linalg.norm(j.origin - (j.origin @ e) * e) < 1e-12
    c = np.array(radius["com"])
    target = axis @ inertia(radius["inertia"]) @ axis + radius["mass"] * (c @ c - (c @ axis) ** 2)
    dc = distal.com - (distal.com @ j.axis) * j.axis
    got = j.axis @ distal.inertia @ j.axis + distal.mass * dc @ dc
    assert got == pytest.approx(target, rel=1e-9)
    assert 0.5 < m.placement.split < 0.9


@pytest.mark.parametrize("kind,placement", [("solid", None), ("segmented", "oblique")])
def test_mass_matched_cylinder_has_the_composite_mass_and_com(kind, placement):
    m = build_model(kind, placement=placement, cylinder="mass_matched")
    prox, distal, j = _forearm_links(m)
    ulna, radius, ru, *_ = _yaml_forearm()
    mass = ulna["mass"] + radius["mass"]
    com = (ulna["mass"] * np.array(ulna["com"]) + radius["mass"] * (ru + np.array(radius["com"]))) / mass
    total = prox.mass + distal.mass
    got = (prox.mass * prox.com + distal.mass * (j.origin + distal.com)) / total
    assert total == pytest.approx(mass, rel=1e-12)
    assert np.allclose(got, com, atol=1e-12)
    uniform = build_model(kind, placement=placement)
    up, ud, uj = _forearm_links(uniform)
    ucom = (up.mass * up.com + ud.mass * (uj.origin + ud.com)) / (up.mass + ud.mass)
    assert np.linalg.norm(ucom - com) > 0.01  # the uniform cylinder's COM is elsewhere (13+ mm)
    assert m.placement.cylinder == "mass_matched"


def test_normalisation_floor_leaves_out_and_counts_tiny_ranges():
    t = np.linspace(0, 1, 50)
    refs, tests = [], []
    for amp in (1.0, 0.5, 0.004):  # the last is 0.4 % of the DOF's range over the movements
        r = np.zeros((50, 20))
        r[:, 1] = amp * np.sin(2 * np.pi * t)
        refs.append(r)
        tests.append(r + 0.01)
    e = movement_errors(tests, refs, floor_fraction=0.01)
    assert e.excluded[1] == 1 and np.isnan(e.nrmse[2, 1]) and np.isfinite(e.nrmse_all[2, 1])
    ptp = [np.ptp(r[:, 1]) for r in refs]
    assert e.nrmse[0, 1] == pytest.approx(0.01 / ptp[0])
    assert e.nrmse_all[2, 1] == pytest.approx(0.01 / ptp[2])
    assert e.nrmse_global[2, 1] == pytest.approx(0.01 / ptp[0])
    assert movement_errors(tests, refs, floor_fraction=0.001).excluded[1] == 0
    assert e.excluded[0] == 3  # a DOF with no range at all is left out everywhere


def test_three_readings_of_45_percent():
    deg = lambda rule, mid, dof: float(np.rad2deg(movement_library(rule)[mid - 1].stop[dof]))
    # pronation (neutral 0, limit 80): 36, 36, 0.45 x 160 = 72
    assert [deg(r, 1, 1) for r in ("toward_limit", "of_limit", "of_range")] == pytest.approx([36, 36, 72])
    # wrist flexion (range -70..80, neutral 5): 5 + 0.45 x 75, 0.45 x 80, 5 + 0.45 x 150
    assert [deg(r, 11, 2) for r in ("toward_limit", "of_limit", "of_range")] == pytest.approx(
        [38.75, 36, 72.5])
    assert all(np.array_equal(a.stop, b.stop) for a, b in
               zip(movement_library(), movement_library("toward_limit"), strict=True))


def test_halves_partition_the_movements():
    for fit_on, scored_on in halves().values():
        assert not set(fit_on) & set(scored_on)
        assert sorted(fit_on + scored_on) == list(range(1, 66))


def test_hand_errors_vanish_when_the_forearm_is_still():
    """With elbow and pro/sup still, the hand is identical in all models: no hand error."""
    trials = Trials.sample(100.0, movement_ids=[22, 23, 27, 28])  # close/open hand, elbow still
    ref = reference_filtered(load_reference(), trials, 50)
    for placement in ("paper", "parallel", "oblique"):
        e = compare(build_model("segmented", placement=placement), ref, trials)
        assert np.nanmax(e.rmse[:, 2:]) < 1e-9


def test_default_placement_is_what_the_results_report(paper_results):
    """config/model.yaml's placements = the fits reported in results.json, and the reported
    rows were computed with exactly what build_model builds."""
    s = load_description().simplified
    assert paper_results["default_placement"] == s.default_placement
    for name in ("paper", "parallel", "oblique"):
        built = build_model("segmented", placement=name).placement.as_dict()
        reported = paper_results["variants"][name]["placement"]
        assert reported.keys() == built.keys()
        for k, v in built.items():
            assert reported[k] == (pytest.approx(v, abs=1e-12) if not isinstance(v, str) else v), (name, k)
    for name in ("parallel", "oblique"):
        fitted = paper_results["variants"][name]["fit"]["overrides"]
        spec = s.placements[name]
        for key in ("axis_offset_proximal", "axis_offset_distal"):
            assert np.allclose(getattr(spec, key), fitted[key], atol=5e-6), (name, key)  # 0.01 mm
        if "split" in fitted:
            assert spec.split == pytest.approx(fitted["split"], abs=5e-5)


def test_docs_and_tables_quote_results_json(paper_results):
    """docs/paper-discussion.md's generated blocks (reproduce_paper --blocks) and tables.md
    are results.json's; the README holds none (reproduce_paper never writes it)."""
    assert "<!-- generated:" not in (ROOT / "README.md").read_text(encoding="utf-8")
    readme = (ROOT / "docs" / "paper-discussion.md").read_text(encoding="utf-8")
    tables = (RESULTS / "tables.md").read_text(encoding="utf-8")
    assert tables == tables_markdown(paper_results)
    for key, fn in GENERATED.items():
        start, end = _block(key)
        assert start in readme and end in readme, key
        body = readme[readme.index(start) + len(start):readme.index(end)].strip()
        assert body == fn(paper_results), f"docs/paper-discussion.md block {key} differs from results.json"
    # and the prose's own headline numbers: the solid / oblique pro/sup means
    head = readme[readme.index(_block("paper-headline")[0]):]
    for name in ("solid", "oblique"):
        mean = 100 * paper_results["models"][name]["p50"]["summary"]["pro_sup"]["nrmse"]["mean"]
        assert re.search(rf"\| {re.escape(f'{mean:.3g}')} \|", head), name


def test_anatomical_model_reproduces_the_reference(paper_results):
    assert paper_results["anatomical_self_check_rmse_max"] < 1e-9


@pytest.mark.parametrize("kwargs,message", [
    ({"kind": "segmented", "placement": "diagonal"}, "placement must be one of"),
    ({"kind": "solid", "placement": "paper"}, "solid model has no placement"),
    ({"kind": "anatomical", "placement": "paper"}, "solid and segmented models only"),
    ({"kind": "segmented", "cylinder": "hollow"}, "cylinder must be one of"),
])
def test_bad_placement_is_refused_with_a_clear_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        build_model(**kwargs)


def test_placement_overrides_are_reported_as_custom():
    m = build_model("segmented", placement="parallel", axis_offset_proximal=[-0.01, 0.0],
                    axis_offset_distal=[-0.01, 0.0])
    assert m.placement.name == "custom" and m.placement.split_rule == "radius_inertia"
    assert m.placement.split != build_model("segmented", placement="parallel").placement.split
    assert build_model("segmented").placement.name == load_description().simplified.default_placement


def test_fit_cache_is_keyed_by_inputs_but_not_by_the_placements_it_writes(tmp_path, monkeypatch):
    from forearm_dynamics.analysis import placement

    for f in (ROOT / "config").glob("*.yaml"):
        shutil.copy(f, tmp_path / f.name)
    monkeypatch.setattr(placement, "config_file", lambda name: tmp_path / name)
    d0 = placement.inputs_digest()
    text = (tmp_path / "model.yaml").read_text(encoding="utf-8")
    moved = text.replace("default_placement: oblique", "default_placement: paper")
    assert moved != text
    (tmp_path / "model.yaml").write_text(moved, encoding="utf-8")
    assert placement.inputs_digest() == d0  # the fits do not read the placements
    (tmp_path / "model.yaml").write_text(text.replace("thickness_fraction: 0.34", "thickness_fraction: 0.35"),
                                         encoding="utf-8")
    assert placement.inputs_digest() != d0
    cache = placement.FitCache(tmp_path / "cache.json")
    calls = []
    value = cache.get_or_compute({"a": 1}, lambda: calls.append(1) or {"x": 2})
    again = placement.FitCache(tmp_path / "cache.json").get_or_compute({"a": 1}, lambda: calls.append(1))
    assert value == again == {"x": 2} and calls == [1]
