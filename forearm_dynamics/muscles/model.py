"""A muscle model per arm: parameters, the joints each muscle crosses, its path surrogate.

Why a file format of our own (JSON, `forearm_dynamics.muscles/1`): the node needs the
parameters and the surrogate polynomials only, not a musculoskeletal engine; the shipped file
is derived from MyoSuite's MyoArm (Apache-2.0) by `python -m forearm_dynamics.muscles.fit`,
and a user's file (their own MuJoCo model through the same script) is read the same way.

Body size (the rule, stated once): the shipped file is the 50th-percentile male. For another
size (`anthropometry.resolve_body_size`, as `build_model`), lengths scale with the segment
they lie in and forces with muscle cross-section under geometric similarity:
- moment arms about elbow, pro/sup and wrist × forearm-length ratio; about thumb and finger
  joints × hand-length ratio;
- muscle-tendon length, optimal fibre length and tendon slack × forearm-length ratio for a
  muscle crossing the elbow, pro/sup or wrist, × hand-length ratio for an intrinsic hand
  muscle;
- max isometric force × (body-mass ratio)^(2/3).
The left arm has the same joint names and signs as the right from the user's side
(README), so its moment arms and parameters are the right arm's.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..anthropometry import resolve_body_size
from ..description import JOINT_NAMES
from ..errors import DataError
from .surrogate import Surrogate

#: Every muscle's required parameters (SI: N, m, m, rad, optimal fibre lengths per second).
PARAMETERS = (
    "max_isometric_force",
    "optimal_fiber_length",
    "tendon_slack_length",
    "pennation_at_optimal",
    "max_contraction_velocity",
)
FORMAT = "forearm_dynamics.muscles/1"
DEFAULT_FILE = Path(__file__).resolve().parent.parent / "data" / "muscles_myoarm.json"
ARM_JOINTS = ("elbow_flexion", "pro_sup", "wrist_flexion", "wrist_deviation")


class MuscleModelError(DataError, ValueError):
    """A muscle model file or input that cannot be used (names the file, muscle, parameter)."""


@dataclass(frozen=True)
class MuscleModel:
    """Muscles of one arm. Vectors are in `names` order; moment arms (n, 20) in joint order."""

    names: tuple[str, ...]
    max_isometric_force: np.ndarray  # (n,) N
    optimal_fiber_length: np.ndarray  # (n,) m
    tendon_slack_length: np.ndarray  # (n,) m
    pennation_at_optimal: np.ndarray  # (n,) rad
    max_contraction_velocity: np.ndarray  # (n,) L0/s
    spans: tuple[tuple[str, ...], ...]  # the joints each muscle crosses
    surrogate: Surrogate
    source: dict[str, Any]
    side: str = "right"
    body_size: str = "p50"
    scaling: dict[str, float] = field(default_factory=dict)
    path: str = ""
    joint_names: tuple[str, ...] = JOINT_NAMES

    @property
    def n(self) -> int:
        return len(self.names)

    def params(self) -> tuple[np.ndarray, ...]:
        """(F0, L0, LTs, alpha0, vmax): what curves.unit_forces takes."""
        return (self.max_isometric_force, self.optimal_fiber_length, self.tendon_slack_length,
                self.pennation_at_optimal, self.max_contraction_velocity)

    def moment_arms(self, q) -> np.ndarray:
        """q (20,) -> (n, 20) m; (N, 20) -> (N, n, 20). Positive: the muscle's pull turns the
        joint in its positive direction (README signs); 0 where the muscle does not cross."""
        return self.surrogate.moment_arms(_posture(q, "q"))

    def lengths(self, q) -> np.ndarray:
        """Muscle-tendon lengths (m): q (20,) -> (n,); (N, 20) -> (N, n)."""
        return self.surrogate.lengths(_posture(q, "q"))

    def geometry(self, q, qd, out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R, L, V) of one sample: moment arms (n, 20), lengths (n,), path velocities
        (n,) m/s, lengthening positive (V = −R·q̇, since R = −∂L/∂q). New arrays, or
        written into out = geometry_outputs() (a node's per-sample path: no allocation, the
        values the same to the bit; q and qd then float arrays (20,) the caller has checked
        finite, as the node's decode does)."""
        if out is None:
            q = _posture(q, "q")
            qd = _posture(qd, "qd")
            if q.ndim != 1 or qd.ndim != 1:
                raise MuscleModelError("geometry() takes one sample: q and qd of shape (20,)")
            R, L = self.surrogate.evaluate(q)
            return R, L, -(R @ qd)
        R, L, V = out
        self.surrogate.evaluate(q, (R, L))
        np.matmul(R, qd, out=V)
        np.negative(V, out=V)
        return R, L, V

    def geometry_outputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrays for geometry(q, qd, out=...): (R (n, 20), L (n,), V (n,)); R and L views
        of one buffer the surrogate's product writes in place (Surrogate.new_outputs)."""
        return (*self.surrogate.new_outputs(), np.zeros(self.n))

    def config(self) -> dict[str, Any]:
        """What the node announces on ~/config: muscle set, source, licence, scaling."""
        return {
            "muscles": list(self.names),
            "spans": {n: list(s) for n, s in zip(self.names, self.spans)},
            "max_isometric_force": dict(zip(self.names, map(float, self.max_isometric_force))),
            "source": {k: self.source.get(k) for k in ("name", "version", "licence", "url",
                                                       "notice", "derived_by")},
            "file": self.path,
            "side": self.side,
            "body_size": self.body_size,
            "scaling": dict(self.scaling),
        }


