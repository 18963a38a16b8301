"""arm markers against an independent forward kinematics: Pinocchio loaded from the URDF file
that export_urdf writes (not the in-memory model), at random postures, both sides, with a
payload; and the CDR bytes bag_viz writes against rclpy's own message."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from forearm_dynamics import build_model
from forearm_dynamics.cli import export_urdf
from forearm_dynamics.nodes.arm_markers import marker_array
from forearm_dynamics.viz import ArmScene, MarkerMaker, TorqueColours
from forearm_dynamics.viz.colors import FULL_SCALE_NM, VIRIDIS, library_peaks, viridis
from forearm_dynamics.viz.marker_cdr import marker_array_cdr
from forearm_dynamics.viz.muscles import strongest

pytestmark = pytest.mark.unit

CASES = [
    ("segmented", "right", 50, 0.0),
    ("segmented", "left", "female_5", 0.0),
    ("segmented", "right", 95, 0.8),
    ("solid", "left", 50, 0.4),
    ("anatomical", "left", 5, 1.2),
]
SHAPE = {"Cylinder": Marker.CYLINDER, "Box": Marker.CUBE, "Sphere": Marker.SPHERE}


def _urdf_scene(tmp_path, kind, side, size, payload):
    """The exported URDF file, loaded by Pinocchio with its visual geometry."""
    path = tmp_path / f"{kind}_{side}.urdf"
    argv = ["--model", kind, "--side", side, "--body-size", str(size), "-o", str(path)]
    if payload:
        argv += ["--payload-mass", str(payload)]
    assert export_urdf.main(argv) == 0
    model, visual = pin.buildModelsFromUrdf(str(path), geometry_types=[pin.GeometryType.VISUAL])
    return model, visual


def _size_of(geom) -> np.ndarray:
    name = type(geom).__name__
    if name == "Cylinder":
        return np.array([2 * geom.radius, 2 * geom.radius, 2 * geom.halfLength])
    if name == "Sphere":
        return np.full(3, 2 * geom.radius)
    return 2 * np.asarray(geom.halfSide)


@pytest.mark.parametrize(("kind", "side", "size", "payload"), CASES)
def test_marker_poses_are_the_urdf_forward_kinematics(tmp_path, kind, side, size, payload):
    arm = build_model(kind, size, side=side, payload_mass=payload)
    umodel, visual = _urdf_scene(tmp_path, kind, side, size, payload)
    udata, gdata = umodel.createData(), pin.GeometryData(visual)
    scene = ArmScene(arm)
    maker = MarkerMaker(scene, TorqueColours(arm.joint_names))
    by_link = {umodel.frames[g.parentFrame].name: k for k, g in enumerate(visual.geometryObjects)}
    massive = [n.name for n in (arm.tree.root, *arm.tree.links, *arm.tree.fixed_links) if n.mass > 0]
    assert sorted(by_link) == sorted(massive) and len(by_link) == visual.ngeoms
    assert (payload > 0) == ("payload" in by_link)
    # the URDF's joints may come in another order: map by name
    order = [umodel.getJointId(n) for n in arm.joint_names]
    rng = np.random.default_rng(abs(hash((kind, side, str(size)))) % 2**32)
    lo, hi = umodel.lowerPositionLimit, umodel.upperPositionLimit
    for _ in range(20):
        q = rng.uniform(arm.model.lowerPositionLimit, arm.model.upperPositionLimit)
        uq = np.zeros(umodel.nq)
        for i, jid in enumerate(order):
            uq[umodel.joints[jid].idx_q] = q[i]
        assert (uq >= lo - 1e-12).all() and (uq <= hi + 1e-12).all()
        pin.updateGeometryPlacements(umodel, udata, visual, gdata, uq)
        msg = marker_array(maker.frame(q, rng.normal(0, 1, arm.nv)), scene.root_frame, 0)
        shapes = [m for m in msg.markers if not m.ns.startswith("torque/")]
        assert sorted(m.ns for m in shapes) == sorted(massive)
        for m in shapes:
            k = by_link[m.ns]
            placed, geom = gdata.oMg[k], visual.geometryObjects[k].geometry
            p = m.pose.position
            np.testing.assert_allclose([p.x, p.y, p.z], placed.translation, rtol=0, atol=1e-9)
            o = m.pose.orientation
            rot = pin.Quaternion(o.w, o.x, o.y, o.z).toRotationMatrix()
            np.testing.assert_allclose(rot, placed.rotation, rtol=0, atol=1e-9)
            assert m.type == SHAPE[type(geom).__name__]
            np.testing.assert_allclose([m.scale.x, m.scale.y, m.scale.z], _size_of(geom),
                                       rtol=0, atol=1e-12)
            assert m.header.frame_id == umodel.frames[1].name  # the URDF root link


def test_torque_arrows_lie_along_the_urdf_joint_axes(tmp_path):
    arm = build_model("segmented", 50, side="left", payload_mass=0.5)
    umodel, _ = _urdf_scene(tmp_path, "segmented", "left", 50, 0.5)
    udata = umodel.createData()
    scene = ArmScene(arm)
    maker = MarkerMaker(scene, TorqueColours(arm.joint_names), arrows=True, arrow_scale=0.1)
    rng = np.random.default_rng(11)
    q = rng.uniform(arm.model.lowerPositionLimit, arm.model.upperPositionLimit)
    tau = rng.normal(0, 0.5, arm.nv)
    uq = np.zeros(umodel.nq)
    for i, n in enumerate(arm.joint_names):
        uq[umodel.joints[umodel.getJointId(n)].idx_q] = q[i]
    pin.forwardKinematics(umodel, udata, uq)
    f = maker.frame(q, tau)
    for i, n in enumerate(arm.joint_names):
        jid = umodel.getJointId(n)
        axis = udata.oMi[jid].rotation @ umodel.joints[jid].extract().axis
        start, end = f.arrows[i]
        np.testing.assert_allclose(start, udata.oMi[jid].translation, atol=1e-9)
        want = max(abs(tau[i]) * 0.1, 1e-3) * np.sign(tau[i])
        np.testing.assert_allclose(end - start, want * axis, atol=1e-9)


def test_the_cdr_bytes_are_rclpys_message():
    arm = build_model("segmented", 50, payload_mass=0.3)
    scene = ArmScene(arm)
    rng = np.random.default_rng(2)
    for arrows in (False, True):
        maker = MarkerMaker(scene, TorqueColours(arm.joint_names), arrows=arrows)
        f = maker.frame(rng.uniform(-0.5, 0.5, arm.nv), rng.normal(0, 1, arm.nv))
        for delete_all in (False, True):
            stamp = int(rng.integers(0, 2**31 * 10**9))  # int32 seconds
            ours = marker_array_cdr(f, scene.root_frame, stamp, delete_all)
            ref = marker_array(f, scene.root_frame, stamp, delete_all)
            # padding bytes are not defined by CDR (rmw leaves them as they are): compare the
            # decoded messages (colours are float32 on the wire), and the lengths
            theirs = serialize_message(ref)
            assert len(ours) == len(theirs)
            assert deserialize_message(ours, MarkerArray) == deserialize_message(theirs, MarkerArray)


@pytest.mark.parametrize("kind", ["segmented", "anatomical", "solid"])
def test_the_strongest_muscle_colours_the_forearm_and_is_labelled(kind):
    """issue 31 item 4: the forearm's links (the elbow's and pro/sup's) take viridis of the
    strongest forearm muscle's activation, every other link keeps its torque colour, and a
    label names the muscle; the CDR bytes are rclpy's message with the label (TEXT_VIEW_FACING)
    and change with it."""
    arm = build_model(kind, 50)
    scene = ArmScene(arm)
    maker = MarkerMaker(scene, TorqueColours(arm.joint_names), arrows=True)
    rng = np.random.default_rng(5)
    q, tau = rng.uniform(-0.5, 0.5, arm.nv), rng.normal(0, 1, arm.nv)
    names = ("PT", "RI2", "FCR", "SUP")
    pick = strongest(names, [0.2, 0.9, 0.31, np.nan])  # RI2 is a hand muscle: not the forearm's
    assert pick == ("FCR", 0.31)
    plain, f = maker.frame(q, tau), maker.frame(q, tau, pick)
    forearm = [i for i, s in enumerate(scene.shapes)
               if s.joint_index is not None
               and scene.joint_names[s.joint_index] in ("elbow_flexion", "pro_sup")]
    assert forearm, kind
    np.testing.assert_allclose(f.rgba[forearm, :3], np.repeat(viridis(0.31)[None], len(forearm), 0))
    rest = [i for i in range(len(f.ns)) if i not in forearm]
    np.testing.assert_array_equal(f.rgba[rest], plain.rgba[rest])
    assert f.text == "FCR 0.31" and plain.text is None
    stamp = 1_700_000_000 * 10**9 + 5
    for frame in (f, maker.frame(q, tau, ("ECRB", 0.05))):
        ours = marker_array_cdr(frame, scene.root_frame, stamp)
        theirs = serialize_message(marker_array(frame, scene.root_frame, stamp))
        assert len(ours) == len(theirs)
        msg = deserialize_message(ours, MarkerArray)
        assert msg == deserialize_message(theirs, MarkerArray)
        label = [m for m in msg.markers if m.ns == "muscle/strongest"]
        assert len(label) == 1 and label[0].text == frame.text and label[0].type == 9
        assert label[0].lifetime.sec == 0 and label[0].lifetime.nanosec == 500_000_000
        np.testing.assert_allclose([label[0].pose.position.x, label[0].pose.position.y,
                                    label[0].pose.position.z], frame.text_position)
    assert strongest(("RI2", "OP"), [0.5, 0.5]) is None  # no forearm muscle in the message


def test_colour_scale_is_viridis_of_torque_over_the_group_full_scale():
    arm = build_model("segmented", 50)
    peaks = library_peaks()
    assert 3.0 < peaks["elbow"] < 10.0 and 0.01 < peaks["fingers"] < 0.2  # the library's
    for g, peak in peaks.items():  # the stated table: each peak rounded up to 2 digits
        assert float(f"{peak:.2g}") <= FULL_SCALE_NM[g] <= peak * 1.1, g
        assert FULL_SCALE_NM[g] >= peak and float(f"{FULL_SCALE_NM[g]:.2g}") == FULL_SCALE_NM[g], g
    colours = TorqueColours(arm.joint_names, {"elbow": 2.0})
    tau = np.zeros(arm.nv)
    e, w = arm.joint_names.index("elbow_flexion"), arm.joint_names.index("wrist_flexion")
    tau[e], tau[w] = -1.0, 10 * FULL_SCALE_NM["wrist"]
    frac = colours.fraction(tau)
    assert frac[e] == pytest.approx(0.5) and frac[w] == 1.0 and frac[0 if e else 1] == 0.0
    np.testing.assert_allclose(colours.rgb(tau)[w], VIRIDIS[-1])
    np.testing.assert_allclose(viridis(0.5), VIRIDIS[4])
    with pytest.raises(ValueError, match="unknown DOF group"):
        TorqueColours(arm.joint_names, {"elbw": 1.0})


def test_bad_postures_and_torques_are_refused_by_name():
    arm = build_model("segmented", 50)
    maker = MarkerMaker(ArmScene(arm), TorqueColours(arm.joint_names))
    with pytest.raises(ValueError, match="positions must be 20 finite"):
        maker.frame(np.full(20, np.nan), np.zeros(20))
    with pytest.raises(ValueError, match="torques must be 20 finite"):
        maker.frame(np.zeros(20), np.zeros(19))
