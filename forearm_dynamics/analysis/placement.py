"""The model variants of the comparison, and fitting their free placement coordinates.

Every variant says how many coordinates were fitted to the anatomical reference, so a table
can compare models with equal freedom. The fits minimise OBJECTIVE (below) with Nelder-Mead
and are cached in a JSON file keyed by everything they depend on (FitCache).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import minimize

from ..anthropometry import resolve_body_size
from ..builders import build_tree, resolve_placement
from ..description import ModelDescription, load_description
from ..dynamics import ArmModel
from ..paths import config_file
from ..reference import REFERENCE_FILE
from .comparison import Trials, compare
from .errors import ErrorSet

#: What every fit minimises (also written to results.json and the README).
OBJECTIVE = ("mean over the movements of the pro/sup NRMSE plus the mean of the elbow NRMSE, "
             "each normalised by that DOF's reference peak-to-peak over all 65 movements "
             "(global normalisation: a movement with a near-constant torque cannot dominate)")
CM = 0.01  # the optimiser works in cm so every coordinate has a similar scale
FIT_VERSION = 2  # bump when the objective or the optimiser changes: the cache is refitted
NM_OPTIONS = {"xatol": 5e-3, "fatol": 1e-6, "maxfev": 600}


@dataclass(frozen=True)
class Variant:
    """One model of the comparison. free: fitted coordinates ("split", "proximal", "distal":
    a 2-D axis offset at that end, "offset": one 2-D offset used at both ends = an axis
    parallel to the cylinder)."""

    name: str
    kind: str  # "solid" | "segmented"
    label: str
    free: tuple[str, ...] = ()
    placement: str | None = None  # named placement of config/model.yaml (segmented)
    cylinder: str = "uniform"
    start: tuple = ()  # where a fit starts: split and offsets (m) in `free` order

    @property
    def n_fitted(self) -> int:
        return sum(1 if f == "split" else 2 for f in self.free)


VARIANTS: dict[str, Variant] = {v.name: v for v in (
    Variant("solid", "solid", "solid (paper: pro/sup about the cylinder's axis)"),
    Variant("solid_mass_matched", "solid", "solid, mass-matched cylinder (COM = ulna + radius)",
            cylinder="mass_matched"),
    Variant("paper", "segmented", "segmented, paper placement (axis on the centreline)",
            placement="paper"),
    Variant("solid_parallel_axis", "solid", "solid, parallel axis fitted", ("offset",),
            start=((-0.008, 0.008),)),
    Variant("parallel", "segmented", "segmented, parallel axis fitted (paper's split rule)",
            ("offset",), placement="parallel", start=((-0.008, 0.008),)),
    Variant("solid_fitted_axis", "solid", "solid, oblique axis fitted", ("proximal", "distal"),
            start=((0.0, 0.015), (-0.015, 0.0))),
    Variant("oblique", "segmented", "segmented, oblique axis + split fitted (extension)",
            ("split", "proximal", "distal"), placement="oblique",
            start=(0.6, (0.0, 0.015), (-0.015, 0.002))),
)}
#: The rows of the headline table, in order of fitted parameters.
HEADLINE = ("solid", "solid_mass_matched", "paper", "solid_parallel_axis", "parallel",
            "solid_fitted_axis", "oblique")


def configured_overrides(name: str) -> dict:
    """A named placement's configured coordinates as explicit overrides (to perturb or refit)."""
    spec = load_description().simplified.placements[name]
    out = {"axis_offset_proximal": spec.axis_offset_proximal.tolist(),
           "axis_offset_distal": spec.axis_offset_distal.tolist()}
    if not isinstance(spec.split, str):
        out["split"] = spec.split
    return out


def fitted_overrides(v: Variant, x: np.ndarray) -> dict:
    """Optimiser coordinates (split, offsets in cm) -> build overrides (offsets in m)."""
    out, k = {}, 0
    for f in v.free:
        if f == "split":
            out["split"] = float(np.clip(x[k], 0.0, 1.0))
            k += 1
        else:
            off = [float(x[k]) * CM, float(x[k + 1]) * CM]
            keys = ("proximal", "distal") if f == "offset" else (f,)
            for end in keys:
                out[f"axis_offset_{end}"] = off
            k += 2
    return out


def _x0(v: Variant) -> tuple[np.ndarray, np.ndarray]:
    """Start point and an initial simplex (3 mm steps, 0.05 in split)."""
    x0, steps = [], []
    for f, s in zip(v.free, v.start, strict=True):
        if f == "split":
            x0.append(float(s))
            steps.append(0.05)
        else:
            x0 += [s[0] / CM, s[1] / CM]
            steps += [0.3, 0.3]
    x0 = np.array(x0)
    simplex = np.vstack([x0] + [x0 + np.eye(len(x0))[i] * steps[i] for i in range(len(x0))])
    return x0, simplex