def _posture(x, what: str) -> np.ndarray:
    a = np.asarray(x, float)
    if a.shape[-1:] != (len(JOINT_NAMES),) or a.ndim > 2:
        raise MuscleModelError(f"{what} must have shape (20,) or (N, 20), got {a.shape}")
    if not math.isfinite(a.sum()):  # one call on the hot path; the name only on failure
        col = np.nonzero(~np.isfinite(a.reshape(-1, 20)).all(axis=0))[0]
        bad = JOINT_NAMES[int(col[0])] if len(col) else "sum"
        raise MuscleModelError(f"{what}[{bad}] is not finite")
    return a


def _number(where: str, muscle: dict, key: str, *, positive: bool) -> float:
    if key not in muscle:
        raise MuscleModelError(f"{where}: muscle {muscle.get('name', '?')!r}: missing parameter {key!r}")
    v = muscle[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) \
            or (positive and v <= 0) or (not positive and v < 0):
        raise MuscleModelError(
            f"{where}: muscle {muscle.get('name', '?')!r}: parameter {key!r} = {v!r} must be a "
            f"{'positive' if positive else 'non-negative'} number")
    return float(v)


def _read(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MuscleModelError(f"{path}: no such muscle model file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MuscleModelError(f"{path}: not a readable muscle model (JSON): {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise MuscleModelError(f"{path}: not a muscle model file (format must be {FORMAT!r})")
    for key in ("joints", "muscles", "source"):
        if key not in doc:
            raise MuscleModelError(f"{path}: missing {key!r}")
    return doc


def load_muscle_model(path: str | Path | None = None, *, side: str = "right",
                      body_size: Any = 50) -> MuscleModel:
    """The shipped MyoArm-derived model (path None) or a user's file, for one arm and size."""
    if side not in ("right", "left"):
        raise MuscleModelError(f"side must be 'right' or 'left', got {side!r}")
    file = Path(path) if path is not None else DEFAULT_FILE
    doc = _read(file)
    where = str(file)
    joints = doc["joints"]
    if list(joints.get("names", [])) != list(JOINT_NAMES):
        raise MuscleModelError(f"{where}: joints.names must be the 20 joint names in order")
    size = resolve_body_size(body_size)
    s_force = float(size.mass) ** (2.0 / 3.0)
    arm_cols = [JOINT_NAMES.index(j) for j in ARM_JOINTS]
    joint_scale = np.full(len(JOINT_NAMES), float(size.hand_length))
    joint_scale[arm_cols] = float(size.forearm)
    names, spans, rows, params = [], [], [], {k: [] for k in PARAMETERS}
    length_scale = []
    for k, mus in enumerate(doc["muscles"]):
        if not isinstance(mus, dict) or not isinstance(mus.get("name"), str):
            raise MuscleModelError(f"{where}: muscle #{k} has no name")
        if mus["name"] in names:
            raise MuscleModelError(f"{where}: muscle {mus['name']!r} appears twice")
        for key in PARAMETERS:
            positive = key not in ("pennation_at_optimal", "tendon_slack_length")
            params[key].append(_number(where, mus, key, positive=positive))
        span = mus.get("spans")
        if not span or any(j not in JOINT_NAMES for j in span):
            raise MuscleModelError(f"{where}: muscle {mus['name']!r}: 'spans' must list joint names")
        if "surrogate" not in mus:
            raise MuscleModelError(f"{where}: muscle {mus['name']!r}: missing parameter 'surrogate'")
        names.append(mus["name"])
        spans.append(tuple(span))
        rows.append(mus["surrogate"])
        length_scale.append(size.forearm if set(span) & set(ARM_JOINTS) else size.hand_length)
    length_scale = np.asarray(length_scale, float)
    try:
        sur = Surrogate.from_doc(joints, spans, rows, length_scale=length_scale,
                                 joint_scale=joint_scale)
    except (KeyError, ValueError, TypeError) as exc:
        raise MuscleModelError(f"{where}: surrogate: {exc}") from None
    return MuscleModel(
        names=tuple(names),
        max_isometric_force=np.asarray(params["max_isometric_force"]) * s_force,
        optimal_fiber_length=np.asarray(params["optimal_fiber_length"]) * length_scale,
        tendon_slack_length=np.asarray(params["tendon_slack_length"]) * length_scale,
        pennation_at_optimal=np.asarray(params["pennation_at_optimal"]),
        max_contraction_velocity=np.asarray(params["max_contraction_velocity"]),
        spans=tuple(spans),
        surrogate=sur,
        source=dict(doc["source"]),
        side=side,
        body_size=size.label,
        scaling={"forearm_length": float(size.forearm), "hand_length": float(size.hand_length),
                 "force": s_force},
        path=where,
    )
