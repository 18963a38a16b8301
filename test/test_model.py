"""Foundation: statics by hand, power balance, URDF round trip, body size, bad input."""

import numpy as np
import pinocchio as pin
import pytest
from trajectories import sine_trajectory

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.anthropometry import resolve_body_size
from forearm_dynamics.description import FINGERS, load_description

pytestmark = pytest.mark.unit

KINDS = ("anatomical", "solid", "segmented")
G = np.array([0.0, -9.80665, 0.0])


def rodrigues(axis, angle):
    a = np.asarray(axis) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def hand_point_masses():
    """(mass, COM relative to the wrist centre) of every hand segment at q = 0, recomputed
    here from the description's numbers (50th percentile)."""
    h = load_description().hand
    lf, m = h.length_fraction, h.mass
    palm, b = h.palm_length, h.breadth
    out = [(m["carpus"]["carpus"] + sum(m["metacarpal"][f] for f in FINGERS),
            np.array([0, -palm / 2, 0]))]
    for f in FINGERS:
        y = -palm
        for seg in ("proximal", "middle", "distal"):
            seg_len = lf[seg][f] * h.length
            out.append((m[seg][f], np.array([h.mcp_x_fraction[f] * b, y - seg_len / 2, 0])))
            y -= seg_len
    d = np.array([np.sin(h.thumb_angle), -np.cos(h.thumb_angle), 0])
    base = h.thumb_cmc_fraction * np.array([b, palm, h.thickness_fraction * b])
    s = 0.0
    for seg in ("metacarpal", "proximal", "distal"):
        seg_len = lf[seg]["thumb"] * h.length
        out.append((m[seg]["thumb"], base + (s + seg_len / 2) * d))
        s += seg_len
    return out


@pytest.mark.parametrize("elbow", [0.3, np.pi / 2, 2.0])
def test_statics_by_hand_anatomical(elbow):
    a = load_description().anatomical
    wrist = a.radioulnar_origin + a.wrist_centre  # in the ulna (elbow) frame
    masses = [(a.ulna.mass, a.ulna.com), (a.radius.mass, a.radioulnar_origin + a.radius.com)]
    hand = [(mi, wrist + c) for mi, c in hand_point_masses()]
    rot = rodrigues(a.elbow_axis, elbow)
    # elbow: sum of m g x lever about the elbow axis through its origin
    tau_elbow = sum(m * np.cross(rot @ c, G) for m, c in masses + hand) @ a.elbow_axis
    # wrist flexion axis (+x in the hand frame, rotated by the elbow)
    tau_wrist = sum(m * np.cross(rot @ (c - wrist), G) for m, c in hand) @ (rot @ [1, 0, 0])
    q = np.zeros(20)
    q[0] = elbow
    tau = build_model("anatomical").gravity_torques(q)
    assert tau[0] == pytest.approx(-tau_elbow, rel=1e-12, abs=1e-12)
    assert tau[JOINT_NAMES.index("wrist_flexion")] == pytest.approx(-tau_wrist, rel=1e-12, abs=1e-14)
    assert abs(tau_elbow) > 0.5  # the posture is not trivial


def test_gravity_is_minus_y_standard():
    for kind in KINDS:
        m = build_model(kind)
        np.testing.assert_array_equal(m.model.gravity.linear, G)


@pytest.mark.parametrize("kind", KINDS)
def test_power_balance(kind):
    """tau . qd = dE/dt along a smooth trajectory, E = kinetic + potential (central diff)."""
    model = build_model(kind)
    pm, data = model.model, model.model.createData()
    t, q, qd, qdd = sine_trajectory(n=40, seed=3, kind=kind)
    h = 1e-5
    # re-derive q(t +- h) from the same sines by Taylor to 3rd order is not exact: use the
    # analytic trajectory sampled at t +- h instead.
    _, qp, qdp, _ = _shifted(t + h, seed=3, kind=kind)
    _, qm, qdm, _ = _shifted(t - h, seed=3, kind=kind)

    def energy(qq, vv):
        return pin.computeKineticEnergy(pm, data, qq, vv) + pin.computePotentialEnergy(pm, data, qq)

    tau = model.inverse_dynamics(q, qd, qdd)
    for k in range(len(t)):
        power = tau[k] @ qd[k]
        de = (energy(qp[k], qdp[k]) - energy(qm[k], qdm[k])) / (2 * h)
        scale = np.abs(tau[k] * qd[k]).sum()
        assert abs(power - de) <= 1e-6 * scale, (k, power, de)


