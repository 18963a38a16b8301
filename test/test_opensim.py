"""OpenSim (Simbody) inverse dynamics of the same trees must match Pinocchio to round-off."""

from __future__ import annotations

from dataclasses import replace
from functools import cache

import numpy as np
import pinocchio as pin
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.dynamics import ArmModel
from forearm_dynamics.opensim_engine import OpenSimArm

pytestmark = pytest.mark.unit

osim = pytest.importorskip("opensim")  # the optional [reference] extra; only a guard

TOL = 1e-8  # N·m, absolute
CASES = [("anatomical", 5), ("anatomical", 50), ("anatomical", 95), ("solid", 50), ("segmented", 50)]


@cache
def _pair(kind: str, size: int) -> tuple[ArmModel, OpenSimArm]:
    arm = build_model(kind, size)
    return arm, OpenSimArm(arm.tree)


def _trajectory(arm: ArmModel, n: int = 200, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Sums of three sines per joint, inside the joint ranges, with exact derivatives."""
    rng = np.random.default_rng(seed)
    lo = np.array([j.lower for j in arm.tree.joints])
    hi = np.array([j.upper for j in arm.tree.joints])
    mid, half = (hi + lo) / 2, 0.95 * (hi - lo) / 2
    t = np.linspace(0.0, 2.0, n)[:, None, None]
    w = rng.uniform(1.0, 12.0, (1, arm.nv, 3))
    phase = rng.uniform(0.0, 2 * np.pi, (1, arm.nv, 3))
    amp = rng.dirichlet(np.ones(3), arm.nv)[None]  # sums to 1 per joint -> stays in range
    arg = w * t + phase
    q = mid + half * (amp * np.sin(arg)).sum(-1)
    qd = half * (amp * w * np.cos(arg)).sum(-1)
    qdd = -half * (amp * w**2 * np.sin(arg)).sum(-1)
    return q, qd, qdd


@pytest.mark.parametrize(("kind", "size"), CASES)
def test_trajectory_matches_pinocchio(kind: str, size: int, record_property) -> None:
    arm, ref = _pair(kind, size)
    assert ref.joint_names == arm.joint_names
    q, qd, qdd = _trajectory(arm)
    expected = arm.inverse_dynamics(q, qd, qdd)
    got = ref.inverse_dynamics(q, qd, qdd)
    diff = float(np.abs(got - expected).max())
    record_property("max_abs_diff_Nm", diff)
    print(f"{kind} P{size}: max |OpenSim - Pinocchio| = {diff:.3e} N·m")
    assert got.shape == expected.shape == q.shape
    assert np.abs(expected).max() > 0.1  # a real load, so a 1e-8 match means something
    assert diff < TOL


def test_static_gravity_matches_first_principles() -> None:
    """At q = 0 all frames are parallel to the world, so the holding torque of joint j is
    -axis_j · sum over its subtree of (com - joint) x (m g): no engine involved."""
    arm, ref = _pair("anatomical", 50)
    tree = arm.tree
    origin = {tree.root.name: np.zeros(3)}
    for j in tree.joints:
        origin[j.child] = origin[j.parent] + j.origin
    children = {j.child: j for j in tree.joints}

    def below(joint_child: str) -> list[str]:
        out = [joint_child]
        for j in tree.joints:
            if j.parent in out and j.child not in out:
                out.append(j.child)
        return out

    expected = np.empty(arm.nv)
    for i, j in enumerate(tree.joints):
        moment = np.zeros(3)
        for name in below(j.child):
            link = tree.link(name)
            moment += np.cross(origin[name] + link.com - origin[j.child], link.mass * tree.gravity)
        expected[i] = -children[j.child].axis @ moment
    z = np.zeros(arm.nv)
    got = ref.inverse_dynamics(z, z, z)
    assert np.abs(expected).max() > 0.1
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)
    g = ref.model.getGravity()
    np.testing.assert_array_equal([g.get(k) for k in range(3)], tree.gravity)


def test_static_gravity_in_a_posture() -> None:
    arm, ref = _pair("segmented", 50)
    q = np.linspace(-0.3, 0.9, arm.nv)
    z = np.zeros(arm.nv)
    np.testing.assert_allclose(ref.inverse_dynamics(q, z, z), arm.gravity_torques(q), rtol=0, atol=TOL)


def test_internal_order_is_mapped_back_to_joint_names() -> None:
    """Simbody answers in its own (breadth-first) mobility order; the map must undo it."""
    arm, ref = _pair("anatomical", 50)
    tree_order = ref.model.getCoordinateNamesInMultibodyTreeOrder()
    names = [tree_order.getElt(k) for k in range(tree_order.size())]
    assert names == [arm.joint_names[k] for k in ref.internal_order]
    assert list(ref.internal_order) != list(range(arm.nv))  # else this test proves nothing

    # Mass-matrix columns: unit acceleration of one joint at a time, gravity and velocity removed.
    q = np.linspace(0.2, 1.1, arm.nv)
    z = np.zeros(arm.nv)
    bias = ref.inverse_dynamics(q, z, z)
    columns = np.stack([ref.inverse_dynamics(q, z, e) - bias for e in np.eye(arm.nv)], axis=1)
    mass = pin.crba(arm.model, arm.data, q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    np.testing.assert_allclose(columns, mass, rtol=0, atol=TOL)
    assert np.abs(mass - np.diag(np.diag(mass))).max() > 1e-4  # coupled, so order matters


def test_distinct_per_joint_values() -> None:
    arm, ref = _pair("solid", 50)
    q = np.linspace(-0.5, 0.5, arm.nv)
    qd = np.arange(1.0, arm.nv + 1) / 4
    qdd = np.arange(arm.nv, 0.0, -1.0)
    np.testing.assert_allclose(ref.inverse_dynamics(q, qd, qdd), arm.inverse_dynamics(q, qd, qdd),
                               rtol=0, atol=TOL)


def test_shapes_and_errors() -> None:
    arm, ref = _pair("anatomical", 50)
    z = np.zeros(arm.nv)
    assert ref.inverse_dynamics(z, z, z).shape == (arm.nv,)
    assert ref.inverse_dynamics(z[None], z[None], z[None]).shape == (1, arm.nv)
    with pytest.raises(ValueError, match="shape"):
        ref.inverse_dynamics(z[:-1], z[:-1], z[:-1])
    with pytest.raises(ValueError, match="NaN"):
        ref.inverse_dynamics(np.full(arm.nv, np.nan), z, z)


def test_to_osim_round_trip(tmp_path) -> None:
    arm, ref = _pair("anatomical", 50)
    path = ref.to_osim(tmp_path / "arm.osim")
    model = osim.Model(str(path))
    model.initSystem()
    coords = model.getCoordinateSet()
    assert [coords.get(k).getName() for k in range(coords.getSize())] == list(arm.joint_names)
    for joint in arm.tree.joints:
        c = coords.get(joint.name)
        assert (c.getRangeMin(), c.getRangeMax()) == (joint.lower, joint.upper)
        assert not c.getDefaultClamped()
        assert not c.getDefaultLocked()
    assert model.getBodySet().get("wrist_row").getMass() == 0.0
    g = model.getGravity()
    np.testing.assert_array_equal([g.get(k) for k in range(3)], arm.tree.gravity)


def test_gravity_comes_from_the_tree() -> None:
    """A tilted gravity must reach OpenSim: its default (-9.80665 on y) would hide a missing set."""
    arm = build_model("anatomical", 50)
    tree = replace(arm.tree, gravity=np.array([3.0, -7.0, 5.0]))
    tilted, ref = ArmModel(tree), OpenSimArm(tree)
    q = np.linspace(-0.4, 0.8, arm.nv)
    z = np.zeros(arm.nv)
    expected = tilted.gravity_torques(q)
    assert np.abs(expected - arm.gravity_torques(q)).max() > 0.1
    np.testing.assert_allclose(ref.inverse_dynamics(q, z, z), expected, rtol=0, atol=TOL)