class Scorer:
    """Scores model variants on a set of movements against filtered reference torques.

    global_ptp: the normalising ranges (from all 65 movements), so a subset is scored on the
    same scale. desc: a modified description (sensitivity cases); None = config/model.yaml.
    """

    def __init__(self, reference: np.ndarray, trials: Trials, global_ptp: np.ndarray,
                 body_size=50, desc: ModelDescription | None = None):
        self.reference, self.trials, self.global_ptp = reference, trials, global_ptp
        self.size = resolve_body_size(body_size)
        self.desc = desc or load_description()

    def model(self, v: Variant, **overrides) -> ArmModel:
        kw = {"cylinder": v.cylinder, **overrides}
        if v.kind == "segmented":
            kw["placement"] = v.placement
        tree = build_tree(v.kind, self.desc, self.size, **kw)
        return ArmModel(tree, resolve_placement(v.kind, self.desc, self.size, **kw))

    def anatomical_model(self) -> ArmModel:
        return ArmModel(build_tree("anatomical", self.desc, self.size))

    def errors(self, v: Variant, **overrides) -> ErrorSet:
        return self.errors_of_model(self.model(v, **overrides))

    def errors_of_model(self, model: ArmModel) -> ErrorSet:
        return compare(model, self.reference, self.trials, self.global_ptp)

    def objective(self, v: Variant, **overrides) -> float:
        return objective_of(self.errors(v, **overrides))

    def subset(self, movement_ids) -> Scorer:
        rows = [self.trials.movement_ids.index(i) for i in movement_ids]
        out = Scorer(self.reference[rows], self.trials.subset(movement_ids), self.global_ptp,
                     self.size, self.desc)
        return out


def objective_of(e: ErrorSet) -> float:
    return float(np.nanmean(e.nrmse_global[:, 1]) + np.nanmean(e.nrmse_global[:, 0]))


def fit(v: Variant, scorer: Scorer, start: tuple | None = None, callback=None) -> dict:
    """Nelder-Mead over the variant's free coordinates; {overrides, objective, evaluations}."""
    if not v.free:
        raise ValueError(f"variant {v.name!r} has nothing to fit")
    x0, simplex = _x0(replace(v, start=start) if start else v)

    def f(x):
        if callback:
            callback()
        return scorer.objective(v, **fitted_overrides(v, x))

    r = minimize(f, x0, method="Nelder-Mead", options={**NM_OPTIONS, "initial_simplex": simplex})
    return {"overrides": fitted_overrides(v, r.x), "objective": float(r.fun), "evaluations": int(r.nfev)}


def start_of(v: Variant, overrides: dict) -> tuple:
    """A fit's result as a start point for the same variant (e.g. at another body size)."""
    out = []
    for f in v.free:
        if f == "split":
            out.append(overrides["split"])
        else:
            out.append(tuple(overrides["axis_offset_proximal" if f == "offset" else f"axis_offset_{f}"]))
    return tuple(out)


def _config_content(name: str, drop: tuple[str, ...] = ()) -> str:
    """A config file's content (parsed, canonical JSON): comments and layout do not count,
    so correcting a citation does not invalidate the fits."""
    data = yaml.safe_load(config_file(name).read_text(encoding="utf-8"))
    for key in drop:
        data.pop(key, None)
    return json.dumps(data, sort_keys=True)


def inputs_digest() -> str:
    """Hash of everything a fit depends on besides its own spec. model.yaml counts without
    its `simplified:` block: the fits write that block, not read it."""
    h = hashlib.sha256()
    h.update(f"fit-version {FIT_VERSION} {OBJECTIVE} {sorted(NM_OPTIONS.items())}".encode())
    h.update(REFERENCE_FILE.read_bytes())
    for name in ("movements.yaml", "analysis.yaml", "body_sizes.yaml"):
        h.update(_config_content(name).encode())
    h.update(_config_content("model.yaml", drop=("simplified",)).encode())
    return h.hexdigest()


class FitCache:
    """Fits and other expensive results in one JSON file, each under a key that hashes its
    spec and inputs_digest(): change a config file, the reference or the objective and the
    entry is simply not found (and recomputed)."""

    def __init__(self, path: Path | None, seed: Path | None = None):
        """path: the cache file (read and written); seed: read when path does not exist yet
        (e.g. the checkout's committed cache for a run into another folder)."""
        self.path = path
        self.digest = inputs_digest()
        self.entries: dict = {}
        self.used: set[str] = set()
        self.hits = self.misses = 0
        source = path if path is not None and path.is_file() else seed
        if source is not None and source.is_file():
            try:
                self.entries = json.loads(source.read_text(encoding="utf-8")).get("entries", {})
            except (OSError, ValueError):
                self.entries = {}  # unreadable cache: recompute everything

    def key(self, spec: dict) -> str:
        return hashlib.sha256((self.digest + json.dumps(spec, sort_keys=True)).encode()).hexdigest()[:24]

    def get_or_compute(self, spec: dict, compute):
        k = self.key(spec)
        self.used.add(k)
        if k in self.entries:
            self.hits += 1
            return self.entries[k]["value"]
        self.misses += 1
        value = compute()
        self.entries[k] = {"spec": spec, "value": value}
        self.save()
        return value

    def save(self, prune: bool = False) -> None:
        """Write the file; prune=True keeps only the entries this run used (at the end)."""
        if self.path is None:
            return
        live = {k: v for k, v in self.entries.items() if k in self.used} if prune else self.entries
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text(json.dumps({"inputs_digest": self.digest, "entries": live}, indent=1,
                                  sort_keys=True), encoding="utf-8")
        tmp.replace(self.path)
