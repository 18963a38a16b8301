"""Issue 30 items 2-3: OpenSim files as labs have them (the default map knows the full-body
models' arm names, a typo in a user's map is an error) and units mistakes refused on every
path (ranges.py: here the core; the tools: test_units_cli.py; the node: test_units_live.py).

The Hamner file's header (opensim-models Pipelines/Hamner/outputReference/ResultsIK/
subject02_running_ik.mot, commit 025471aeb655259d7442d87110a5189cf6ffe3df) is written out
below as a fact; its values are synthetic, made here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from forearm_dynamics import JOINT_NAMES, build_model, movement_library
from forearm_dynamics.bounds import torque_bounds
from forearm_dynamics.errors import MotionError
from forearm_dynamics.formats.opensim import CoordinateMap, map_motion, read_motion
from forearm_dynamics.ranges import TINY_HINT, UNITS_HINT, SampleGuard, check_recording

pytestmark = pytest.mark.unit

#: the file's column labels after `time`, as written in its header line (tab separated)
HAMNER_HEADER = ("pelvis_tilt\tpelvis_list\tpelvis_rotation\tpelvis_tx\tpelvis_ty\tpelvis_tz\t"
                 "hip_flexion_r\thip_adduction_r\thip_rotation_r\tknee_angle_r\tankle_angle_r\t"
                 "subtalar_angle_r\tmtp_angle_r\thip_flexion_l\thip_adduction_l\thip_rotation_l\t"
                 "knee_angle_l\tankle_angle_l\tsubtalar_angle_l\tmtp_angle_l\tlumbar_extension\t"
                 "lumbar_bending\tlumbar_rotation\tarm_flex_r\tarm_add_r\tarm_rot_r\telbow_flex_r\t"
                 "pro_sup_r\twrist_flex_r\twrist_dev_r\tarm_flex_l\tarm_add_l\tarm_rot_l\telbow_flex_l\t"
                 "pro_sup_l\twrist_flex_l\twrist_dev_l")
HAMNER = HAMNER_HEADER.split("\t")
START = 1000.0


def hamner_angles_deg(t: np.ndarray) -> dict[str, np.ndarray]:
    """Running-like arm angles (deg) in the full-body models' conventions."""
    w = 2 * np.pi * 1.4 * t
    a = {c: np.zeros_like(t) for c in HAMNER}
    a["elbow_flex_r"] = 95 + 35 * np.sin(w)
    a["pro_sup_r"] = 60 + 10 * np.sin(w + 1)  # their 0 is full supination: ours -30 +- 10
    a["wrist_flex_r"] = 10 * np.sin(w + 2)
    a["wrist_dev_r"] = 5 * np.sin(w + 3)
    a["elbow_flex_l"] = 90 + 30 * np.sin(w + np.pi)
    a["pro_sup_l"] = 100 + 10 * np.sin(w)
    a["arm_flex_r"] = -20 + 20 * np.sin(w)
    return a


def write_hamner(path, degrees_header: bool, scale: float = 1.0, rate: float = 60.0) -> np.ndarray:
    """A .mot with the Hamner header; values in degrees x scale; header inDegrees as asked."""
    t = np.arange(round(rate * 3)) / rate
    a = hamner_angles_deg(t)
    head = ["Coordinates", "version=1", f"nRows={len(t)}", f"nColumns={len(HAMNER) + 1}",
            f"inDegrees={'yes' if degrees_header else 'no'}", "endheader", "\t".join(["time", *HAMNER])]
    rows = np.column_stack([t, *(a[c] * scale for c in HAMNER)])
    path.write_text("\n".join(head + ["\t".join(f"{x:.10g}" for x in r) for r in rows]) + "\n")
    return t


# -- the map (unit) -------------------------------------------------------------------------
@pytest.mark.parametrize("side,suffix", [("right", "_r"), ("left", "_l")])
def test_hamner_columns_map_with_the_default_map(tmp_path, side, suffix):
    src = tmp_path / "subject02_running_ik.mot"
    t = write_hamner(src, True)
    mm = map_motion(read_motion(src), CoordinateMap.load(), side)
    want = {"elbow_flexion": f"elbow_flex{suffix}", "pro_sup": f"pro_sup{suffix}",
            "wrist_flexion": f"wrist_flex{suffix}", "wrist_deviation": f"wrist_dev{suffix}"}
    assert mm.mapped == want
    other = "_l" if suffix == "_r" else "_r"
    assert sorted(mm.other_arm) == sorted(f"{c}{other}" for c in ("elbow_flex", "pro_sup", "wrist_flex",
                                                                   "wrist_dev"))
    a = hamner_angles_deg(t)
    j = JOINT_NAMES.index
    np.testing.assert_allclose(mm.q[:, j("elbow_flexion")], np.radians(a[f"elbow_flex{suffix}"]), atol=1e-9)
    # their pro_sup 0 is full supination (the model files, config/opensim_coordinates.yaml)
    np.testing.assert_allclose(mm.q[:, j("pro_sup")], np.radians(a[f"pro_sup{suffix}"] - 90), atol=1e-9)
    assert len(mm.held) == 16


