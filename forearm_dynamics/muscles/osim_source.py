"""An OpenSim model's muscles at our joints (`OsimSource`): what source_osim.py fits.

Why a module of its own: reading the model (mapping, holding, constraints, parameters,
computeMomentArm, NaN paths, the model's own ranges) is one job; fitting and the command
line (source_osim.py) another. See source_osim.py for what is done and why.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..coordinate_map import CoordinateMap
from ..description import JOINT_NAMES
from ..errors import MotionError, UsageError
from .fit import joint_box
from .model import MuscleModelError

DEFAULT_VMAX = 10.0  # optimal fibre lengths per second: OpenSim DeGrooteFregly2016Muscle's
SPAN_MIN_M = 1e-6  # a moment arm this large at some posture: the muscle crosses the joint
SPAN_POSTURES = 12
REPAIR_DEG = 0.5  # a NaN path is taken this far away (normal σ per mapped joint)
#: (OpenSim property, our parameter, rule): "pos" > 0, "nonneg" >= 0, "angle" in [0, 90°)
PROPERTIES = (
    ("max_isometric_force", "max_isometric_force", "pos"),
    ("optimal_fiber_length", "optimal_fiber_length", "pos"),
    ("tendon_slack_length", "tendon_slack_length", "nonneg"),
    ("pennation_angle_at_optimal", "pennation_at_optimal", "angle"),
)


def _opensim() -> Any:
    try:
        import opensim
    except ImportError:
        raise UsageError("reading an .osim model needs the optional 'opensim' package (OpenSim "
                         "4.6): pip install -e '.[reference]'") from None
    opensim.Logger.removeFileSink()  # no opensim.log in the user's working directory
    opensim.Logger.setLevelString("error")
    return opensim


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class Mapped:
    joint: str  # ours
    coordinate: str  # the model's
    sign: float
    offset: float  # rad: ours = sign * theirs + offset


class OsimSource:
    """An OpenSim model's muscles at our joints: lengths and moment arms (fit.MyoArm's
    interface: names, evaluate, parameters, version)."""

    def __init__(self, path: str | Path, side: str = "right", cmap: CoordinateMap | None = None,
                 progress=print, exclude: tuple[str, ...] = ()):
        osim = _opensim()
        self.path = Path(path)
        if not self.path.is_file():
            raise UsageError(f"{self.path}: no such OpenSim model file")
        self.progress = progress
        self.n_evaluated = 0  # postures asked of OpenSim (the report's cost figure)
        self.box_rule = "our joints' ranges cut to the model's coordinate ranges (mapped)"
        self.repaired: dict[str, list] = {}  # muscle -> postures (deg, mapped) repaired
        cmap = cmap if cmap is not None else CoordinateMap.load()
        try:
            model = osim.Model(str(self.path))
        except RuntimeError as exc:
            first = (str(exc).strip().splitlines() or ["?"])[0]
            raise MuscleModelError(f"{self.path}: OpenSim cannot read it as a model: {first}") from None
        coords = model.getCoordinateSet()
        names = [coords.get(i).getName() for i in range(coords.getSize())]
        entries = cmap.for_side(side)
        cmap.check_present(side, names, f"coordinate of {self.path}", names)
        self.mapped: list[Mapped] = []
        for n in names:
            if n in entries:
                joint, sign, offset = entries[n]
                if any(m.joint == joint for m in self.mapped):
                    other = next(m.coordinate for m in self.mapped if m.joint == joint)
                    raise MotionError(f"{self.path}: coordinates {other!r} and {n!r} both map "
                                      f"to {joint} ({cmap.path})")
                self.mapped.append(Mapped(joint, n, sign, offset))
                c = coords.get(n)
                c.set_locked(False)  # MoBL-ARMS locks its wrist by default
                c.set_clamped(False)
        if not self.mapped:
            raise MotionError(f"{self.path}: no coordinate maps to a joint of ours (its "
                              f"coordinates: {', '.join(names[:10])}); see {cmap.path}")
        self.state = state = model.initSystem()
        self.model, self.osim = model, osim
        mapped_names = {m.coordinate for m in self.mapped}
        self.held: dict[str, float] = {}
        self.dependent: list[str] = []
        for n in names:
            if n in mapped_names:
                continue
            c = coords.get(n)
            if c.isDependent(state):
                self.dependent.append(n)
                continue
            v = c.getDefaultValue()
            if not c.getDefaultLocked() and c.getRangeMin() <= 0.0 <= c.getRangeMax():
                v = 0.0
                c.setValue(state, v, False)
            self.held[n] = v
        self.unmapped_line = ("coordinates mapped to none of our joints (held; dependent ones "
                              f"follow their constraints): {', '.join(self.held)}"
                              + (f"; dependent: {', '.join(self.dependent)}" if self.dependent else ""))
        self._constrained = model.getConstraintSet().getSize() > 0
        self.box = self._source_box(coords)
        self._coord = [coords.get(m.coordinate) for m in self.mapped]
        self._col = np.array([JOINT_NAMES.index(m.joint) for m in self.mapped])
        self._sign = np.array([m.sign for m in self.mapped])
        self._offset = np.array([m.offset for m in self.mapped])
        ms = model.getMuscles()
        every = [ms.get(i).getName() for i in range(ms.getSize())]
        unknown = [n for n in exclude if n not in every]
        if unknown:
            raise UsageError(f"{self.path}: --exclude names no muscle of the model: "
                             f"{', '.join(unknown)} (its muscles: {', '.join(every[:8])} ...)")
        self.excluded = list(exclude)
        muscles = [ms.get(i) for i in range(ms.getSize()) if ms.get(i).getName() not in exclude]
        self.vmax_replaced: list[str] = []
        self._params = {}
        for mus in muscles:  # refuse a bad file before minutes of sampling
            self._params[mus.getName()] = self._read_parameters(mus)
        self.all_names = [m.getName() for m in muscles]
        self._muscles = muscles
        self._pairs = [list(range(len(self.mapped)))] * len(muscles)  # until spans are known
        self.spans = self._find_spans()
        keep = [i for i, s in enumerate(self.spans) if s]
        self.dropped = [self.all_names[i] for i in range(len(muscles)) if not self.spans[i]]
        self._muscles = [muscles[i] for i in keep]
        self._pairs = [self.spans[i] for i in keep]
        self.names = [self.all_names[i] for i in keep]
        self.vmax_replaced = [n for n in self.vmax_replaced if n in self.names]
        self.version = {"file": str(self.path), "sha256": sha256(self.path),
                        "opensim": osim.__version__}

    def _source_box(self, coords) -> tuple[np.ndarray, np.ndarray]:
        """Our joints' ranges cut to the model's own coordinate ranges (mapped to ours): past
        them a model's geometry is untested (MoBL's FCU wrapping fails past 70° of wrist
        flexion, which ours reaches to 80°); the surrogate holds its edge value there."""
        lo, hi = joint_box()
        lo, hi = lo.copy(), hi.copy()
        for m in self.mapped:
            c, j = coords.get(m.coordinate), JOINT_NAMES.index(m.joint)
            ends = sorted(m.sign * v + m.offset for v in (c.getRangeMin(), c.getRangeMax()))
            lo[j], hi[j] = max(lo[j], ends[0]), min(hi[j], ends[1])
            if hi[j] - lo[j] < math.radians(1.0):
                raise MuscleModelError(
                    f"{self.path}: coordinate {m.coordinate}'s range ({math.degrees(ends[0]):.1f}"
                    f" to {math.degrees(ends[1]):.1f} deg as {m.joint}) leaves nothing of "
                    f"{m.joint}'s range (check the map's sign and offset)")
        return lo, hi

    def _read_parameters(self, mus) -> dict[str, float]:
        name, out = mus.getName(), {}
        for prop, ours, rule in PROPERTIES:
            p = mus.getPropertyByName(prop)
            v = float(getattr(mus, "get_" + prop)())
            if p.getValueIsDefault():
                raise MuscleModelError(f"{self.path}: muscle {name!r}: parameter {prop!r} is "
                                       "missing (the file does not state it)")
            ok = math.isfinite(v) and (v > 0 if rule == "pos" else v >= 0 if rule == "nonneg"
                                       else 0 <= v < math.pi / 2)
            if not ok:
                what = {"pos": "a positive number", "nonneg": "a non-negative number",
                        "angle": "an angle in [0, 90°) (rad)"}[rule]
                raise MuscleModelError(f"{self.path}: muscle {name!r}: parameter {prop!r} = "
                                       f"{v!r} must be {what}")
            out[ours] = v
        p = mus.getPropertyByName("max_contraction_velocity")
        vmax = float(mus.get_max_contraction_velocity())
        if p.getValueIsDefault() or not (math.isfinite(vmax) and vmax > 0):
            vmax = DEFAULT_VMAX
            self.vmax_replaced.append(name)
        out["max_contraction_velocity"] = vmax
        return out

    def _find_spans(self) -> list[list[int]]:
        lo, hi = self.box
        q = np.random.default_rng(12345).uniform(lo, hi, size=(SPAN_POSTURES, 20))
        _, R = self._evaluate(q, range(len(self._muscles)))
        big = np.abs(R).max(axis=0) > SPAN_MIN_M  # (muscles, 20)
        return [[k for k, c in enumerate(self._col) if big[i, c]] for i in range(len(big))]

    def _set(self, qk: np.ndarray) -> None:
        s = self.state
        for c, v in zip(self._coord, self._sign * (qk[self._col] - self._offset)):
            c.setValue(s, float(v), False)
        if self._constrained:
            self.model.assemble(s)
            got = np.array([c.getValue(s) for c in self._coord])
            want = self._sign * (qk[self._col] - self._offset)
            if np.abs(got - want).max() > 1e-6:
                k = int(np.argmax(np.abs(got - want)))
                raise MuscleModelError(f"{self.path}: the model's constraints move coordinate "
                                       f"{self.mapped[k].coordinate} ({want[k]:.4f} rad set, "
                                       f"{got[k]:.4f} assembled): it cannot be one of our joints")
        self.model.realizePosition(s)

    def _evaluate(self, q: np.ndarray, rows) -> tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(q)
        rows = list(rows)
        L = np.empty((len(q), len(rows)))
        R = np.zeros((len(q), len(rows), 20))
        t0 = last = time.perf_counter()
        for k, qk in enumerate(q):
            self._set(qk)
            failed = [i for i, m in enumerate(rows) if not self._one(m, L[k], R[k], i)]
            for i in failed:  # OpenSim's wrapping gave NaN here (MoBL's FCU): a posture 0.5° off
                self._repair(rows[i], qk, L[k], R[k], i)
            now = time.perf_counter()
            if self.progress and now - last > 10.0:
                last = now
                self.progress(f"  {k + 1}/{len(q)} postures ({(now - t0) / (k + 1) * 1e3:.0f} ms "
                              "each)", flush=True)
        self.n_evaluated += len(q)
        return L, R

    def _one(self, m: int, L: np.ndarray, R: np.ndarray, i: int) -> bool:
        """Muscle m's length and moment arms at the state's posture into L[i], R[i]; False
        when OpenSim gives a value that is not finite."""
        mus, s = self._muscles[m], self.state
        L[i] = mus.getLength(s)
        for p in self._pairs[m]:
            R[i, self._col[p]] = self._sign[p] * mus.computeMomentArm(s, self._coord[p])
        return bool(np.isfinite(L[i]) and np.isfinite(R[i]).all())

    def _repair(self, m: int, qk: np.ndarray, L: np.ndarray, R: np.ndarray, i: int) -> None:
        """A path OpenSim cannot compute at qk (NaN: a wrapping surface's singular case) takes
        its values at the first of up to 5 postures ~REPAIR_DEG off where it is finite,
        counted in `repaired` (the file's source.nan_repaired)."""
        name = self._muscles[m].getName()
        rng = np.random.default_rng(len(self.repaired.get(name, ())))
        for _ in range(5):
            qj = qk.copy()
            qj[self._col] += rng.normal(0.0, math.radians(REPAIR_DEG), len(self._col))
            self._set(qj)
            if self._one(m, L, R, i):
                self.repaired.setdefault(name, []).append([round(math.degrees(v), 2)
                                                           for v in qk[self._col]])
                self._set(qk)
                return
        raise MuscleModelError(f"{self.path}: muscle {name!r}: OpenSim gives no finite length "
                               f"or moment arm near {np.degrees(qk[self._col]).round(1).tolist()} "
                               f"deg ({', '.join(mp.joint for mp in self.mapped)})")

    def evaluate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q (N, 20) ours -> lengths (N, n) m, moment arms (N, n, 20) m (our signs)."""
        return self._evaluate(q, range(len(self._muscles)))

    def parameters(self, i: int) -> dict[str, float]:
        return dict(self._params[self.names[i]])

    def source(self) -> dict[str, Any]:
        """The provenance fit.build writes into the file's `source`."""
        return {
            "name": f"OpenSim model {self.path.name} ({self.model.getName()})",
            "version": self.version,
            "licence": "as stated by the user's file",
            "url": str(self.path),
            "sha256": self.version["sha256"],
            "notice": ("derived on the user's machine from their own model; its licence "
                       "applies to this file (do not redistribute what it forbids)"),
            "derived_by": "python -m forearm_dynamics.muscles.source_osim (forearm_dynamics)",
            "mapping": {m.joint: {"source_joint": m.coordinate, "sign": m.sign,
                                  "offset_deg": round(math.degrees(m.offset), 6)}
                        for m in self.mapped},
            "held": {n: round(math.degrees(v), 6) for n, v in self.held.items()},
            "held_unit": "deg (rotational) or m (translational), as the coordinate",
            "dependent": self.dependent,
            "dropped_muscles": self.dropped,
            "excluded_muscles": self.excluded,
            "fit_box_deg": {m.joint: [round(math.degrees(self.box[0][j]), 3),
                                      round(math.degrees(self.box[1][j]), 3)]
                            for m in self.mapped for j in [JOINT_NAMES.index(m.joint)]},
            "fit_box_rule": self.box_rule,
            "nan_repaired": {n: len(v) for n, v in self.repaired.items()},
            "nan_repair_rule": (f"a posture where OpenSim gives a NaN length or moment arm "
                                f"takes the values at a posture ~{REPAIR_DEG}° off"),
            "moment_arms": ("OpenSim Muscle.computeMomentArm(state, coordinate) × sign "
                            "(constraint-consistent; not -dL/dq)"),
            "parameter_rule": ("max isometric force, optimal fibre length, tendon slack "
                               "length, pennation at optimal as the file states them; max "
                               f"contraction velocity the file's, or {DEFAULT_VMAX:g} optimal "
                               "lengths/s (OpenSim DeGrooteFregly2016Muscle's default) where "
                               f"it is 0 or absent: {len(self.vmax_replaced)} muscles"),
            "vmax_replaced": self.vmax_replaced,
        }