def _shifted(times, seed, kind):
    rng = np.random.default_rng(seed)
    model = build_model(kind)
    lo, hi = model.model.lowerPositionLimit, model.model.upperPositionLimit
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    amp = rng.uniform(0.1, 0.45, (3, 20)) * half
    freq = rng.uniform(0.3, 2.5, (3, 20)) * 2 * np.pi
    phase = rng.uniform(0, 2 * np.pi, (3, 20))
    arg = times[:, None, None] * freq + phase
    return (times, mid + (amp * np.sin(arg)).sum(1), (amp * freq * np.cos(arg)).sum(1),
            (-amp * freq**2 * np.sin(arg)).sum(1))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("size", [5, 50, 95])
def test_urdf_round_trip(kind, size):
    model = build_model(kind, body_size=size)
    urdf_model = pin.buildModelFromXML(model.to_urdf())
    urdf_model.gravity = pin.Motion(G, np.zeros(3))
    data = urdf_model.createData()
    # map by joint name: the URDF parser may order sibling branches differently
    idx = [urdf_model.joints[urdf_model.getJointId(n)].idx_v for n in model.joint_names]
    assert sorted(idx) == list(range(20))
    _, q, qd, qdd = sine_trajectory(n=30, seed=5, kind=kind)
    ours = model.inverse_dynamics(q, qd, qdd)
    for k in range(len(q)):
        qq, vv, aa = (np.empty(20) for _ in range(3))
        qq[idx], vv[idx], aa[idx] = q[k], qd[k], qdd[k]
        theirs = pin.rnea(urdf_model, data, qq, vv, aa)[idx]
        np.testing.assert_allclose(theirs, ours[k], atol=1e-12, rtol=1e-12)


def _masses(model):
    return sum(link.mass for link in model.tree.links)