def test_typo_in_a_users_map_is_an_error(tmp_path):
    src = tmp_path / "run.mot"
    write_hamner(src, True)
    good = tmp_path / "good.yaml"
    good.write_text("coordinates:\n  elbow_flex_r: {joint: elbow_flexion}\n  pro_sup_r: {joint: pro_sup, "
                    "offset_deg: -90}\n")
    assert map_motion(read_motion(src), CoordinateMap.load(good)).mapped == {
        "elbow_flexion": "elbow_flex_r", "pro_sup": "pro_sup_r"}
    bad = tmp_path / "typo.yaml"
    bad.write_text("coordinates:\n  elbow_flx_r: {joint: elbow_flexion}\n  pro_sup_r: {joint: pro_sup}\n")
    with pytest.raises(MotionError, match="elbow_flx_r name no column of") as exc:
        map_motion(read_motion(src), CoordinateMap.load(bad))
    assert "\n" not in str(exc.value)
    wrong_joint = tmp_path / "joint.yaml"
    wrong_joint.write_text("coordinates:\n  elbow_flex_r: {joint: elbow_flex}\n")
    with pytest.raises(MotionError, match="unknown joint 'elbow_flex'"):
        CoordinateMap.load(wrong_joint)


# -- the range check (unit) -------------------------------------------------------------------
def test_every_movement_in_wrong_units_is_refused_and_in_right_units_is_not():
    """The matrix of benchmarks/units_matrix.py on the core check, every library movement."""
    counts = {"correct": 0, "deg_as_rad": 0, "rad_twice": 0}
    for mv in movement_library():
        q = mv.evaluate(mv.sample_times(50.0))[0]
        for kind, s in (("correct", 1.0), ("deg_as_rad", 180 / math.pi), ("rad_twice", math.pi / 180)):
            rep = check_recording(q * s, JOINT_NAMES, source="x")
            if rep.refusal is not None:
                counts[kind] += 1
                assert "check units" in rep.refusal and "\n" not in rep.refusal
    n = len(movement_library())
    assert counts == {"correct": 0, "deg_as_rad": n, "rad_twice": n}


def test_bands_far_moderate_held_and_zeros():
    q = np.zeros((10, 20))
    assert check_recording(q, JOINT_NAMES, source="zeros").refusal is None  # a still neutral pose
    q[:, 0] = math.radians(175)  # elbow 45 deg past its range: moderate (warned, once)
    rep = check_recording(q, JOINT_NAMES, source="f")
    assert rep.refusal is None and len(rep.warnings) == 1 and "elbow_flexion" in rep.warnings[0]
    q[3, 3] = 40.0  # deviation of 40 "rad": far
    rep = check_recording(q, JOINT_NAMES, source="f.mot (inDegrees=no)")
    assert rep.refusal.startswith("f.mot (inDegrees=no): wrist_deviation is 40 rad")
    assert UNITS_HINT in rep.refusal
    measured = [n != "wrist_deviation" for n in JOINT_NAMES]  # a held joint is not the file's
    assert check_recording(q, JOINT_NAMES, source="f", measured=measured).refusal is None
    g = SampleGuard(JOINT_NAMES)
    assert g.check(np.zeros(20)) is None
    assert g.check(q[0]) is None and len(g.pending_warnings) == 1
    assert g.check(q[0]) is None and len(g.pending_warnings) == 1  # once per joint
    assert UNITS_HINT in g.check(q[3])
    tiny = np.zeros((200, 20))
    tiny[:, 0] = np.radians(np.radians(90 + 30 * np.sin(np.linspace(0, 6, 200))))
    rep = check_recording(tiny, JOINT_NAMES, source="t")
    assert rep.tiny and TINY_HINT in rep.refusal


def test_torque_bound_holds_for_the_library_and_not_for_degrees():
    arm = build_model("segmented", 50)
    b = torque_bounds(arm)
    assert set(b.per_group) == {"elbow", "pro_sup", "wrist", "thumb", "fingers"}
    bound = np.array([b.of(n) for n in JOINT_NAMES])
    worst = 0.0
    for mv in movement_library():
        tau = arm.inverse_dynamics_batch(*mv.evaluate(mv.sample_times(200.0)))
        worst = max(worst, float((np.abs(tau) / bound).max()))
    assert worst < 1.0, worst
    mv = movement_library()[0]
    q, qd, qdd = (x * 180 / math.pi for x in mv.evaluate(mv.sample_times(200.0)))
    assert (np.abs(arm.inverse_dynamics_batch(q, qd, qdd, check_ranges="off")) > bound).any()


