"""The wrist and hand subtree, identical in every model (paper Sec. II-A)."""

from __future__ import annotations

import numpy as np

from .anthropometry import BodySize
from .description import FINGERS, ModelDescription
from .payload import GRASP_OBJECT_RADIUS
from .tree import Joint, Link, cylinder_inertia, massless, prism_inertia

X, Y, Z = np.eye(3)


def hand_subtree(
    desc: ModelDescription, size: BodySize, parent: str, wrist_origin: np.ndarray
) -> tuple[list[Link], list[Joint]]:
    """Links and joints from the wrist down, in JOINT_NAMES order.

    Neutral posture (q = 0): fingers along -y, palm facing medial (-z), thumb radial (+x).
    """
    h = desc.hand
    length = h.length * size.hand_length
    breadth = h.breadth * size.hand_breadth
    palm = h.palm_length * size.hand_length
    thick = h.thickness_fraction * breadth
    r_finger = h.finger_radius_fraction * breadth
    r_thumb = h.thumb_radius_fraction * breadth
    mass = {seg: {d: m * size.mass for d, m in v.items()} for seg, v in h.mass.items()}
    rng = desc.ranges
    links: list[Link] = []
    joints: list[Joint] = []

    def joint(name, parent_link, child_link, origin, axis):
        joints.append(Joint(name, parent_link, child_link, np.asarray(origin, float),
                            np.asarray(axis, float), *rng[name]))

    def segment(name, m, seg_length, radius, direction):
        com = 0.5 * seg_length * direction
        links.append(Link(name, m, com, cylinder_inertia(m, radius, seg_length, direction), "cylinder"))

    # Wrist: flexion (about +x), then deviation (about -z, ulnar positive).
    joint("wrist_flexion", parent, "wrist_row", wrist_origin, X)
    links.append(massless("wrist_row"))
    joint("wrist_deviation", "wrist_row", "carpus", np.zeros(3), -Z)
    # Carpus + metacarpals 2-5: one rectangular prism, COM at its centre.
    m_carpus = mass["carpus"]["carpus"] + sum(mass["metacarpal"][f] for f in FINGERS)
    prism_com = np.array([0.0, -0.5 * palm, 0.0])
    links.append(Link("carpus", m_carpus, prism_com, prism_inertia(m_carpus, breadth, palm, thick),
                      "prism"))

    # Thumb: CMC flexion (about -z: across the palm), CMC palmar abduction, MCP, IP.
    th = h.thumb_angle
    d = np.array([np.sin(th), -np.cos(th), 0.0])
    abd_axis = np.array([np.cos(th), np.sin(th), 0.0])  # abd_axis x d = -z (palmar)
    cmc = h.thumb_cmc_fraction * np.array([breadth, palm, thick])
    lf = h.length_fraction
    joint("thumb_cmc_flexion", "carpus", "thumb_cmc", cmc, -Z)
    links.append(massless("thumb_cmc"))
    joint("thumb_cmc_abduction", "thumb_cmc", "thumb_metacarpal", np.zeros(3), abd_axis)
    parent_link, offset = "thumb_metacarpal", 0.0
    thumb = (("metacarpal", None), ("proximal", "thumb_mcp_flexion"), ("distal", "thumb_ip_flexion"))
    for seg, jname in thumb:
        name = f"thumb_{seg}"
        if jname:
            joint(jname, parent_link, name, offset * d, -Z)
        seg_len = lf[seg]["thumb"] * length
        segment(name, mass[seg]["thumb"], seg_len, r_thumb, d)
        parent_link, offset = name, seg_len

    # Fingers 2-5: MCP on the prism's distal edge, then PIP and DIP, all about +x.
    for f in FINGERS:
        parent_link = "carpus"
        origin = np.array([h.mcp_x_fraction[f] * breadth, -palm, 0.0])
        for seg, j in (("proximal", "mcp"), ("middle", "pip"), ("distal", "dip")):
            name = f"{f}_{seg}"
            joint(f"{f}_{j}_flexion", parent_link, name, origin, X)
            seg_len = lf[seg][f] * length
            segment(name, mass[seg][f], seg_len, r_finger, -Y)
            parent_link, origin = name, -seg_len * Y
    return links, joints


def grasp_point(desc: ModelDescription, size: BodySize) -> np.ndarray:
    """The default payload COM in the hand (carpus) frame: a power grasp.

    Palm centre (the carpus prism's centre, half a palm length distal of the wrist centre),
    moved to the palmar side by half the palm thickness plus the radius of a 60 mm object.
    The hand dimensions scale with body size; the object does not.
    """
    h = desc.hand
    palm = h.palm_length * size.hand_length
    thick = h.thickness_fraction * h.breadth * size.hand_breadth
    return np.array([0.0, -0.5 * palm, -(0.5 * thick + GRASP_OBJECT_RADIUS)])
