"""The exported URDF is visible and right: every body drawn as the solid of its own inertia.

Checked two ways: a strict parse of the XML (every link with an inertial has one visual and
one collision, the same geometry, whose uniform-solid inertia is the inertial's, placed at
the COM along the segment), and Pinocchio loading the file with its geometry (VISUAL and
COLLISION), whose placements follow the joints at any posture.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from forearm_dynamics import build_model
from forearm_dynamics.anthropometry import resolve_body_size
from forearm_dynamics.builders import forearm_cylinder
from forearm_dynamics.description import FINGERS, load_description

pytestmark = pytest.mark.unit

KINDS = ("anatomical", "solid", "segmented")
CYLINDERS = {"forearm_proximal", "forearm_distal", "thumb_metacarpal", "thumb_proximal",
             "thumb_distal", *(f"{f}_{s}" for f in FINGERS for s in ("proximal", "middle", "distal"))}
BOXES = {"carpus", "humerus", "ulna", "radius"}


def _floats(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split()])


def _origin(el) -> tuple[np.ndarray, np.ndarray]:
    o = el.find("origin")
    return _floats(o.get("xyz")), Rotation.from_euler("xyz", _floats(o.get("rpy"))).as_matrix()


def _inertia(el) -> np.ndarray:
    a = {k: float(v) for k, v in el.find("inertia").attrib.items()}
    return np.array([[a["ixx"], a["ixy"], a["ixz"]], [a["ixy"], a["iyy"], a["iyz"]],
                     [a["ixz"], a["iyz"], a["izz"]]])


def _solid_inertia(shape, mass: float) -> np.ndarray:
    """A uniform cylinder (axis z) or box, about its centre, in its own frame."""
    if shape.tag == "cylinder":
        r, length = float(shape.get("radius")), float(shape.get("length"))
        t = mass * (3 * r**2 + length**2) / 12
        return np.diag([t, t, mass * r**2 / 2])
    x, y, z = _floats(shape.get("size"))
    return mass / 12 * np.diag([y**2 + z**2, x**2 + z**2, x**2 + y**2])


def _parse(kind: str, size=50):
    model = build_model(kind, body_size=size)
    robot = ET.fromstring(model.to_urdf())
    return robot, model


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("size", [5, 95])
def test_every_body_is_drawn_as_its_own_inertia(kind, size):
    robot, model = _parse(kind, size)
    materials = {m.get("name"): _floats(m.find("color").get("rgba")) for m in robot.findall("material")}
    assert materials and all(len(c) == 4 and ((c >= 0) & (c <= 1)).all() for c in materials.values())
    tree = model.tree
    drawn = set()
    for link in robot.findall("link"):
        name = link.get("name")
        ours = tree.link(name)
        inertial = link.find("inertial")
        visuals, collisions = link.findall("visual"), link.findall("collision")
        if inertial is None:
            assert ours.mass == 0 and not visuals and not collisions, name
            continue
        assert len(visuals) == 1 and len(collisions) == 1, name
        vis, col = visuals[0], collisions[0]
        assert vis.find("material").get("name") in materials, name
        assert [(g.tag, g.attrib) for g in vis.find("geometry")] == \
            [(g.tag, g.attrib) for g in col.find("geometry")], name
        assert vis.find("origin").attrib == col.find("origin").attrib, name
        shape = vis.find("geometry")[0]
        assert shape.tag == ("cylinder" if name in CYLINDERS else "box"), name
        mass = float(inertial.find("mass").get("value"))
        com, _ = _origin(inertial)
        centre, rot = _origin(vis)
        np.testing.assert_allclose(centre, com, atol=1e-12, err_msg=name)  # uniform: centre = COM
        solid = rot @ _solid_inertia(shape, mass) @ rot.T
        np.testing.assert_allclose(solid, _inertia(inertial), rtol=1e-9, atol=1e-12 * mass,
                                   err_msg=name)
        drawn.add(name)
    assert drawn == {link.name for link in (tree.root, *tree.links) if link.mass > 0}


@pytest.mark.parametrize("kind", KINDS)
def test_shapes_have_the_segments_dimensions_and_lie_along_them(kind):
    """Dimensions recomputed here from the description, and the cylinders' end caps on the
    joints: the drawn forearm runs elbow -> wrist, each phalanx joint -> next joint."""
    robot, model = _parse(kind, 50)
    desc, size = load_description(), resolve_body_size(50)
    links = {link.get("name"): link for link in robot.findall("link")}
    children: dict[str, list[np.ndarray]] = {}
    for j in model.tree.joints:
        children.setdefault(j.parent, []).append(np.asarray(j.origin))

    def shape(name):
        vis = links[name].find("visual")
        centre, rot = _origin(vis)
        return vis.find("geometry")[0], centre, rot

    for name in CYLINDERS & set(links):
        if links[name].find("visual") is None:  # the solid model's massless proximal piece
            continue
        cyl, centre, rot = shape(name)
        half = float(cyl.get("length")) / 2 * rot[:, 2]
        ends = (centre - half, centre + half)
        joints = [np.zeros(3), *children.get(name, [])]
        on_end = [min(np.linalg.norm(p - e) for e in ends) for p in joints]
        assert min(on_end) < 1e-9, (name, on_end)  # one joint sits on an end cap's centre
        # the next joint on the other end (not for the forearm: pro/sup sits on its offset axis)
        if not name.startswith("forearm_") and name in children:
            assert sorted(on_end)[1] < 1e-9, (name, on_end)
    # the forearm: the cylinder fitted to ulna + radius, split at `split`
    fa = forearm_cylinder(desc, size)
    pieces = [n for n in ("forearm_proximal", "forearm_distal") if n in links
              and links[n].find("visual") is not None]
    if kind == "anatomical":
        assert not pieces
    else:
        lengths = [float(shape(n)[0].get("length")) for n in pieces]
        assert sum(lengths) == pytest.approx(fa.length, rel=1e-9)
        for n in pieces:
            assert float(shape(n)[0].get("radius")) == pytest.approx(fa.radius, rel=1e-9)
            assert abs(shape(n)[2][:, 2] @ fa.axis) == pytest.approx(1.0, abs=1e-12)
        if kind == "segmented":
            assert lengths[0] / fa.length == pytest.approx(desc.simplified.split, rel=1e-9)
    # the palm: the carpus prism, breadth x palm length x thickness, unrotated
    h = desc.hand
    box, centre, rot = shape("carpus")
    breadth = h.breadth * size.hand_breadth
    np.testing.assert_allclose(_floats(box.get("size")), [breadth, h.palm_length * size.hand_length,
                                                          h.thickness_fraction * breadth], rtol=1e-9)
    np.testing.assert_allclose(rot, np.eye(3), atol=1e-12)
    # the finger cylinders have the finger radius
    r = float(shape("index_middle")[0].get("radius"))
    assert r == pytest.approx(h.finger_radius_fraction * breadth, rel=1e-9)
    # anatomical bones: boxes whose longest edge runs along the bone (y, superior)
    for bone in BOXES - {"carpus"}:
        if bone in links and links[bone].find("visual") is not None:
            box, _, rot = shape(bone)
            edges = _floats(box.get("size"))
            assert abs(rot[:, int(np.argmax(edges))][1]) > 0.9, bone


@pytest.mark.parametrize("kind", KINDS)
def test_pinocchio_loads_the_geometry(kind, tmp_path):
    model = build_model(kind, body_size=50)
    path = tmp_path / "arm.urdf"
    path.write_text(model.to_urdf())
    pmodel, collision, visual = pin.buildModelsFromUrdf(
        str(path), geometry_types=[pin.GeometryType.COLLISION, pin.GeometryType.VISUAL])
    massive = {link.name: link for link in (model.tree.root, *model.tree.links) if link.mass > 0}
    assert visual.ngeoms == collision.ngeoms == len(massive)
    q = np.random.default_rng(3).uniform(pmodel.lowerPositionLimit, pmodel.upperPositionLimit)
    data = pmodel.createData()
    for gmodel in (visual, collision):
        gdata = pin.GeometryData(gmodel)
        pin.updateGeometryPlacements(pmodel, data, gmodel, gdata, q)
        pin.updateFramePlacements(pmodel, data)
        seen = set()
        for k, geom in enumerate(gmodel.geometryObjects):
            frame = pmodel.frames[geom.parentFrame]
            link = massive[frame.name]
            seen.add(frame.name)
            oMf = data.oMf[geom.parentFrame]
            placed = gdata.oMg[k]
            # at q: the shape's centre is the body's COM, moving with its frame
            np.testing.assert_allclose(placed.translation, oMf.act(np.asarray(link.com)), atol=1e-12)
            shape = geom.geometry
            if frame.name in CYLINDERS:
                assert type(shape).__name__ == "Cylinder"
                axis = placed.rotation[:, 2]
                # the cylinder's axis is its inertia's symmetry axis, turned with the body
                inertia_world = oMf.rotation @ link.inertia @ oMf.rotation.T
                np.testing.assert_allclose(inertia_world @ axis,
                                           (axis @ inertia_world @ axis) * axis, atol=1e-12)
                assert shape.radius > 0 and shape.halfLength > 0
            else:
                assert type(shape).__name__ == "Box"
                assert (shape.halfSide > 0).all()
        assert seen == set(massive)


def test_a_mirrored_link_is_drawn_mirrored():
    """Geometry comes from the link's own inertia: reflect a link (a left arm) and its drawing
    is the reflected one, with no table of shapes to keep in step."""
    from dataclasses import replace

    from forearm_dynamics.urdf import geometry

    s = np.diag([1.0, 1.0, -1.0])  # lateral z -> -z
    for link in build_model("segmented", 50).tree.links:
        if link.mass <= 0:
            continue
        right, left = geometry(link), geometry(replace(link, com=s @ link.com,
                                                       inertia=s @ link.inertia @ s))
        assert left.kind == right.kind and np.allclose(left.size, right.size, rtol=1e-9)
        np.testing.assert_allclose(left.origin, s @ right.origin, atol=1e-15)
        if left.kind == "cylinder":
            assert abs(left.axis @ (s @ right.axis)) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("inertia", [None, (2e-3, 1e-3, 2e-3, 0.0, 0.0, 0.0)])
def test_an_object_in_the_left_hand_is_drawn_where_it_is(inertia, tmp_path):
    """The payload is a sphere at its COM (the sphere of its mean moment, or the default
    grasp object's 30 mm for a point mass), welded to the hand; Pinocchio loads it."""
    model = build_model("segmented", side="left", payload_mass=0.4, payload_inertia=inertia)
    path = tmp_path / "arm.urdf"
    path.write_text(model.to_urdf())
    pmodel, visual = pin.buildModelsFromUrdf(str(path), geometry_types=[pin.GeometryType.VISUAL])
    names = [pmodel.frames[g.parentFrame].name for g in visual.geometryObjects]
    assert names.count("payload") == 1
    k = names.index("payload")
    sphere = visual.geometryObjects[k].geometry
    assert type(sphere).__name__ == "Sphere"
    if inertia is None:
        assert sphere.radius == pytest.approx(0.03)
    else:
        assert sphere.radius == pytest.approx(np.sqrt(2.5 * np.mean(inertia[:3]) / 0.4), rel=1e-12)
    # at a random posture the sphere's centre is the payload's COM as the model computes it
    q = np.random.default_rng(5).uniform(pmodel.lowerPositionLimit, pmodel.upperPositionLimit)
    data = pmodel.createData()
    gdata = pin.GeometryData(visual)
    pin.updateGeometryPlacements(pmodel, data, visual, gdata, q)
    pin.updateFramePlacements(pmodel, data)
    # payload frame: origin at the payload COM (the weld puts it there), left of the body
    np.testing.assert_allclose(gdata.oMg[k].translation,
                               data.oMf[pmodel.getFrameId("payload")].translation, atol=1e-12)
    hand = data.oMf[pmodel.getFrameId("carpus")].translation
    assert 0.02 < np.linalg.norm(gdata.oMg[k].translation - hand) < 0.15
