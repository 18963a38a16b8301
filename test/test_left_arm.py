"""The left arm is the mirror image of the right: same names, same signs, same torques.

Proof by the engine's own kinematics: at every posture each left-arm frame is the mirror of
the right's (position S p, rotation S R S, S = diag(1, 1, -1)), every rotation is proper,
and the joint torques of mirrored motions are equal joint by joint (gravity along -y lies in
the mirror plane). The same holds for the URDF a user exports.
"""

import re

import numpy as np
import pinocchio as pin
import pytest

from forearm_dynamics import JOINT_NAMES, build_model

pytestmark = pytest.mark.unit

KINDS = ("anatomical", "solid", "segmented")
S = np.diag([1.0, 1.0, -1.0])
PAYLOAD = {"payload_mass": 0.8, "payload_com": (0.01, -0.05, -0.04),
           "payload_inertia": (2e-3, 1.2e-3, 1.5e-3, 2e-4, -1e-4, 3e-4)}
CASES = [(k, 50, {}) for k in KINDS] + [("segmented", "female_5", PAYLOAD), ("anatomical", 95, PAYLOAD)]


def random_states(n=60, seed=0):
    """States well outside the joint ranges too: the mirror must not depend on them."""
    rng = np.random.default_rng(seed)
    return rng.normal(0, 1.5, (n, 20)), rng.normal(0, 4.0, (n, 20)), rng.normal(0, 30.0, (n, 20))


def pair(kind, size, extra):
    return build_model(kind, size, **extra), build_model(kind, size, side="left", **extra)


