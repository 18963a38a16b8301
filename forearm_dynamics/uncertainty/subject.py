"""The subject-parameter part of the σ: how far this person's torques may be from the model's
because their forearm and hand are not the ones their stature and body mass predict.

The model is built from a body size (anthropometry.BodySize: forearm length, hand length,
hand breadth and body mass as ratios to MoBL-ARMS) and scales every segment mass with body
mass. A real person of that stature and mass differs: θ = ln of (forearm_length,
hand_length, hand_breadth, forearm_mass, hand_mass) has, around the model's values, the
residual covariance Σ_θ of ANSUR II after regression on stature and body mass
(subject_stats.py, data/subject_ansur.json; masses from volume proxies). Lengths are part of
it: they move the COMs and inertias AND the joints (the wrist's and every finger joint's
origin), so τ is not linear in the inertial parameters at fixed kinematics (the joint
torque regressor's Y(q, q̇, q̈) changes with the lengths) and Var τ = Y Σ_π Yᵀ would leave
the lever arms out. Instead, first order in θ with the model rebuilt:

    Σ_θ = Σ_k s_k s_kᵀ  (s_k = √λ_k v_k, its eigen-decomposition)
    Var τ = Σ_k ((τ(θ = +s_k) − τ(θ = −s_k)) / 2)²

the 2K models (K ≤ 5) built once, at construction, through the same builders as the model
itself (build_tree with the perturbed BodySize; each forearm and hand link's mass and
inertia times e^θ, the payload and the humerus left as given), and 2K RNEAs per
evaluation (central differences: exact to second order in θ). TorqueStd evaluates it when
it re-linearises (every 4 ms of stream time), like the estimation part.

Which covariance: the sex of the body size (women's "female_*", men's 5/50/95), both sexes
pooled for a custom body size ("all"; wider). Dimensions the user measured (a custom
body size given forearm_length, hand_length, hand_breadth) have no spread, and the others
are conditioned on them: Σ_uu − Σ_um Σ_mm⁻¹ Σ_mu (`measured=`).

Why the σ does not include it by default (`subject="none"`): it is a bias constant over a
session for one person, not an error that varies sample to sample, and it is not what a
comparison against the same model's truth (check_bag, benchmarks/uncertainty.py) can
check; it is for a user whose model is scaled from stature and body mass and who wants the
band to cover the person, not the model.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from ..builders import build_tree
from ..description import load_description
from ..dynamics import pinocchio_model
from ..tree import KinematicTree
from .subject_stats import DIMS, GROUPS, load_stats

#: values of the `subject` option: "none" (no subject part), "ansur" (the group from the
#: body size), or a group named
SUBJECT_CHOICES = ("none", "ansur", *(f"ansur_{g}" for g in GROUPS))
#: the links that make the forearm (simplified: the cylinder's two parts; anatomical: the bones)
FOREARM_LINKS = frozenset({"forearm_proximal", "forearm_distal", "ulna", "radius"})
#: eigen-directions with less variance than this fraction of the largest are dropped
_RANK_TOL = 1e-12


def group_for(body_size) -> str:
    """"female" for the women's sizes, "male" for the men's, "all" for a custom size."""
    label = body_size.label
    if label.startswith("female_"):
        return "female"
    if label == "custom":
        return "all"
    return "male"


def spread_covariance(group: str, measured=()) -> np.ndarray:
    """Σ_θ (5, 5) in DIMS order for one ANSUR group, conditioned on the measured dimensions
    (their rows and columns 0)."""
    if group not in GROUPS:
        raise ValueError(f"subject group must be one of {GROUPS}, got {group!r}")
    unknown = set(measured) - set(DIMS)
    if unknown:
        raise ValueError(f"measured dimensions {sorted(unknown)} are not among {DIMS}")
    cov = np.array(load_stats()["groups"][group]["residual_cov"], float)
    m = [DIMS.index(d) for d in measured]
    u = [i for i in range(len(DIMS)) if i not in m]
    out = np.zeros_like(cov)
    if not m:
        return cov
    cuu, cum, cmm = cov[np.ix_(u, u)], cov[np.ix_(u, m)], cov[np.ix_(m, m)]
    out[np.ix_(u, u)] = cuu - cum @ np.linalg.solve(cmm, cum.T)
    return out


def _rebuild_args(arm) -> tuple[str, dict]:
    """(kind, build_tree keywords) that rebuild arm's forearm placement at another size."""
    pl = arm.placement
    if pl is None:
        return arm.kind, {}
    k = arm.body_size.forearm  # ForearmPlacement holds offsets at its size; build_tree takes them at p50
    offsets = {"axis_offset_proximal": np.asarray(pl.axis_offset_proximal) / k,
               "axis_offset_distal": np.asarray(pl.axis_offset_distal) / k}
    if pl.name in load_description().simplified.placements:
        return arm.kind, {"placement": pl.name, "cylinder": pl.cylinder}
    split = "radius_inertia" if pl.split_rule == "radius_inertia" else pl.split
    if arm.kind == "solid":
        return "solid", {**offsets, "cylinder": pl.cylinder}
    return arm.kind, {**offsets, "split": split, "cylinder": pl.cylinder}


