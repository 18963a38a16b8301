"""The cached muscle reference and the comparison the tests and the benchmark make with it.

`make muscle-reference` (forearm_dynamics.cli.make_muscle_reference) writes
forearm_dynamics/data/muscle_so_reference.npz:

- OpenSim's StaticOptimization (opensim_so.py) of the MOVEMENT_IDS movements at RATE_HZ frames:
  activations, forces, reserves per frame (float32: SO's own tolerance is ~1e-6);
- the exact-geometry solve of the same frames: the source engine's own moment arms and
  lengths (MuJoCo MyoArm tendon Jacobians, muscles/fit.py's `MyoArm`, optional extra
  `muscles-fit`) solved by a second QP method at tight tolerance (scipy's bounded-variable
  least squares, BVLS: an exact active-set method, independent of daqp), so the surrogate
  geometry is checked on the same frames too;
- meta: OpenSim and MuJoCo versions, the SHA-256 of the muscle model (a reference made from
  another model is stale and the test says so), settings, the command.

`compare` puts our per-sample QP (surrogate + daqp, as the node) beside either and gives the
per-muscle figures of issue 31: RMS(Δactivation), force RMS in % of max isometric force, and
the correlation of every muscle whose peak activation reaches PEAK_FOR_CORRELATION.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..description import JOINT_NAMES
from ..muscles import MuscleModel
from .opensim_so import RESERVE_LIMIT_NM, RESERVE_OPTIMAL_TORQUE, TORQUE_LIMIT_NM

REFERENCE_FILE = Path(__file__).resolve().parents[1] / "data" / "muscle_so_reference.npz"
PEAK_FOR_CORRELATION = 0.05
#: issue 31's targets against OpenSim SO
TARGET_RMS_DA = 0.01
TARGET_FORCE_PCT = 2.0
TARGET_CORR = 0.95


@dataclass
class MuscleReference:
    """Frames of several movements: `offsets[i]:offsets[i+1]` are movement_ids[i]'s."""

    movement_ids: np.ndarray  # (M,)
    offsets: np.ndarray  # (M + 1,)
    times: np.ndarray  # (F,) s from each movement's start
    names: tuple[str, ...]
    activations: np.ndarray  # (F, n) OpenSim SO
    forces: np.ndarray  # (F, n) N
    reserves: np.ndarray  # (F, 20) N·m
    exact_activations: np.ndarray | None  # (F, n) exact geometry + BVLS, None if not made
    exact_reserves: np.ndarray | None
    meta: dict

    def frames(self, i: int) -> slice:
        return slice(int(self.offsets[i]), int(self.offsets[i + 1]))


def save_reference(path: Path, ref: MuscleReference) -> None:
    path = Path(path)
    tmp = path.with_suffix(".tmp.npz")
    extra = {}
    if ref.exact_activations is not None:
        extra = {"exact_activations": ref.exact_activations.astype(np.float32),
                 "exact_reserves": ref.exact_reserves.astype(np.float32)}
    np.savez_compressed(
        tmp, movement_ids=np.asarray(ref.movement_ids, np.int64),
        offsets=np.asarray(ref.offsets, np.int64), times=np.asarray(ref.times, np.float64),
        names=np.array(ref.names), activations=ref.activations.astype(np.float32),
        forces=ref.forces.astype(np.float32), reserves=ref.reserves.astype(np.float32),
        meta=np.array(json.dumps(ref.meta, sort_keys=True)), **extra)
    tmp.replace(path)


def load_reference(path: Path = REFERENCE_FILE) -> MuscleReference:
    with np.load(path, allow_pickle=False) as z:
        exact = "exact_activations" in z.files
        return MuscleReference(
            z["movement_ids"], z["offsets"], z["times"], tuple(str(x) for x in z["names"]),
            z["activations"].astype(float), z["forces"].astype(float),
            z["reserves"].astype(float),
            z["exact_activations"].astype(float) if exact else None,
            z["exact_reserves"].astype(float) if exact else None,
            json.loads(str(z["meta"])))