@pytest.mark.parametrize(("kind", "size", "extra"), CASES)
def test_mirrored_motions_need_equal_torques(kind, size, extra):
    right, left = pair(kind, size, extra)
    assert (right.side, left.side) == ("right", "left")
    assert left.joint_names == right.joint_names == JOINT_NAMES
    q, qd, qdd = random_states()
    tr, tl = right.inverse_dynamics(q, qd, qdd), left.inverse_dynamics(q, qd, qdd)
    assert np.abs(tr).max() > 1.0  # real loads
    np.testing.assert_allclose(tl, tr, rtol=0, atol=1e-12 * max(1.0, np.abs(tr).max()))
    # gravity alone too (the static case a controller meets most)
    np.testing.assert_allclose(left.gravity_torques(q[0]), right.gravity_torques(q[0]),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize(("kind", "size", "extra"), CASES)
def test_every_frame_is_the_mirror_and_proper(kind, size, extra):
    right, left = pair(kind, size, extra)
    dr, dl = right.model.createData(), left.model.createData()
    names = [f.name for f in right.model.frames]
    assert [f.name for f in left.model.frames] == names
    moved = 0.0
    for q in random_states(n=10, seed=1)[0]:
        pin.framesForwardKinematics(right.model, dr, q)
        pin.framesForwardKinematics(left.model, dl, q)
        for k in range(len(names)):
            r, m = dr.oMf[k], dl.oMf[k]
            np.testing.assert_allclose(m.translation, S @ r.translation, rtol=0, atol=1e-14)
            np.testing.assert_allclose(m.rotation, S @ r.rotation @ S, rtol=0, atol=1e-14)
            assert np.linalg.det(m.rotation) == pytest.approx(1.0, abs=1e-12)
            moved = max(moved, abs(m.translation[2] - r.translation[2]))
    assert moved > 0.05  # the left arm really is elsewhere (z mirrored), not the same arm
    for placement in left.model.jointPlacements:
        np.testing.assert_array_equal(placement.rotation, np.eye(3))


def _tip(model, frame, q):
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[model.getFrameId(frame)].translation.copy()


# (joint, frame moved, direction the user calls positive: right arm, left arm) in world axes
# x anterior, y superior, z toward the subject's right (lateral for the right arm, medial
# for the left). Neutral posture: arm hanging, thumb forward, palm facing the body.
MEDIAL = {"right": -1.0, "left": 1.0}  # z sign of "toward the body" / "toward the palm"
USER_VIEW = [
    ("elbow_flexion", "index_distal", lambda side: np.array([1.0, 0, 0])),  # hand forward
    ("pro_sup", "thumb_distal", lambda side: np.array([0, 0, MEDIAL[side]])),  # thumb turns in
    ("wrist_flexion", "index_distal", lambda side: np.array([0, 0, MEDIAL[side]])),  # to the palm
    ("wrist_deviation", "index_distal", lambda side: np.array([-1.0, 0, 0])),  # to the ulna
    ("thumb_cmc_abduction", "thumb_distal", lambda side: np.array([0, 0, MEDIAL[side]])),  # palmar
    ("index_mcp_flexion", "index_distal", lambda side: np.array([0, 0, MEDIAL[side]])),
]


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize(("joint", "frame", "direction"), USER_VIEW)
def test_positive_means_the_same_to_the_user(side, joint, frame, direction):
    """A small positive angle moves the hand the way the README's table says, on both arms."""
    model = build_model("anatomical", side=side)
    q = np.zeros(20)
    q[model.joint_names.index(joint)] = 0.05
    step = _tip(model.model, frame, q) - _tip(model.model, frame, np.zeros(20))
    d = direction(side)
    assert step @ d > 0.5 * np.linalg.norm(step), (step, d)


@pytest.mark.parametrize(("kind", "size", "extra"), CASES)
def test_left_urdf_gives_the_same_torques(kind, size, extra):
    right, left = pair(kind, size, extra)
    urdf = left.to_urdf()
    assert "left arm" in urdf
    # no rotated, let alone mirrored, link or joint frame (visual/collision shapes are rotated
    # to their principal axes by rpy, which can only express proper rotations)
    frames = re.findall(r'<(?:inertial|joint)\b.*?</(?:inertial|joint)>', urdf, flags=re.DOTALL)
    assert len(frames) > 20
    assert {r for f in frames for r in re.findall(r'rpy="([^"]*)"', f)} == {"0 0 0"}
    parsed = pin.buildModelFromXML(urdf)
    parsed.gravity = left.model.gravity
    data = parsed.createData()
    idx = [parsed.joints[parsed.getJointId(n)].idx_v for n in left.joint_names]
    assert sorted(idx) == list(range(20))
    for placement in parsed.jointPlacements:
        assert np.linalg.det(placement.rotation) == pytest.approx(1.0, abs=1e-15)
    q, qd, qdd = random_states(n=20, seed=2)
    expected = right.inverse_dynamics(q, qd, qdd)
    for k in range(len(q)):
        qq, vv, aa = (np.empty(20) for _ in range(3))
        qq[idx], vv[idx], aa[idx] = q[k], qd[k], qdd[k]
        got = pin.rnea(parsed, data, qq, vv, aa)[idx]
        np.testing.assert_allclose(got, expected[k], rtol=0, atol=1e-12 * max(1.0, np.abs(expected[k]).max()))
        pin.forwardKinematics(parsed, data, qq)
        for m in data.oMi[1:]:
            assert np.linalg.det(m.rotation) == pytest.approx(1.0, abs=1e-12)


def test_mirror_numbers():
    """Origins S o, COMs S c, inertias S I S, axes -S a; masses and limits unchanged."""
    right, left = pair("segmented", 50, PAYLOAD)
    rt, lt = right.tree, left.tree
    for a, b in zip(rt.joints, lt.joints, strict=True):
        assert (a.name, a.parent, a.child, a.lower, a.upper) == (b.name, b.parent, b.child, b.lower, b.upper)
        np.testing.assert_array_equal(b.origin, S @ a.origin)
        np.testing.assert_array_equal(b.axis, -(S @ a.axis))
    for a, b in zip((rt.root, *rt.links, *rt.fixed_links), (lt.root, *lt.links, *lt.fixed_links),
                    strict=True):
        assert (a.name, a.mass) == (b.name, b.mass)
        np.testing.assert_array_equal(b.com, S @ a.com)
        np.testing.assert_array_equal(b.inertia, S @ a.inertia @ S)
    np.testing.assert_array_equal(lt.fixed_joints[0].origin, S @ rt.fixed_joints[0].origin)
    np.testing.assert_array_equal(lt.gravity, rt.gravity)
    assert lt.payload.as_dict() == rt.payload.as_dict()  # the user's numbers, in the (mirrored) hand frame
    # a non-trivial mirror: the wrist flexion axis flips, the elbow axis' lateral part does not
    assert lt.joints[2].axis @ rt.joints[2].axis == pytest.approx(-1.0)


def test_side_is_checked():
    assert build_model("solid", side=" Left ").side == "left"
    for bad in ("middle", "", None, 1):
        with pytest.raises(ValueError, match="side must be 'right' or 'left'"):
            build_model("solid", side=bad)