def test_body_size_scaling_rule():
    sizes = {p: resolve_body_size(p) for p in (5, 50, 95)}
    assert sizes[5].forearm == pytest.approx(244 / 267)
    assert sizes[95].hand_length == pytest.approx(210 / 193)
    assert sizes[95].mass == pytest.approx(110.7 / 84.6)
    m50 = build_model("anatomical", 50)
    for p in (5, 95):
        m = build_model("anatomical", p)
        assert _masses(m) == pytest.approx(_masses(m50) * sizes[p].mass, rel=1e-12)
        ru = m.tree.joints[1].origin
        assert np.linalg.norm(ru) == pytest.approx(np.linalg.norm(m50.tree.joints[1].origin)
                                                   * sizes[p].forearm, rel=1e-12)
        # inertia: mass ratio x length ratio^2
        ulna, ulna50 = m.tree.link("ulna").inertia, m50.tree.link("ulna").inertia
        np.testing.assert_allclose(ulna, ulna50 * sizes[p].mass * sizes[p].forearm**2, rtol=1e-12)
        # a finger segment length follows hand length
        j = JOINT_NAMES.index("index_pip_flexion")
        assert np.linalg.norm(m.tree.joints[j].origin) == pytest.approx(
            np.linalg.norm(m50.tree.joints[j].origin) * sizes[p].hand_length, rel=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_torques_grow_with_body_size(kind):
    from forearm_dynamics import get_movement

    mv = get_movement(19)  # wrist flexion + adduction, elbow flexing
    q, qd, qdd = mv.evaluate(mv.sample_times(200.0))
    peaks = []
    for p in (5, 50, 95):
        tau = build_model(kind, body_size=p).inverse_dynamics(q, qd, qdd)
        peaks.append(np.abs(tau).max(axis=0))
    peaks = np.array(peaks)
    moving = peaks[1] > 1e-6
    assert np.all(peaks[0][moving] < peaks[1][moving])
    assert np.all(peaks[1][moving] < peaks[2][moving])


def test_custom_body_size():
    m = build_model("segmented", body_size={"stature": 1.9, "body_mass": 90})
    assert m.body_size.forearm == pytest.approx(1.9 / 1.755)
    assert m.body_size.mass == pytest.approx(90 / 84.6)
    m2 = build_model("segmented", body_size={"body_mass": 70, "forearm_length": 0.25,
                                             "hand_length": 0.18, "hand_breadth": 0.08})
    assert m2.body_size.hand_breadth == pytest.approx(0.08 / 0.088)


def test_hand_identical_in_all_models():
    models = {k: build_model(k) for k in KINDS}
    hand = {k: [(ln.name, ln.mass, tuple(ln.com), tuple(ln.inertia.ravel()))
                for ln in m.tree.links[2:]] for k, m in models.items()}
    joints = {k: [(j.name, j.parent if j.name != "wrist_flexion" else "-", tuple(j.axis),
                   tuple(j.origin) if j.name != "wrist_flexion" else "-", j.lower, j.upper)
                  for j in m.tree.joints[2:]] for k, m in models.items()}
    assert hand["anatomical"] == hand["solid"] == hand["segmented"]
    assert joints["anatomical"] == joints["solid"] == joints["segmented"]
    # the wrist centre is at the same place in the world at q = 0 in every model
    wrist = {}
    for k, m in models.items():
        data = m.model.createData()
        pin.forwardKinematics(m.model, data, np.zeros(20))
        wrist[k] = data.oMi[m.model.getJointId("wrist_flexion")].translation.copy()
    np.testing.assert_allclose(wrist["solid"], wrist["anatomical"], atol=1e-15)
    np.testing.assert_allclose(wrist["segmented"], wrist["anatomical"], atol=1e-15)
    # and with the forearm still, hand torques are identical across models
    _, q, qd, qdd = sine_trajectory(n=20, seed=9)
    q[:, :2] = qd[:, :2] = qdd[:, :2] = 0.0
    taus = [models[k].inverse_dynamics(q, qd, qdd)[:, 2:] for k in KINDS]
    np.testing.assert_allclose(taus[1], taus[0], atol=1e-13)
    np.testing.assert_allclose(taus[2], taus[0], atol=1e-13)


def test_solid_and_segmented_keep_forearm_mass():
    a = load_description().anatomical
    for kind in ("solid", "segmented"):
        tree = build_model(kind).tree
        forearm = tree.link("forearm_proximal").mass + tree.link("forearm_distal").mass
        assert forearm == pytest.approx(a.ulna.mass + a.radius.mass, rel=1e-12)


def test_single_and_batch_agree():
    m = build_model("segmented")
    _, q, qd, qdd = sine_trajectory(n=5, seed=1)
    batch = m.inverse_dynamics(q, qd, qdd)
    for k in range(5):
        np.testing.assert_array_equal(m.inverse_dynamics(q[k], qd[k], qdd[k]), batch[k])


@pytest.mark.parametrize(("call", "match"), [
    (lambda m: m.inverse_dynamics(np.zeros(19), np.zeros(19), np.zeros(19)), r"shape \(20,\)"),
    (lambda m: m.inverse_dynamics(np.zeros(20), np.zeros(3), np.zeros(20)), r"qd\(3,\)"),
    (lambda m: m.inverse_dynamics(np.zeros((4, 20)), np.zeros((4, 20)), np.zeros((3, 20))),
     r"qdd\(3, 20\)"),
    (lambda m: m.inverse_dynamics(np.full(20, np.nan), np.zeros(20), np.zeros(20)),
     r"NaN or inf in q\[elbow_flexion\]"),
    (lambda m: m.inverse_dynamics(np.zeros((2, 20)), np.zeros((2, 20)),
                                  np.array([[0] * 19 + [np.inf]] * 2)), r"qdd\[little_dip_flexion\]"),
])
def test_bad_inputs(call, match):
    with pytest.raises(ValueError, match=match):
        call(build_model("segmented"))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"kind": "banana"}, "unknown model kind 'banana'"),
    ({"kind": "segmented", "body_size": 42}, "body_size 42"),
    ({"kind": "segmented", "body_size": {"stature": 0.3, "body_mass": 70}}, "stature"),
    ({"kind": "segmented", "body_size": {"stature": 1.8, "body_mass": -5}}, "body_mass"),
    ({"kind": "segmented", "body_size": {"stature": 1.8}}, "needs body_mass"),
    ({"kind": "segmented", "body_size": {"height": 1.8, "body_mass": 70}}, "unknown anthropometry"),
    ({"kind": "segmented", "split": 1.5}, "split must be in"),
    ({"kind": "segmented", "split": float("nan")}, "split must be in"),
    ({"kind": "segmented", "axis_offset_distal": [0.01]}, "axis_offset_distal"),
    ({"kind": "anatomical", "split": 0.5}, "solid and segmented"),
    ({"kind": "segmented", "spilt": 0.5}, "unknown override"),
])
def test_bad_model_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_model(**kwargs)