# -- the exact-geometry solve ------------------------------------------------------------------
def bvls_solve(mm: MuscleModel, R: np.ndarray, L: np.ndarray, V: np.ndarray, tau: np.ndarray,
               *, velocity: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """min Σa² + Σ(r/r_opt)² s.t. R·F(a) + r = τ, 0 ≤ a ≤ 1, by eliminating r = τ − A·a:
    min ‖a‖² + ‖(τ − A·a)/r_opt‖², a bounded linear least-squares problem solved exactly by
    scipy's BVLS (active set, finite termination). Returns (activations, reserves)."""
    from scipy.optimize import lsq_linear

    from ..muscles.curves import unit_forces

    unit, _ = unit_forces(mm.params(), L, V, use_velocity=velocity, passive=False)
    A = R.T * unit[None, :]  # (20, n)
    w = 1.0 / RESERVE_OPTIMAL_TORQUE
    M = np.vstack([np.eye(mm.n), w * A])
    b = np.concatenate([np.zeros(mm.n), w * tau])
    sol = lsq_linear(M, b, bounds=(0.0, 1.0), method="bvls", tol=1e-14, max_iter=10_000)
    a = np.clip(sol.x, 0.0, 1.0)
    return a, tau - A @ a


# -- the comparison ----------------------------------------------------------------------------
@dataclass
class MuscleFigures:
    """Per-muscle figures of ours against a reference over the accepted frames."""

    names: tuple[str, ...]
    rms_da: np.ndarray  # (n,)
    max_da: np.ndarray
    force_rms_pct: np.ndarray  # (n,) % of max isometric force (nan without forces)
    peak: np.ndarray  # (n,) the reference's peak activation
    corr: np.ndarray  # (n,) nan where peak < PEAK_FOR_CORRELATION
    frames: int
    rejected: dict[str, int]

    def passes(self) -> bool:
        corr = self.corr[self.peak >= PEAK_FOR_CORRELATION]
        force = self.force_rms_pct[np.isfinite(self.force_rms_pct)]
        return bool(np.all(self.rms_da <= TARGET_RMS_DA) and np.all(force <= TARGET_FORCE_PCT)
                    and np.all(corr >= TARGET_CORR))

    def worst(self, k: int = 5) -> list[dict]:
        order = np.argsort(-self.rms_da)[:k]
        return [self.row(i) for i in order]

    def row(self, i: int) -> dict:
        return {"muscle": self.names[i], "rms_da": float(self.rms_da[i]),
                "max_da": float(self.max_da[i]), "force_rms_pct": float(self.force_rms_pct[i]),
                "peak_activation": float(self.peak[i]),
                "correlation": None if not np.isfinite(self.corr[i]) else float(self.corr[i])}

    def summary(self) -> dict:
        corr = self.corr[np.isfinite(self.corr)]
        return {"frames": self.frames, "rejected": self.rejected,
                "max_rms_da": float(self.rms_da.max()), "max_abs_da": float(self.max_da.max()),
                "max_force_rms_pct": float(np.nanmax(self.force_rms_pct))
                if np.isfinite(self.force_rms_pct).any() else None,
                "min_correlation": float(corr.min()) if len(corr) else None,
                "muscles_correlated": len(corr), "passes": self.passes(),
                "worst": self.worst()}


def figures(mm: MuscleModel, ours_a: np.ndarray, ref_a: np.ndarray, keep: np.ndarray,
            rejected: dict[str, int], ours_f: np.ndarray | None = None,
            ref_f: np.ndarray | None = None) -> MuscleFigures:
    a, r = ours_a[keep], ref_a[keep]
    da = a - r
    rms = np.sqrt((da ** 2).mean(axis=0))
    if ours_f is not None and ref_f is not None:
        df = (ours_f[keep] - ref_f[keep]) / mm.max_isometric_force
        force = 100.0 * np.sqrt((df ** 2).mean(axis=0))
    else:
        force = np.full(mm.n, np.nan)
    peak = r.max(axis=0)
    corr = np.full(mm.n, np.nan)
    for i in np.flatnonzero(peak >= PEAK_FOR_CORRELATION):
        if a[:, i].std() > 0 and r[:, i].std() > 0:
            corr[i] = float(np.corrcoef(a[:, i], r[:, i])[0, 1])
        else:
            corr[i] = 1.0 if np.allclose(a[:, i], r[:, i], atol=TARGET_RMS_DA) else 0.0
    return MuscleFigures(mm.names, rms, np.abs(da).max(axis=0), force, peak, corr,
                         int(keep.sum()), rejected)


def accepted_frames(mm: MuscleModel, q: np.ndarray, tau: np.ndarray, forces: np.ndarray,
                    reserves: np.ndarray) -> tuple[np.ndarray, dict[str, int]]:
    """Frames to compare: OpenSim's reserves below RESERVE_LIMIT_NM and its torques (Σ R·F +
    r) within TORQUE_LIMIT_NM of ours (else its constraint was not met, or its splines'
    derivatives differ from the movement's), and every spanned joint inside the surrogate's
    fit box (outside it the node clips the posture to the box's edge and OpenSim's
    polynomials, which cannot clip, extrapolate: the two geometries differ there)."""
    R = mm.moment_arms(q)
    tau_so = np.einsum("kij,ki->kj", R, forces) + reserves
    reserve_use = np.abs(reserves).max(axis=1) > RESERVE_LIMIT_NM
    torque_off = np.abs(tau_so - tau).max(axis=1) > TORQUE_LIMIT_NM
    outside = ~mm.surrogate.in_box(q)
    keep = ~(reserve_use | torque_off | outside)
    return keep, {"reserve_use": int(reserve_use.sum()),
                  "torque_mismatch": int((torque_off & ~reserve_use).sum()),
                  "outside_fit_box": int((outside & ~(reserve_use | torque_off)).sum())}


__all__ = ["JOINT_NAMES", "MuscleFigures", "MuscleReference", "accepted_frames", "bvls_solve",
           "figures", "load_reference", "save_reference"]
