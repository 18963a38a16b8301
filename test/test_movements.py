"""The 65 movements: ids, postures, minimum-jerk kinematics, holds long enough to filter."""

import numpy as np
import pytest

from forearm_dynamics import JOINT_NAMES, get_movement, movement_library
from forearm_dynamics.description import load_description
from forearm_dynamics.filtering import lowpass
from forearm_dynamics.movements import min_jerk

pytestmark = pytest.mark.unit

IDX = {n: i for i, n in enumerate(JOINT_NAMES)}


def test_sixty_five_in_id_order():
    lib = movement_library()
    assert [m.id for m in lib] == list(range(1, 66))
    assert len({(m.name, m.elbow) for m in lib}) == 65
    assert {m.elbow for m in lib} == {"elbow_0", "elbow_45", "elbow_90", "elbow_flexing",
                                      "elbow_extending"}
    assert all(m.duration == pytest.approx(1.5) for m in lib)
    assert get_movement(3).name == "wrist_pronation" and get_movement(3).elbow == "elbow_90"


def test_stop_is_45_percent_from_neutral_toward_the_limit():
    ranges = load_description().ranges
    mv = get_movement(1)  # wrist pronation, elbow 0
    lo, hi = ranges["pro_sup"]
    neutral = (lo + hi) / 2
    assert mv.start[IDX["pro_sup"]] == pytest.approx(neutral)
    assert mv.stop[IDX["pro_sup"]] == pytest.approx(neutral + 0.45 * (hi - neutral))
    assert mv.moving == ("pro_sup",)
    opened = get_movement(26)  # open hand, elbow 0
    lo, hi = ranges["index_mcp_flexion"]
    assert opened.stop[IDX["index_mcp_flexion"]] == pytest.approx((lo + hi) / 2 - 0.45 * (hi - lo) / 2)
    supinated = get_movement(51)  # in full supination: close hand + flex wrist
    assert supinated.start[IDX["pro_sup"]] == pytest.approx(ranges["pro_sup"][0])
    assert "pro_sup" not in supinated.moving and "wrist_flexion" in supinated.moving


def test_elbow_conditions():
    flexing, extending = get_movement(4), get_movement(5)
    e = IDX["elbow_flexion"]
    assert flexing.start[e] == 0 and flexing.stop[e] == pytest.approx(np.deg2rad(130))
    assert extending.start[e] == pytest.approx(np.deg2rad(130)) and extending.stop[e] == 0
    assert get_movement(2).start[e] == get_movement(2).stop[e] == pytest.approx(np.pi / 4)


@pytest.mark.parametrize("movement_id", [1, 19, 33, 65])
def test_derivatives_are_analytic(movement_id):
    mv = get_movement(movement_id)
    t = np.linspace(0.0, mv.duration, 3001)
    h = 1e-6
    q, qd, qdd = mv.evaluate(t)
    qp, qdp, _ = mv.evaluate(t + h)
    qm, qdm, _ = mv.evaluate(t - h)
    # away from the two instants where the jerk jumps (there a central difference is O(h))
    edges = np.array([mv.hold_before, mv.hold_before + mv.transition])
    inner = (t > h) & (t < mv.duration - h) & (np.abs(t[:, None] - edges).min(axis=1) > 2 * h)
    np.testing.assert_allclose(((qp - qm) / (2 * h))[inner], qd[inner], atol=1e-6)
    np.testing.assert_allclose(((qdp - qdm) / (2 * h))[inner], qdd[inner], atol=1e-4)
    # still before and after the transition
    assert np.all(qd[t < mv.hold_before] == 0) and np.all(qd[t > mv.hold_before + mv.transition] == 0)
    np.testing.assert_allclose(q[0], mv.start)
    np.testing.assert_allclose(q[-1], mv.stop)


def test_min_jerk_is_bell_shaped():
    s, ds, dds = min_jerk(np.linspace(0, 1, 1001))
    assert s[0] == 0 and s[-1] == 1 and ds[0] == 0 and ds[-1] == 0 and dds[0] == 0
    assert np.argmax(ds) == 500 and ds[500] == pytest.approx(1.875)


def test_holds_let_the_filter_settle():
    """The 6 Hz filter of a movement equals that of the same movement with endless holds."""
    mv = get_movement(19)
    fs = 1000.0
    t = mv.sample_times(fs)
    q = mv.evaluate(t)[0]
    long_t = np.arange(-5000, len(t) + 5000) / fs
    long_q = lowpass(mv.evaluate(long_t)[0], fs)[5000:5000 + len(t)]
    amp = np.abs(mv.stop - mv.start).max()
    assert np.abs(lowpass(q, fs) - long_q).max() < 1e-5 * amp


def test_evaluate_refuses_bad_times():
    with pytest.raises(ValueError, match="1-D"):
        get_movement(1).evaluate(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        get_movement(1).evaluate([0.0, np.nan])
    with pytest.raises(ValueError, match="1..65"):
        get_movement(66)
