"""The shoulder: the humerus' orientation in the world as three more coordinates.

Without a shoulder the humerus is welded to the world (vertical, still). With one, three
revolute joints at the glenohumeral centre (the humerus frame's origin, as in MoBL-ARMS)
turn it, in the sequence of the model the angles come from, so the 20 joints' torques
include gravity in its real direction and the humerus' angular velocity and acceleration
(docs/shoulder.md). The thorax is the world: upright and still (x anterior, y superior,
z lateral for the right arm, gravity -y).

Two conventions, both as their model files define them (body-fixed sequences, each axis
in the frame the previous rotations left; OpenSim's CustomJoint, checked in
test/test_shoulder.py against OpenSim itself):

- "mobl": MoBL-ARMS (Holzbaur et al. 2005; Saul et al. 2015) joints shoulder0 (elv_angle
  about a), shoulder1 (shoulder_elv about b, then shoulder1_r2 about a, coupled to
  -elv_angle) and shoulder2 (shoulder_rot about a), a = (0.0048, 0.99908918, 0.04240001),
  b = (-0.99826136, 0.0023, 0.05889802). The clavicle and scapula rotations before them are
  undone by MoBL's "unrot" phantom joints, so the sequence is thorax -> humerus:
  R = R_a(plane) R_b(elevation) R_a(rotation - plane).
- "fullbody": OpenSim full-body models (gait2392, Hamner 2010, Rajagopal 2016) joint
  acromial_r: arm_flex_r about z, arm_add_r about x, arm_rot_r about y of the torso frame:
  R = R_z(flex) R_x(add) R_y(rot); acromial_l uses z, -x, -y (the mirror image).

The left arm takes the mirror of the right arm's axes (-S a, as tree.mirror_tree), so the
same public names and signs hold on both sides, as for the other joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tree import MIRROR

_A_MOBL = (0.0048, 0.99908918, 0.04240001)
_B_MOBL = (-0.99826136, 0.0023, 0.05889802)


@dataclass(frozen=True)
class ShoulderConvention:
    """Three public coordinates and how they turn the humerus.

    chain_axes: the three revolute axes (right arm, unit) of the chain thorax -> humerus;
    coupling C: chain angles = C @ public angles (MoBL's shoulder1_r2 = -elv_angle), so
    public generalized forces = C.T @ chain torques. aliases: the names model files give
    each public coordinate, per side.
    """

    name: str
    joint_names: tuple[str, str, str]
    chain_axes: tuple[tuple[float, float, float], ...]
    coupling: tuple[tuple[float, float, float], ...]
    aliases: dict[str, tuple[str, ...]]
    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    source: str

    def axes(self, side: str) -> np.ndarray:
        a = np.array([np.asarray(x, float) / np.linalg.norm(x) for x in self.chain_axes])
        return a if side == "right" else -(a @ MIRROR.T)

    @property
    def C(self) -> np.ndarray:
        return np.asarray(self.coupling, float)

    def alias_map(self, side: str) -> dict[str, str]:
        """Every accepted input name -> public name (public names map to themselves)."""
        out = {n: n for n in self.joint_names}
        for public, names in zip(self.joint_names, self.aliases[side]):
            out[names] = public
        return out


CONVENTIONS: dict[str, ShoulderConvention] = {
    "mobl": ShoulderConvention(
        "mobl", ("shoulder_elevation_plane", "shoulder_elevation", "shoulder_rotation"),
        (_A_MOBL, _B_MOBL, _A_MOBL),
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (-1.0, 0.0, 1.0)),
        {"right": ("elv_angle", "shoulder_elv", "shoulder_rot"),
         "left": ("elv_angle_l", "shoulder_elv_l", "shoulder_rot_l")},
        (-1.5708, 0.0, -1.5708), (2.26893, 3.14159, 0.349066),
        "MoBL-ARMS (Saul et al. 2015) joints shoulder0/1/2; ranges as MoBL's coordinates",
    ),
    "fullbody": ShoulderConvention(
        "fullbody", ("arm_flexion", "arm_adduction", "arm_rotation"),
        ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
        {"right": ("arm_flex_r", "arm_add_r", "arm_rot_r"),
         "left": ("arm_flex_l", "arm_add_l", "arm_rot_l")},
        (-1.5708, -2.0944, -1.5708), (1.5708, 1.5708, 1.5708),
        "OpenSim full-body models (gait2392, Hamner 2010, Rajagopal 2016) joint acromial_r/l; "
        "ranges as Hamner 2010's coordinates",
    ),
}
SHOULDER_CHOICES = ("none", *CONVENTIONS)


def convention(name: str) -> ShoulderConvention:
    try:
        return CONVENTIONS[name]
    except KeyError:
        raise ValueError(f"shoulder must be one of {SHOULDER_CHOICES}, got {name!r}") from None


def shoulder_names() -> dict[str, tuple[str, str]]:
    """Every shoulder input name of every convention and side -> (convention, public name)."""
    out: dict[str, tuple[str, str]] = {}
    for conv in CONVENTIONS.values():
        for side in ("right", "left"):
            for name, public in conv.alias_map(side).items():
                out[name] = (conv.name, public)
    return out


def detect_convention(names, side: str = "right") -> str | None:
    """The convention whose three coordinates `names` holds (public or model names), or None.

    Raises ValueError when the names mix conventions or give only some of one.
    """
    found: dict[str, set[str]] = {}
    for conv in CONVENTIONS.values():
        amap = conv.alias_map(side)
        hit = {amap[n] for n in names if n in amap}
        if hit:
            found[conv.name] = hit
    if not found:
        return None
    if len(found) > 1:
        raise ValueError(f"shoulder angles of two conventions in one input: {sorted(found)}")
    (name, hit), = found.items()
    missing = [n for n in CONVENTIONS[name].joint_names if n not in hit]
    if missing:
        raise ValueError(f"shoulder ({name}): {missing} missing; all three angles are needed")
    return name


def axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by `angle` about the unit vector `axis`."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def humerus_rotation(conv: ShoulderConvention, side: str, angles) -> np.ndarray:
    """R (world <- humerus) for public angles (rad): plain numpy, independent of Pinocchio."""
    chain = conv.C @ np.asarray(angles, float)
    r = np.eye(3)
    for axis, q in zip(conv.axes(side), chain):
        r = r @ axis_rotation(axis, q)
    return r


def angles_from_rotation(conv: ShoulderConvention, side: str, r: np.ndarray, guess=None) -> np.ndarray:
    """Public angles whose humerus_rotation is `r` (nearest to `guess`, default zero;
    Gauss-Newton on SO(3): a stream passes its previous angles, so they stay continuous).

    Used for an orientation sensor: near the sequence's gimbal lock (MoBL: elevation 0,
    full-body: adduction ±90°) the angles are ill-defined and the solution is the least-norm
    step; the orientation they give is still `r`.
    """
    r = np.asarray(r, float)
    axes = conv.axes(side)
    cinv = np.linalg.inv(conv.C)
    chain = np.zeros(3) if guess is None else conv.C @ np.asarray(guess, float)
    for _ in range(50):
        rs = [axis_rotation(a, q) for a, q in zip(axes, chain)]
        cur = rs[0] @ rs[1] @ rs[2]
        err = cur.T @ r  # body-frame error
        w = _log(err)
        if np.linalg.norm(w) < 1e-13:
            break
        # body Jacobian of the chain: column i = axis i seen from the humerus frame
        jac = np.column_stack([
            (rs[2].T @ rs[1].T) @ axes[0], rs[2].T @ axes[1], axes[2]])
        chain = chain + np.linalg.lstsq(jac, w, rcond=1e-9)[0]
    return cinv @ chain


def _log(r: np.ndarray) -> np.ndarray:
    c = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if th < 1e-9:
        return 0.5 * v
    if np.pi - th < 1e-6:  # near 180°: the axis from the symmetric part
        a = np.sqrt(np.maximum((np.diag(r) + 1.0) / 2.0, 0.0))
        i = int(np.argmax(a))
        a = (r[:, i] + r[i, :]) / 2.0 / (a[i] if a[i] else 1.0)
        a /= np.linalg.norm(a)
        return th * a if a @ v >= 0 else -th * a
    return th / (2.0 * np.sin(th)) * v


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """The rotation of a unit quaternion (ROS order x, y, z, w), normalised first."""
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


#: REP 103/145 world frames (z up: ENU) -> this model's world (y up): x stays anterior.
ENU_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])



#: a synthetic shoulder motion per convention: (mid, amplitude, frequency Hz, phase) per
#: coordinate, inside the coordinates' ranges and away from the sequence's gimbal lock
#: (MoBL elevation stays 0.3-1.5 rad). Sines, so the derivatives are exact.
SYNTHETIC = {
    "mobl": ((0.6, 0.4, 0.5, 0.0), (0.9, 0.6, 0.7, 1.0), (-0.4, 0.5, 0.9, 2.0)),
    "fullbody": ((0.0, 0.5, 1.4, 0.0), (-0.3, 0.2, 1.4, 1.0), (0.1, 0.2, 0.7, 2.0)),
}


def synthetic_shoulder_motion(name: str, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, qd, qdd), each (N, 3), of SYNTHETIC[name] at times t (s): for tests and benchmarks."""
    t = np.atleast_1d(np.asarray(t, float))[:, None]
    mid, amp, f, ph = (np.array(c) for c in zip(*SYNTHETIC[name]))
    w = 2 * np.pi * f
    arg = w * t + ph
    return mid + amp * np.sin(arg), amp * w * np.cos(arg), -amp * w * w * np.sin(arg)

__all__ = ["CONVENTIONS", "ENU_TO_WORLD", "SHOULDER_CHOICES", "SYNTHETIC", "ShoulderConvention",
           "angles_from_rotation", "axis_rotation", "convention", "detect_convention",
           "humerus_rotation", "quaternion_matrix", "shoulder_names", "synthetic_shoulder_motion"]
