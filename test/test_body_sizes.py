"""Men's and women's sizes: config/body_sizes.yaml against the source table, and the ratios."""

import numpy as np
import pytest
import yaml

from forearm_dynamics import build_model
from forearm_dynamics.anthropometry import resolve_body_size
from forearm_dynamics.paths import config_file

pytestmark = pytest.mark.unit

# ANSUR II (2012) 5th / 50th / 95th percentiles, men (n = 4082) | women (n = 1986), mm
# (body mass kg), as tabulated in the design notes Sec. 3 from the public survey data.
SOURCE = {
    "male": {"hand_length": (177, 193, 210), "hand_breadth": (81, 88, 96),
             "forearm_length": (244, 267, 295), "stature": (1648, 1755, 1870),
             "body_mass": (64.4, 84.6, 110.7)},
    "female": {"hand_length": (165, 180, 199), "hand_breadth": (72, 78, 85),
               "forearm_length": (218, 240.5, 268), "stature": (1525, 1626, 1740),
               "body_mass": (51.3, 66.8, 87.1)},
}
NAMES = [f"{sex}_{p}" for sex in ("male", "female") for p in (5, 50, 95)]


def table():
    with open(config_file("body_sizes.yaml"), encoding="utf-8") as fh:
        text = fh.read()
    return text, yaml.safe_load(text)


def test_config_holds_the_source_numbers():
    text, t = table()
    assert "ANSUR II 2012" in text and "women (n = 1986)" in text and "men (n = 4082)" in text
    assert t["reference"] == "male_50"
    assert sorted(t["sizes"]) == sorted(NAMES)
    for sex, dims in SOURCE.items():
        for k, p in enumerate((5, 50, 95)):
            row = t["sizes"][f"{sex}_{p}"]
            for dim, values in dims.items():
                expected = values[k] if dim == "body_mass" else values[k] / 1000.0
                assert row[dim] == pytest.approx(expected, rel=1e-12), (sex, p, dim)


@pytest.mark.parametrize("name", NAMES)
def test_ratios_are_to_the_male_50th(name):
    """Recomputed here from the yaml: every size, women's included, over MoBL's male 50th."""
    _, t = table()
    row, ref = t["sizes"][name], t["sizes"]["male_50"]
    size = resolve_body_size(name)
    assert size.forearm == row["forearm_length"] / ref["forearm_length"]
    assert size.hand_length == row["hand_length"] / ref["hand_length"]
    assert size.hand_breadth == row["hand_breadth"] / ref["hand_breadth"]
    assert size.mass == row["body_mass"] / ref["body_mass"]
    sex, pct = name.split("_")
    assert size.label == (f"p{pct}" if sex == "male" else name)
    if sex == "male":  # the integers keep meaning the men's percentiles
        assert resolve_body_size(int(pct)) == size
        assert resolve_body_size(np.int64(pct)) == size
    assert resolve_body_size(name.upper()) == size


def test_female_model_follows_the_rule():
    m50, f50 = build_model("anatomical", 50), build_model("anatomical", "female_50")
    assert f50.body_size.label == "female_50"
    assert f50.body_size.forearm == pytest.approx(240.5 / 267)
    mass = sum(link.mass for link in f50.tree.links) / sum(link.mass for link in m50.tree.links)
    assert mass == pytest.approx(66.8 / 84.6, rel=1e-12)
    k = f50.body_size
    ulna, ulna50 = f50.tree.link("ulna").inertia, m50.tree.link("ulna").inertia
    np.testing.assert_allclose(ulna, ulna50 * k.mass * k.forearm**2, rtol=1e-12)
    # a finger's MCP sits at a hand-breadth x position, a finger segment has a hand length
    j = {j.name: j for j in f50.tree.joints}
    j50 = {j.name: j for j in m50.tree.joints}
    assert j["index_mcp_flexion"].origin[0] == pytest.approx(
        j50["index_mcp_flexion"].origin[0] * 78 / 88, rel=1e-12)
    assert np.linalg.norm(j["index_pip_flexion"].origin) == pytest.approx(
        np.linalg.norm(j50["index_pip_flexion"].origin) * 180 / 193, rel=1e-12)


def test_women_smaller_torques_ordered():
    from forearm_dynamics import get_movement

    mv = get_movement(19)
    q, qd, qdd = mv.evaluate(mv.sample_times(200.0))
    peaks = [np.abs(build_model("segmented", s).inverse_dynamics(q, qd, qdd)).max(axis=0)
             for s in ("female_5", "female_50", "female_95", "male_50")]
    moving = peaks[1] > 1e-6
    assert np.all(peaks[0][moving] < peaks[1][moving])
    assert np.all(peaks[1][moving] < peaks[2][moving])
    assert np.all(peaks[1][moving] < peaks[3][moving])  # the female median below the male


@pytest.mark.parametrize(("value", "match"), [
    ("female_7", "body_size 'female_7' is not a tabulated size"),
    ("woman_50", "body_size 'woman_50' is not a size"),
    (7, "body_size 7 is not a tabulated percentile"),
    ("", "is not a size"),
    (50.0, "got float"),
])
def test_bad_names(value, match):
    with pytest.raises(ValueError, match=match):
        build_model("segmented", value)
