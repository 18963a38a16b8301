"""The model description: typed views of config/model.yaml and the public joint names."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import yaml

from .paths import config_file

FINGERS = ("index", "middle", "ring", "little")

#: The 20 joints, in the order of every q, qd, qdd and torque vector. Stable public API.
JOINT_NAMES: tuple[str, ...] = (
    "elbow_flexion",
    "pro_sup",
    "wrist_flexion",
    "wrist_deviation",
    "thumb_cmc_flexion",
    "thumb_cmc_abduction",
    "thumb_mcp_flexion",
    "thumb_ip_flexion",
    *(f"{f}_{j}_flexion" for f in FINGERS for j in ("mcp", "pip", "dip")),
)

#: What a positive angle means, for the README and the URDF comments.
SIGN_CONVENTIONS: dict[str, str] = {
    "elbow_flexion": "flexion positive (0 = full extension)",
    "pro_sup": "pronation positive (0 = neutral, hand in the sagittal plane)",
    "wrist_flexion": "flexion (toward the palm) positive, extension negative",
    "wrist_deviation": "ulnar deviation (adduction) positive, radial negative",
    "thumb_cmc_flexion": "flexion (across the palm) positive",
    "thumb_cmc_abduction": "palmar abduction positive",
    "thumb_mcp_flexion": "flexion positive",
    "thumb_ip_flexion": "flexion positive",
    **{f"{f}_{j}_flexion": "flexion positive" for f in FINGERS for j in ("mcp", "pip", "dip")},
}

DOF_GROUPS: dict[str, tuple[str, ...]] = {
    "pro_sup": ("pro_sup",),
    "elbow": ("elbow_flexion",),
    "wrist": ("wrist_flexion", "wrist_deviation"),
    "thumb": JOINT_NAMES[4:8],
    "fingers": JOINT_NAMES[8:],
}


@dataclass(frozen=True)
class RigidBody:
    """Mass, COM (body frame) and inertia about the COM (body frame, 3x3)."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class AnatomicalForearm:
    humerus: RigidBody
    ulna: RigidBody
    radius: RigidBody
    elbow_origin: np.ndarray
    elbow_axis: np.ndarray
    radioulnar_origin: np.ndarray
    radioulnar_axis: np.ndarray
    wrist_centre: np.ndarray  # in the radius frame


#: The split rule of the paper's placements: the distal part's moment of inertia about the
#: pro/sup axis equals the radius's about MoBL's pro/sup axis (paper Sec. IV).
RADIUS_INERTIA = "radius_inertia"


@dataclass(frozen=True)
class PlacementSpec:
    """One named joint placement of config/model.yaml `simplified.placements`."""

    name: str
    split: float | str  # fraction of the length, or RADIUS_INERTIA (computed by the builder)
    axis_offset_proximal: np.ndarray  # (anterior, lateral), m at the 50th percentile
    axis_offset_distal: np.ndarray
    fitted: tuple[str, ...]  # which coordinates were fitted to the reference (documentation)


@dataclass(frozen=True)
class SimplifiedForearm:
    placements: dict[str, PlacementSpec]
    default_placement: str

    @property
    def default(self) -> PlacementSpec:
        return self.placements[self.default_placement]

    # The default placement's numbers (what build_model("segmented") uses).
    @property
    def split(self) -> float | str:
        return self.default.split

    @property
    def axis_offset_proximal(self) -> np.ndarray:
        return self.default.axis_offset_proximal

    @property
    def axis_offset_distal(self) -> np.ndarray:
        return self.default.axis_offset_distal


@dataclass(frozen=True)
class HandDescription:
    mass: dict[str, dict[str, float]]  # segment -> digit -> kg ("carpus" -> {"carpus": kg})
    length_fraction: dict[str, dict[str, float]]
    length: float
    breadth: float
    palm_length: float
    thickness_fraction: float
    finger_radius_fraction: float
    thumb_radius_fraction: float
    mcp_x_fraction: dict[str, float]
    thumb_cmc_fraction: np.ndarray
    thumb_angle: float  # rad


@dataclass(frozen=True)
class ModelDescription:
    gravity: np.ndarray
    anatomical: AnatomicalForearm
    simplified: SimplifiedForearm
    hand: HandDescription
    ranges: dict[str, tuple[float, float]]  # joint name -> (lower, upper), rad


def inertia_matrix(six: list[float]) -> np.ndarray:
    """[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] -> symmetric 3x3."""
    ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in six)
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _body(d: dict) -> RigidBody:
    return RigidBody(float(d["mass"]), np.array(d["com"], float), inertia_matrix(d["inertia"]))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ranges(raw: dict) -> dict[str, tuple[float, float]]:
    rad = {k: (np.deg2rad(v[0]), np.deg2rad(v[1])) for k, v in raw.items()}
    out = {}
    for name in JOINT_NAMES:
        key = name
        if name.split("_")[0] in FINGERS:
            key = "finger_" + name.split("_", 1)[1]
        out[name] = (float(rad[key][0]), float(rad[key][1]))
    return out


def _simplified(raw: dict) -> SimplifiedForearm:
    placements = {}
    for name, p in raw["placements"].items():
        split = p["split"] if p["split"] == RADIUS_INERTIA else float(p["split"])
        placements[name] = PlacementSpec(
            name, split, np.array(p["axis_offset_proximal"], float),
            np.array(p["axis_offset_distal"], float), tuple(p.get("fitted", ())))
    default = raw["default_placement"]
    if default not in placements:
        raise ValueError(f"model.yaml: default_placement {default!r} is not one of {sorted(placements)}")
    return SimplifiedForearm(placements, default)


@lru_cache(maxsize=1)
def load_description() -> ModelDescription:
    """Parse config/model.yaml once; callers get the same frozen object."""
    with open(config_file("model.yaml"), encoding="utf-8") as fh:
        raw = yaml.safe_load(fh)
    a, s, h = raw["anatomical"], raw["simplified"], raw["hand"]
    mass = {k: dict(v) for k, v in h["mass"].items() if isinstance(v, dict)}
    mass["carpus"] = {"carpus": float(h["mass"]["carpus"])}
    return ModelDescription(
        gravity=np.array(raw["gravity"]["vector"], float),
        anatomical=AnatomicalForearm(
            humerus=_body(a["humerus"]),
            ulna=_body(a["ulna"]),
            radius=_body(a["radius"]),
            elbow_origin=np.array(a["elbow"]["origin"], float),
            elbow_axis=_unit(a["elbow"]["axis"]),
            radioulnar_origin=np.array(a["radioulnar"]["origin"], float),
            radioulnar_axis=_unit(a["radioulnar"]["axis"]),
            wrist_centre=np.array(a["wrist_centre"], float),
        ),
        simplified=_simplified(s),
        hand=HandDescription(
            mass=mass,
            length_fraction={k: dict(v) for k, v in h["length_fraction"].items()},
            length=float(h["length"]),
            breadth=float(h["breadth"]),
            palm_length=float(h["palm_length"]),
            thickness_fraction=float(h["thickness_fraction"]),
            finger_radius_fraction=float(h["finger_radius_fraction"]),
            thumb_radius_fraction=float(h["thumb_radius_fraction"]),
            mcp_x_fraction=dict(h["mcp_x_fraction"]),
            thumb_cmc_fraction=np.array(h["thumb_cmc_fraction"], float),
            thumb_angle=float(np.deg2rad(h["thumb_angle_deg"])),
        ),
        ranges=_ranges(raw["ranges_deg"]),
    )
