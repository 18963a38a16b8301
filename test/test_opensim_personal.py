"""The independent engine (OpenSim/Simbody) on the left arm, women's sizes and a payload."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from forearm_dynamics import build_model
from forearm_dynamics.dynamics import ArmModel
from forearm_dynamics.opensim_engine import OpenSimArm

pytestmark = pytest.mark.unit

osim = pytest.importorskip("opensim")  # the optional [reference] extra; only a guard

TOL = 1e-8  # N·m, absolute, as test_opensim.py
PAYLOAD = {"payload_mass": 1.2, "payload_com": (0.015, -0.07, -0.05),
           "payload_inertia": (2.5e-3, 1.1e-3, 2.0e-3, 3e-4, -2e-4, 4e-4)}
CASES = {
    "anatomical-left": ("anatomical", 50, "left", {}),
    "solid-left": ("solid", 50, "left", {}),
    "segmented-left": ("segmented", 50, "left", {}),
    "anatomical-right-payload": ("anatomical", 50, "right", PAYLOAD),
    "segmented-left-female_50-payload": ("segmented", "female_50", "left", PAYLOAD),
    "anatomical-left-female_95-payload": ("anatomical", "female_95", "left", PAYLOAD),
}


@cache
def _pair(case: str) -> tuple[ArmModel, OpenSimArm]:
    kind, size, side, extra = CASES[case]
    arm = build_model(kind, size, side=side, **extra)
    return arm, OpenSimArm(arm.tree)


def _trajectory(nv: int, lo: np.ndarray, hi: np.ndarray, n: int = 150, seed: int = 0):
    """Sums of three sines per joint inside the joint ranges, exact derivatives."""
    rng = np.random.default_rng(seed)
    mid, half = (hi + lo) / 2, 0.95 * (hi - lo) / 2
    t = np.linspace(0.0, 2.0, n)[:, None, None]
    w = rng.uniform(1.0, 12.0, (1, nv, 3))
    phase = rng.uniform(0.0, 2 * np.pi, (1, nv, 3))
    amp = rng.dirichlet(np.ones(3), nv)[None]
    arg = w * t + phase
    return (mid + half * (amp * np.sin(arg)).sum(-1), half * (amp * w * np.cos(arg)).sum(-1),
            -half * (amp * w**2 * np.sin(arg)).sum(-1))


@pytest.mark.parametrize("case", list(CASES))
def test_opensim_agrees(case: str, record_property) -> None:
    arm, ref = _pair(case)
    lo = np.array([j.lower for j in arm.tree.joints])
    hi = np.array([j.upper for j in arm.tree.joints])
    q, qd, qdd = _trajectory(arm.nv, lo, hi)
    expected = arm.inverse_dynamics(q, qd, qdd)
    got = ref.inverse_dynamics(q, qd, qdd)
    diff = float(np.abs(got - expected).max())
    record_property("max_abs_diff_Nm", diff)
    print(f"{case}: max |OpenSim - Pinocchio| = {diff:.3e} N·m")
    assert np.abs(expected).max() > 0.1
    assert diff < TOL


def test_opensim_left_equals_right_with_payload() -> None:
    """Mirror and payload through the independent engine: left OpenSim = right Pinocchio."""
    _, left = _pair("anatomical-left-female_95-payload")
    right = build_model("anatomical", "female_95", **PAYLOAD)
    empty = build_model("anatomical", "female_95")
    rng = np.random.default_rng(7)
    q, qd, qdd = rng.normal(0, 1, (40, 20)), rng.normal(0, 3, (40, 20)), rng.normal(0, 20, (40, 20))
    expected = right.inverse_dynamics(q, qd, qdd)
    np.testing.assert_allclose(left.inverse_dynamics(q, qd, qdd), expected, rtol=0, atol=TOL)
    # and the payload shows in OpenSim where it must: elbow, pro/sup, wrist; not the digits
    change = np.abs(expected - empty.inverse_dynamics(q, qd, qdd)).max(axis=0)
    assert np.all(change[:4] > 0.05) and np.all(change[4:] < 1e-12)


def test_payload_body_is_welded_in_the_osim_file(tmp_path) -> None:
    arm, ref = _pair("segmented-left-female_50-payload")
    model = osim.Model(str(ref.to_osim(tmp_path / "arm.osim")))
    model.initSystem()
    assert model.getBodySet().get("payload").getMass() == PAYLOAD["payload_mass"]
    weld = model.getJointSet().get("payload_weld")
    assert weld.getConcreteClassName() == "WeldJoint"
    assert model.getCoordinateSet().getSize() == arm.nv  # no coordinate added
    assert "left" in model.getName() and "female_50" in model.getName()
