"""The moving shoulder: gravity where it really is, humerus motion, no change without it."""

from __future__ import annotations

import hashlib
from functools import cache

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from forearm_dynamics import build_model
from forearm_dynamics.movements import movement_library
from forearm_dynamics.shoulder import (
    CONVENTIONS,
    angles_from_rotation,
    convention,
    detect_convention,
    humerus_rotation,
    quaternion_matrix,
    synthetic_shoulder_motion,
)

pytestmark = pytest.mark.unit


# -- no shoulder: exactly today's model ------------------------------------------------
#: sha256 (first 16 hex) of the torques of build_model(kind) at the seeded states below,
#: computed at commit 73299b9 (before the shoulder existed) with the same wheels
BEFORE_SHOULDER = {"segmented": "55b6da18e7b26ff1", "solid": "21d2a6afdbae8495",
                   "anatomical": "33b0233da1adbd8b"}


@pytest.mark.parametrize("kind", sorted(BEFORE_SHOULDER))
@pytest.mark.parametrize("side", ["right", "left"])
def test_no_shoulder_is_bit_for_bit_the_model_before(kind, side):
    rng = np.random.default_rng(30)
    q, qd, qdd = (rng.uniform(-1, 1, (50, 20)) for _ in range(3))
    arm = build_model(kind, 50, side=side)
    assert arm.nv == 20 and not hasattr(arm, "shoulder")
    one = np.array([arm.inverse_dynamics(a, b, c) for a, b, c in zip(q, qd, qdd)])
    batch = arm.inverse_dynamics_batch(q, qd, qdd)
    for tau in (one, batch):
        assert hashlib.sha256(tau.tobytes()).hexdigest()[:16] == BEFORE_SHOULDER[kind]


@pytest.mark.parametrize("name", sorted(CONVENTIONS))
def test_shoulder_at_rest_equals_the_welded_humerus_exactly(name):
    """Zero angles, zero rates: the chain's frames are the welded humerus' (bit for bit)."""
    rng = np.random.default_rng(1)
    q, qd, qdd = (rng.uniform(-1, 1, (20, 20)) for _ in range(3))
    fixed, moving = build_model(), build_model(shoulder=name)
    z = np.zeros((20, 3))
    tau = moving.inverse_dynamics(np.hstack([q, z]), np.hstack([qd, z]), np.hstack([qdd, z]))
    assert np.array_equal(tau[:, :20], fixed.inverse_dynamics(q, qd, qdd))


# -- gravity in its real direction: a hand calculation -----------------------------------
def _elbow_gravity_by_hand(arm, r_shoulder: np.ndarray, elbow: float) -> float:
    """Statics with numpy only: forearm + hand rigid (other joints 0) about the elbow axis."""
    tree = arm.tree
    origin = {tree.root.name: np.zeros(3)}
    for j in tree.joints:  # frames parallel at q = 0: positions add up
        origin[j.child] = origin[j.parent] + j.origin
    mass = sum(link.mass for link in tree.links)
    com = sum(link.mass * (origin[link.name] + link.com) for link in tree.links) / mass
    ej = tree.joints[0]
    assert ej.name == "elbow_flexion"
    e, u = np.asarray(ej.origin, float), np.asarray(ej.axis, float)
    lever = Rotation.from_rotvec(u * elbow).apply(com - e)  # humerus frame
    lever_w, u_w = r_shoulder @ lever, r_shoulder @ u
    g = np.asarray(tree.gravity, float)
    return float(-u_w @ np.cross(lever_w, mass * g))  # what holds the forearm still


@pytest.mark.parametrize("side", ["right", "left"])
def test_elbow_gravity_with_the_humerus_vertical_horizontal_and_upside_down(side):
    arm = build_model("anatomical", side=side, shoulder="fullbody")
    found = {}
    for label, flex in (("vertical", 0.0), ("horizontal", np.pi / 2), ("upside_down", np.pi)):
        q = np.zeros(23)
        q[0] = np.pi / 2  # elbow flexed 90°
        q[20] = flex  # arm_flexion: the humerus swung forward about the thorax's z
        tau = arm.gravity_torques(q)
        r = Rotation.from_euler("z", flex).as_matrix()  # scipy, not the package's own
        expected = _elbow_gravity_by_hand(arm, r, np.pi / 2)
        assert tau[0] == pytest.approx(expected, abs=1e-9), label
        found[label] = tau[0]
    # the physics in words: forearm forward (holds ~M g d), up (~0), backward (the opposite)
    assert found["vertical"] > 1.0
    assert abs(found["horizontal"]) < 0.15 * found["vertical"]
    assert found["upside_down"] == pytest.approx(-found["vertical"], rel=0.15)