def perturbed_tree(arm, theta) -> KinematicTree:
    """arm's tree for a person whose DIMS are e^θ times the model's (θ (5,), ln ratios)."""
    th = np.asarray(theta, float).reshape(len(DIMS))
    size = arm.body_size
    size = replace(size, forearm=size.forearm * np.exp(th[0]), hand_length=size.hand_length * np.exp(th[1]),
                   hand_breadth=size.hand_breadth * np.exp(th[2]))
    kind, kw = _rebuild_args(arm)
    tree = build_tree(kind, load_description(), size, side=arm.side, payload=arm.payload, **kw)
    fm, hm = float(np.exp(th[3])), float(np.exp(th[4]))

    def scaled(link):
        f = fm if link.name in FOREARM_LINKS else hm
        return replace(link, mass=link.mass * f, inertia=link.inertia * f)

    # tree.links: every moving link (forearm and hand); the root (humerus) moves nothing, and
    # fixed_links (the payload) are what the user gave
    return replace(tree, links=tuple(scaled(link) for link in tree.links))


class SubjectSpread:
    """Var τ (N·m²) from the spread of the subject's segment parameters at the arm's stature
    and body mass (module docstring). `variance(q, qd, qdd)` costs 2K RNEAs (K ≤ 5)."""

    def __init__(self, arm, group: str | None = None, measured=(), cov=None):
        """cov: a Σ_θ (5, 5) of one's own instead of the ANSUR group's (the tests' Monte Carlo)."""
        self.group = group_for(arm.body_size) if group is None else group
        self.measured = tuple(measured)
        self.cov = spread_covariance(self.group, self.measured) if cov is None else np.asarray(cov, float)
        w, v = np.linalg.eigh(self.cov)
        keep = w > _RANK_TOL * max(w.max(), 1e-300)
        self.directions = (v[:, keep] * np.sqrt(w[keep])).T  # (K, 5): Σ_θ = Σ_k s_k s_kᵀ
        self._models = []
        for s in self.directions:
            pair = []
            for sign in (1.0, -1.0):
                m = pinocchio_model(perturbed_tree(arm, sign * s))
                pair.append((m, m.createData()))
            self._models.append(pair)
        self.nv = arm.nv
        self.var = np.zeros(arm.nv)
        self._d = np.zeros(arm.nv)
        sd = np.sqrt(np.diag(self.cov))
        spread = ", ".join(f"{d} {100 * s:.1f} %" for d, s in zip(DIMS, sd, strict=True) if s > 0)
        what = f"measured (no spread): {', '.join(self.measured)}; " if self.measured else ""
        self.description = (
            f"segment parameters of a person of this stature and body mass: ANSUR II {self.group} "
            f"(n = {load_stats()['groups'][self.group]['n']}) residual spread after regression on "
            f"stature and body mass, {what}1 SD {spread} (masses from volume proxies); "
            "through the model rebuilt along each principal direction (uncertainty/subject.py)")

    def variance(self, q, qd, qdd, out: np.ndarray | None = None) -> np.ndarray:
        """Σ_k ((τ₊ₖ − τ₋ₖ) / 2)² at one state, (nv,) N·m² (into `out` if given)."""
        out = self.var if out is None else out
        out.fill(0.0)
        d = self._d
        for (mp, dp), (mm, dm) in self._models:
            np.subtract(pin.rnea(mp, dp, q, qd, qdd), pin.rnea(mm, dm, q, qd, qdd), out=d)
            d *= 0.5
            d *= d
            out += d
        return out


def subject_spread(arm, subject: str = "none", measured=()) -> SubjectSpread | None:
    """The `subject` option: None for "none", else a SubjectSpread for the group it names."""
    if subject not in SUBJECT_CHOICES:
        raise ValueError(f"subject must be one of {SUBJECT_CHOICES}, got {subject!r}")
    if subject == "none":
        if measured:
            raise ValueError("subject_measured applies only with a subject part (subject='ansur')")
        return None
    return SubjectSpread(arm, None if subject == "ansur" else subject.removeprefix("ansur_"), measured)
