"""An object in the hand: hand-computed statics, fingers untouched, a second construction
path, the default grasp point, and refusals that name the argument."""

from dataclasses import replace

import numpy as np
import pytest

from forearm_dynamics import JOINT_NAMES, build_model
from forearm_dynamics.description import load_description
from forearm_dynamics.dynamics import ArmModel
from forearm_dynamics.tree import combine

pytestmark = pytest.mark.unit

G = np.array([0.0, -9.80665, 0.0])
IDX = {n: i for i, n in enumerate(JOINT_NAMES)}
PROXIMAL = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")
DIGITS = JOINT_NAMES[4:]


def rodrigues(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.mark.parametrize(("elbow", "flex", "dev"), [(0.3, 0.0, 0.0), (np.pi / 2, 0.4, -0.2),
                                                    (2.0, -0.6, 0.3)])
def test_static_change_is_m_g_times_the_lever(elbow, flex, dev):
    """Anatomical model, pro_sup = 0: every frame position from the MoBL numbers by hand."""
    a = load_description().anatomical
    m, com = 1.5, np.array([0.012, -0.07, -0.045])
    q = np.zeros(20)
    q[IDX["elbow_flexion"]], q[IDX["wrist_flexion"]], q[IDX["wrist_deviation"]] = elbow, flex, dev
    empty = build_model("anatomical").gravity_torques(q)
    held = build_model("anatomical", payload_mass=m, payload_com=com).gravity_torques(q)
    # chain at pro_sup = 0: humerus -> (elbow) ulna -> radius -> (flexion, deviation) carpus
    r_e = rodrigues(a.elbow_axis, elbow)
    r_f = r_e @ rodrigues([1, 0, 0], flex)
    r_d = r_f @ rodrigues([0, 0, -1], dev)
    wrist = a.radioulnar_origin + a.wrist_centre  # ulna frame
    p = r_e @ wrist + r_d @ com  # payload COM relative to the elbow origin, world axes
    force = m * G
    levers = {  # (axis in the world, joint point relative to the elbow origin)
        "elbow_flexion": (a.elbow_axis, np.zeros(3)),
        "pro_sup": (r_e @ a.radioulnar_axis, r_e @ a.radioulnar_origin),
        "wrist_flexion": (r_e @ [1, 0, 0], r_e @ wrist),
        "wrist_deviation": (r_f @ [0, 0, -1], r_e @ wrist),
    }
    for name, (axis, point) in levers.items():
        expected = -axis @ np.cross(p - point, force)  # holding torque = -(moment of m g)
        assert held[IDX[name]] - empty[IDX[name]] == pytest.approx(expected, rel=1e-9, abs=1e-12), name
    assert abs(held[IDX["elbow_flexion"]] - empty[IDX["elbow_flexion"]]) > 0.5
    np.testing.assert_allclose(held[4:], empty[4:], rtol=0, atol=1e-13)


@pytest.mark.parametrize("kind", ["anatomical", "solid", "segmented"])
@pytest.mark.parametrize("side", ["right", "left"])
def test_moving_payload_equals_a_heavier_carpus(kind, side):
    """A second construction path: the payload folded into the carpus' own mass and inertia
    (tree.combine) must give the same torques; fingers and thumb do not feel it at all."""
    payload = {"payload_mass": 0.6, "payload_com": (-0.01, -0.08, -0.05),
               "payload_inertia": (1.1e-3, 0.7e-3, 0.9e-3, 1e-4, 0.0, -2e-4)}
    held = build_model(kind, "female_50", side=side, **payload)
    empty = build_model(kind, "female_50", side=side)
    tree = held.tree
    carpus = tree.link("carpus")
    weld = tree.fixed_joints[0]
    body = tree.link(weld.child)
    mass, com, inertia = combine([(carpus.mass, carpus.com, carpus.inertia),
                                  (body.mass, weld.origin + body.com, body.inertia)])
    links = tuple(replace(ln, mass=mass, com=com, inertia=inertia) if ln.name == "carpus" else ln
                  for ln in tree.links)
    folded = ArmModel(replace(tree, links=links, fixed_joints=(), fixed_links=()))
    rng = np.random.default_rng(4)
    q, qd, qdd = rng.normal(0, 1, (30, 20)), rng.normal(0, 3, (30, 20)), rng.normal(0, 20, (30, 20))
    t_held, t_empty = held.inverse_dynamics(q, qd, qdd), empty.inverse_dynamics(q, qd, qdd)
    np.testing.assert_allclose(t_held, folded.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-11)
    np.testing.assert_allclose(t_held[:, 4:], t_empty[:, 4:], rtol=0, atol=1e-13)
    assert np.all(np.abs(t_held[:, :4] - t_empty[:, :4]).max(axis=0) > 0.01)


def test_default_grasp_point():
    """Palm centre, moved palmar by half the palm thickness + 30 mm; scales with the hand."""
    h = load_description().hand
    for size, length, breadth in ((50, 0.193, 0.088), ("female_5", 0.165, 0.072)):
        k_len, k_br = length / 0.193, breadth / 0.088
        expected = np.array([0.0, -0.5 * h.palm_length * k_len,
                             -(0.5 * h.thickness_fraction * h.breadth * k_br + 0.03)])
        arm = build_model("segmented", size, payload_mass=0.5)
        np.testing.assert_allclose(arm.payload.com, expected, rtol=1e-12)
        np.testing.assert_allclose(arm.tree.fixed_joints[0].origin, expected, rtol=1e-12)
        assert arm.tree.fixed_joints[0].parent == "carpus"
        np.testing.assert_array_equal(arm.payload.inertia, np.zeros((3, 3)))  # a point mass


def test_no_mass_no_payload():
    arm = build_model("segmented", payload_mass=0.0, payload_com=(0, -0.05, -0.04))
    assert arm.payload is None and arm.tree.fixed_joints == () and arm.tree.fixed_links == ()
    q = np.linspace(-0.5, 0.5, 20)
    np.testing.assert_array_equal(arm.gravity_torques(q), build_model("segmented").gravity_torques(q))


def test_urdf_carries_the_payload():
    import pinocchio as pin

    arm = build_model("segmented", 95, payload_mass=0.9, payload_com=(0.0, -0.06, -0.05),
                      payload_inertia=(1e-3, 1e-3, 1e-3, 0, 0, 0))
    urdf = arm.to_urdf()
    assert '<joint name="payload_weld" type="fixed">' in urdf
    parsed = pin.buildModelFromXML(urdf)
    parsed.gravity = arm.model.gravity
    idx = [parsed.joints[parsed.getJointId(n)].idx_v for n in arm.joint_names]
    q = np.linspace(-0.4, 0.6, 20)
    qq = np.empty(20)
    qq[idx] = q
    got = pin.computeGeneralizedGravity(parsed, parsed.createData(), qq)[idx]
    np.testing.assert_allclose(got, arm.gravity_torques(q), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"payload_mass": -0.1}, "payload_mass"),
    ({"payload_mass": float("nan")}, "payload_mass"),
    ({"payload_mass": float("inf")}, "payload_mass"),
    ({"payload_mass": "heavy"}, "payload_mass"),
    ({"payload_mass": True}, "payload_mass"),
    ({"payload_mass": 500.0}, "payload_mass"),
    ({"payload_mass": 1.0, "payload_com": (0.6, 0.0, 0.0)}, "payload_com"),
    ({"payload_mass": 1.0, "payload_com": (0.0, float("nan"), 0.0)}, "payload_com"),
    ({"payload_mass": 1.0, "payload_com": (0.0, 0.1)}, "payload_com"),
    ({"payload_mass": 1.0, "payload_com": "palm"}, "payload_com"),
    ({"payload_mass": 1.0, "payload_inertia": (-1e-3, 1e-3, 1e-3, 0, 0, 0)}, "payload_inertia"),
    ({"payload_mass": 1.0, "payload_inertia": (1e-3, 1e-3, 3e-3, 0, 0, 0)}, "triangle"),
    ({"payload_mass": 1.0, "payload_inertia": (1e-3, 1e-3, 1e-3, 2e-3, 0, 0)}, "payload_inertia"),
    ({"payload_mass": 1.0, "payload_inertia": (1e-3, 1e-3, 1e-3)}, "payload_inertia"),
    ({"payload_mass": 1.0, "payload_inertia": (1e-3, 1e-3, float("inf"), 0, 0, 0)}, "payload_inertia"),
    ({"payload_mass": 1.0, "payload_inertia": (10.0, 10.0, 10.0, 0, 0, 0)}, "payload_inertia"),
    ({"payload_mass": 0.0, "payload_inertia": (1e-3, 1e-3, 1e-3, 0, 0, 0)}, "payload_inertia"),
])
def test_bad_payload_names_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_model("segmented", **kwargs)


def test_edge_payloads_accepted():
    """A thin rod (one zero moment, I1 + I2 = I3) and a COM 0.5 m away are still rigid bodies."""
    build_model("segmented", payload_mass=1.0, payload_inertia=(0.0, 1e-2, 1e-2, 0, 0, 0))
    build_model("segmented", payload_mass=1.0, payload_com=(0.0, -0.5, 0.0))