def test_humerus_frame_matches_the_sequence_rotation():
    """Pinocchio's humerus frame = humerus_rotation (plain numpy Rodrigues), both conventions."""
    rng = np.random.default_rng(2)
    for name in CONVENTIONS:
        for side in ("right", "left"):
            arm = build_model(shoulder=name, side=side)
            for _ in range(5):
                angles = rng.uniform(-1, 1, 3)
                qc = np.concatenate([arm.shoulder.C @ angles, np.zeros(20)])
                pin.framesForwardKinematics(arm.model, arm.data, qc)
                r = arm.data.oMf[arm.model.getFrameId("humerus")].rotation
                assert np.allclose(r, humerus_rotation(arm.shoulder, side, angles), atol=1e-12)


def test_fullbody_sequence_is_intrinsic_zxy():
    angles = np.array([0.3, -0.5, 0.7])
    r = humerus_rotation(convention("fullbody"), "right", angles)
    assert np.allclose(r, Rotation.from_euler("ZXY", angles).as_matrix(), atol=1e-12)


def test_angles_from_rotation_round_trip_and_quaternion():
    rng = np.random.default_rng(3)
    for name in CONVENTIONS:
        conv = convention(name)
        for side in ("right", "left"):
            for _ in range(5):
                angles = rng.uniform(0.2, 1.0, 3)
                r = humerus_rotation(conv, side, angles)
                back = angles_from_rotation(conv, side, r)
                assert np.allclose(humerus_rotation(conv, side, back), r, atol=1e-10)
    x, y, z, w = Rotation.from_euler("xyz", [0.2, -0.4, 1.1]).as_quat()
    assert np.allclose(quaternion_matrix(x, y, z, w),
                       Rotation.from_quat([x, y, z, w]).as_matrix(), atol=1e-12)


def test_detect_convention_names_and_errors():
    assert detect_convention(["elbow_flexion"]) is None
    assert detect_convention(["elv_angle", "shoulder_elv", "shoulder_rot"]) == "mobl"
    assert detect_convention(["arm_flex_l", "arm_add_l", "arm_rot_l"], "left") == "fullbody"
    assert detect_convention(["arm_flexion", "arm_adduction", "arm_rotation"]) == "fullbody"
    with pytest.raises(ValueError, match="missing"):
        detect_convention(["arm_flex_r", "arm_add_r"])
    with pytest.raises(ValueError, match="two conventions"):
        detect_convention(["arm_flex_r", "arm_add_r", "arm_rot_r", "elv_angle"])
    with pytest.raises(ValueError, match="shoulder must be one of"):
        build_model(shoulder="ball")


# -- a recording with shoulder motion, against OpenSim -------------------------------------
@cache
def _engines(name: str, side: str):
    from forearm_dynamics.opensim_engine import OpenSimArm

    arm = build_model(side=side, shoulder=name)
    return arm, OpenSimArm(arm.tree, arm.shoulder), build_model(side=side)


@pytest.mark.parametrize("name", sorted(CONVENTIONS))
@pytest.mark.parametrize("side", ["right", "left"])
def test_shoulder_motion_changes_torques_by_what_opensim_says(name, side):
    pytest.importorskip("opensim")
    arm, engine, fixed = _engines(name, side)
    mv = movement_library()[7]
    t = np.linspace(0.0, mv.duration, 120)
    q, qd, qdd = mv.evaluate(t)
    s, sd, sdd = synthetic_shoulder_motion(name, t)
    Q, V, A = np.hstack([q, s]), np.hstack([qd, sd]), np.hstack([qdd, sdd])
    ours = arm.inverse_dynamics(Q, V, A)
    reference = engine.inverse_dynamics(Q, V, A)
    welded = fixed.inverse_dynamics(q, qd, qdd)
    change, change_ref = ours[:, :20] - welded, reference[:, :20] - welded
    # the shoulder changes the elbow's torque by tenths of N·m or more: not zero
    assert np.abs(change_ref[:, 0]).max() > 0.2
    assert np.abs(change - change_ref).max() < 1e-8
    assert np.abs(ours[:, 20:] - reference[:, 20:]).max() < 1e-8


def test_name_matcher_takes_model_file_names_and_external_joints():
    from forearm_dynamics.description import JOINT_NAMES
    from forearm_dynamics.nodes import validation as v

    conv = convention("fullbody")
    names = (*JOINT_NAMES, *conv.joint_names)
    m = v.NameMatcher(names, aliases=conv.alias_map("right"))
    msg = ["arm_rot_r", *reversed(JOINT_NAMES), "arm_flex_r", "arm_add_r"]
    index = m.match(msg)
    assert [msg[i] for i in index[20:]] == ["arm_flex_r", "arm_add_r", "arm_rot_r"]
    assert [msg[i] for i in index[:20]] == list(JOINT_NAMES)
    with pytest.raises(v.Rejection, match="arm_flex_r"):
        v.NameMatcher(names, aliases=conv.alias_map("right")).match(
            [*JOINT_NAMES, "arm_flexion", "arm_flex_r", "arm_add_r", "arm_rot_r"])
    with pytest.raises(v.Rejection, match="3 model joint"):
        v.NameMatcher(names).match(list(JOINT_NAMES))
    # supplied by another input (an Imu): not required
    assert len(v.NameMatcher(names, external=frozenset(conv.joint_names)).match(list(JOINT_NAMES))) == 23
