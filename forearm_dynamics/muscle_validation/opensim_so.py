"""OpenSim's StaticOptimization on our skeleton with the shipped muscles: the muscle reference.

Why OpenSim: it is the tool the field trusts for static optimisation; if our per-sample QP
(muscles/static_opt.py) gives OpenSim's activations on the same model, the node's muscle
forces are OpenSim's, at 1 kHz. What is the same and what is independent:

- skeleton: opensim_engine.build_osim_model(tree), our tree as an OpenSim model (its inverse
  dynamics matches Pinocchio to 1e-9 N·m); OpenSim computes the torques itself, from the
  coordinates file (every coordinate of the model: 20, no dependent ones) through its own
  splines and its own equations of motion;
- muscles: every muscle of the MuscleModel as an OpenSim `DeGrooteFregly2016Muscle` (the class
  whose optimal force SO computes correctly; Schutte1993 returns 0 there) with the same max
  isometric force, optimal fibre length, tendon slack length, pennation and max contraction
  velocity, rigid tendon (ignore_tendon_compliance) and no activation dynamics, so that SO's
  "optimal force" is F0·f_L·f_V·cos(α) as ours; OpenSim's own curves (not ours) evaluate it;
- geometry: each muscle's path is an OpenSim `FunctionBasedPath` over the joints it spans,
  whose length and moment-arm functions are `MultivariatePolynomialFunction`s holding the
  shipped surrogate's polynomials (re-expanded from the normalised joint angles to radians):
  the shipped model carries no path points (it is derived from MuJoCo tendons with wrapping
  surfaces, which OpenSim cannot load), so OpenSim sees exactly the geometry the node uses;
  the geometry itself (surrogate vs the source's exact tendon Jacobians) is validated
  separately against MuJoCo (`exact_geometry_solve`);
- reserves: one CoordinateActuator per coordinate, optimal force 1 N·m, unbounded control,
  so SO's cost (Σ a² + Σ (r/1)²) is the one our QP minimises;
- frames in which a reserve carries more than `RESERVE_LIMIT_NM` (the muscles cannot hold
  the torque: the reserve decides the split) or OpenSim's torques differ from ours by more than
  `TORQUE_LIMIT_NM` (its spline's derivatives near a movement's ends, a constraint not met) are
  rejected, counted and reported, never compared.

OpenSim is the optional `reference` extra, imported lazily; the result is cached in
forearm_dynamics/data/muscle_so_reference.npz by `make muscle-reference`
(forearm_dynamics.cli.make_muscle_reference), so the tests and the benchmark need no
OpenSim run.
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from ..description import JOINT_NAMES
from ..formats.opensim import write_table
from ..muscles import MuscleModel
from ..opensim_engine import _osim, build_osim_model
from ..tree import KinematicTree

#: One movement of each of the library's 13 kinds (wrist pro/sup, wrist flexion/extension,
#: hand open/close, combined, thumb): the reference's movements (the issue asks for >= 10).
MOVEMENT_IDS = (1, 6, 11, 16, 21, 26, 31, 36, 41, 46, 51, 56, 61)
RATE_HZ = 25.0  # SO frames per second (the coordinates file is written at 1 kHz)
COORDINATES_RATE_HZ = 1000.0
RESERVE_OPTIMAL_TORQUE = 1.0  # N·m, OpenSim's usual reserve and our QP's default
RESERVE_LIMIT_NM = 0.5  # a frame whose largest |reserve| (OpenSim's) exceeds this is rejected
TORQUE_LIMIT_NM = 0.02  # ... or whose OpenSim torques differ from ours by more than this
EDGE_S = 0.05  # frames this close to a movement's ends are not solved (spline ends)


# -- the surrogate's polynomials as OpenSim functions -------------------------------------
def _expand(coefs: np.ndarray, exps: np.ndarray, center: np.ndarray, half: np.ndarray,
            cols: Sequence[int]) -> dict[tuple[int, ...], float]:
    """Σ_k c_k Π_j ((q_j − centre_j) / half_j)^e_kj as {raw exponents (over cols): coef}."""
    out: dict[tuple[int, ...], float] = {}
    for c, e in zip(coefs, exps):
        if c == 0.0:
            continue
        # each factor ((q - c)/h)^e = Σ_i C(e, i) q^i (−c)^(e−i) / h^e
        parts = []
        for j in cols:
            ej = int(e[j])
            parts.append([(i, math.comb(ej, i) * (-center[j]) ** (ej - i) / half[j] ** ej)
                          for i in range(ej + 1)])
        for combo in product(*parts):
            key = tuple(i for i, _ in combo)
            out[key] = out.get(key, 0.0) + c * math.prod(w for _, w in combo)
    return out


def _opensim_term_order(osim, dim: int, order: int) -> list[tuple[int, ...]]:
    """The exponents of each coefficient of OpenSim's MultivariatePolynomialFunction of this
    dimension and order, found by evaluating its terms with one variable at 2 and the others
    at 1 (each term is then 2^(its exponent of that variable), exact in a double at any
    order; distinct primes at once overflowed 2^53 at order 19 in 4 dimensions): no
    reliance on a documented ordering."""
    n = math.comb(dim + order, order)
    f = osim.MultivariatePolynomialFunction()
    f.setDimension(dim)
    f.setOrder(order)
    f.setCoefficients(osim.Vector(n, 0.0))
    exps = np.zeros((n, dim), int)
    for i in range(dim):
        x = osim.Vector(dim, 1.0)
        x.set(i, 2.0)
        terms = f.getTermValues(x).to_numpy()
        e = np.rint(np.log2(terms)).astype(int)
        if len(terms) != n or np.any(terms != 2.0 ** e):
            raise RuntimeError("could not read OpenSim's polynomial term order")
        exps[:, i] = e
    keys = [tuple(int(v) for v in row) for row in exps]
    if len(set(keys)) != n:
        raise RuntimeError("OpenSim's polynomial terms are not distinct monomials")
    return keys


def _poly_function(osim, poly: dict[tuple[int, ...], float], dim: int, order: int, orders: dict):
    key = (dim, order)
    if key not in orders:
        orders[key] = _opensim_term_order(osim, dim, order)
    terms = orders[key]
    coef = np.zeros(len(terms))
    index = {t: i for i, t in enumerate(terms)}
    for e, c in poly.items():
        coef[index[e]] += c
    f = osim.MultivariatePolynomialFunction()
    f.setDimension(dim)
    f.setOrder(order)
    f.setCoefficients(osim.Vector.createFromMat(coef))
    return f


@dataclass(frozen=True)
class MusclePolynomials:
    """One muscle's path as polynomials of its joints (radians): length and moment arms."""

    joints: tuple[str, ...]
    order: int
    length: dict[tuple[int, ...], float]
    moment_arms: tuple[dict[tuple[int, ...], float], ...]  # one per joint, joints order


def muscle_polynomials(mm: MuscleModel) -> list[MusclePolynomials]:
    """The node's surrogate of every muscle, re-expanded in raw joint angles (rad).

    Read from `mm.surrogate` itself (`Surrogate.polynomial`: its coefficients after pruning
    and body-size scaling), never from the model file again: the file's coefficients are
    pruned on loading (surrogate.PRUNE_M, up to 0.02 mm per polynomial), so a re-read of the
    file gave OpenSim a geometry up to 4.6e-6 m away from the node's (PL about
    wrist_flexion, movement 36 at 0.7 s). Equal to the surrogate inside its fit box; outside
    it the surrogate holds the angle at the box's edge and OpenSim's polynomial cannot, so
    frames outside the box are never compared (`in_fit_box`, used by accepted_frames)."""
    s = mm.surrogate
    out = []
    for k, span in enumerate(mm.spans):
        cols = [JOINT_NAMES.index(j) for j in span]
        rows = [k] + [s.moment_arm_row(k, c) for c in cols]
        polys = [s.polynomial(r) for r in rows]
        order = max([int(e.sum(axis=1).max()) for e, _ in polys if len(e)] + [1])
        expanded = [_expand(c, e, s.center, s.half, cols) for e, c in polys]
        out.append(MusclePolynomials(tuple(span), order, expanded[0], tuple(expanded[1:])))
    return out


def in_fit_box(mm: MuscleModel, q: np.ndarray) -> np.ndarray:
    """(N,) True where every spanned joint is inside the surrogate's fit box: where the
    surrogate's clip is inactive, so OpenSim's (unclipped) polynomials equal it."""
    return mm.surrogate.in_box(q)


# -- the OpenSim model ----------------------------------------------------------------------
def build_so_model(tree: KinematicTree, mm: MuscleModel) -> Any:
    """Our skeleton + every muscle (DeGrooteFregly2016, FunctionBasedPath) + 1 N·m reserves."""
    osim = _osim()
    model = build_osim_model(tree)
    model.setName(f"{model.getName()}_muscles")
    orders: dict = {}
    for k, poly in enumerate(muscle_polynomials(mm)):
        path = osim.FunctionBasedPath()
        path.setName("path")
        for j in poly.joints:
            path.appendCoordinatePath(f"/jointset/{j}/{j}")
        dim = len(poly.joints)
        path.setLengthFunction(_poly_function(osim, poly.length, dim, poly.order, orders))
        for arm in poly.moment_arms:
            path.appendMomentArmFunction(_poly_function(osim, arm, dim, poly.order, orders))
        mus = osim.DeGrooteFregly2016Muscle()
        mus.setName(mm.names[k])
        mus.set_max_isometric_force(float(mm.max_isometric_force[k]))
        mus.set_optimal_fiber_length(float(mm.optimal_fiber_length[k]))
        mus.set_tendon_slack_length(float(mm.tendon_slack_length[k]))
        mus.set_pennation_angle_at_optimal(float(mm.pennation_at_optimal[k]))
        mus.set_max_contraction_velocity(float(mm.max_contraction_velocity[k]))
        mus.set_ignore_tendon_compliance(True)
        mus.set_ignore_activation_dynamics(True)
        mus.setMinControl(0.0)
        mus.setMaxControl(1.0)
        mus.set_path(path)
        model.addForce(mus)
    for j in tree.joint_names:
        res = osim.CoordinateActuator(j)
        res.setName(f"reserve_{j}")
        res.setOptimalForce(RESERVE_OPTIMAL_TORQUE)
        res.setMinControl(-1e6)
        res.setMaxControl(1e6)
        model.addForce(res)
    model.finalizeConnections()
    return model


def opensim_geometry(model, mm: MuscleModel, q: np.ndarray, qd: np.ndarray | None = None):
    """OpenSim's own moment arms (n, 20), lengths (n,) and lengthening speeds (n,) of one
    posture (computeMomentArm of each spanned pair): what SO uses, to check the expansion."""
    state = model.initSystem()
    coords = model.getCoordinateSet()
    qd = np.zeros_like(q) if qd is None else qd
    for i, j in enumerate(JOINT_NAMES):
        coords.get(j).setValue(state, float(q[i]), False)
        coords.get(j).setSpeedValue(state, float(qd[i]))
    model.realizeVelocity(state)
    R = np.zeros((mm.n, len(JOINT_NAMES)))
    L, V = np.zeros(mm.n), np.zeros(mm.n)
    muscles = model.getMuscles()
    for k, name in enumerate(mm.names):
        mus = muscles.get(name)
        L[k] = mus.getLength(state)
        V[k] = mus.getLengtheningSpeed(state)
        for j in mm.spans[k]:
            R[k, JOINT_NAMES.index(j)] = mus.computeMomentArm(state, coords.get(j))
    return R, L, V


# -- StaticOptimization ----------------------------------------------------------------------
@dataclass
class SOResult:
    """OpenSim's SO of one movement at `times` (s from the movement's start)."""

    times: np.ndarray  # (N,)
    activations: np.ndarray  # (N, n) muscles, model order
    forces: np.ndarray  # (N, n) N
    reserves: np.ndarray  # (N, 20) N·m, joint order
    seconds: float  # wall time of the run


def _read_sto(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    end = next(i for i, line in enumerate(lines) if line.strip() == "endheader")
    labels = lines[end + 1].split("\t")
    rows = [list(map(float, line.split("\t"))) for line in lines[end + 2:] if line.strip()]
    return labels, np.asarray(rows)


def run_static_optimization(model, mm: MuscleModel, t: np.ndarray, q: np.ndarray,
                            solve_times: np.ndarray, *, workdir: Path | None = None,
                            convergence: float = 1e-10, max_iterations: int = 1000) -> SOResult:
    """OpenSim's AnalyzeTool + StaticOptimization: the coordinates file holds q (N, 20) at
    `t` (every coordinate, radians); SO is solved at each of `solve_times` (a subset of t)."""
    import time

    osim = _osim()
    with tempfile.TemporaryDirectory(prefix="muscle_so_") as tmp:
        d = Path(workdir or tmp)
        mot = d / "coordinates.mot"
        write_table(mot, "coordinates", list(JOINT_NAMES), t, q)
        step = round(np.median(np.diff(solve_times)) / np.median(np.diff(t)))
        tool = osim.AnalyzeTool()
        tool.setName("so")
        tool.setModel(model)
        tool.setCoordinatesFileName(str(mot))
        tool.setLowpassCutoffFrequency(-1.0)  # the movements are smooth: no filter
        tool.setInitialTime(float(solve_times[0]))
        tool.setFinalTime(float(solve_times[-1]))
        tool.setResultsDir(str(d))
        so = osim.StaticOptimization()
        so.setName("StaticOptimization")
        so.setUseModelForceSet(True)
        so.setActivationExponent(2.0)
        so.setUseMusclePhysiology(True)
        so.setConvergenceCriterion(convergence)
        so.setMaxIterations(max_iterations)
        so.setStepInterval(step)
        so.setStartTime(float(solve_times[0]))
        so.setEndTime(float(solve_times[-1]))
        # a tool given a model object runs the model's analyses: this one only (a model used
        # for several movements would otherwise run every earlier SO again, and crash)
        model.updAnalysisSet().clearAndDestroy()
        model.addAnalysis(so)
        # the tool was not made from a setup file: it reads the coordinates (and makes the
        # states from their splines) when asked to
        tool.loadStatesFromFile(model.initSystem())
        t0 = time.perf_counter()
        if not tool.run():
            raise RuntimeError("OpenSim AnalyzeTool (StaticOptimization) failed")
        seconds = time.perf_counter() - t0
        la, act = _read_sto(d / "so_StaticOptimization_activation.sto")
        lf, frc = _read_sto(d / "so_StaticOptimization_force.sto")
    col_a = {n: i for i, n in enumerate(la)}
    col_f = {n: i for i, n in enumerate(lf)}
    times = act[:, 0]
    return SOResult(
        times=times,
        activations=act[:, [col_a[n] for n in mm.names]],
        forces=frc[:, [col_f[n] for n in mm.names]],
        reserves=frc[:, [col_f[f"reserve_{j}"] for j in JOINT_NAMES]],
        seconds=seconds,
    )


def model_digest(mm: MuscleModel) -> str:
    """SHA-256 of the muscle model file's bytes, its side, body size and scaling: a cached
    reference made from another model is stale (and says so)."""
    h = hashlib.sha256(Path(mm.path).read_bytes())
    h.update(json.dumps([mm.side, mm.body_size, mm.scaling], sort_keys=True).encode())
    return h.hexdigest()


# -- the reference: OpenSim's SO of the library's movements, and ours on the same frames ------
def solve_times(duration: float, rate_hz: float = RATE_HZ) -> np.ndarray:
    """The frames SO solves: every 1/rate_hz s, EDGE_S away from the movement's ends."""
    n = math.floor((duration - 2 * EDGE_S) * rate_hz + 1e-9) + 1
    return EDGE_S + np.arange(n) / rate_hz


def opensim_movement(model, mm: MuscleModel, movement, rate_hz: float = RATE_HZ) -> SOResult:
    """OpenSim's SO of one library movement (coordinates at COORDINATES_RATE_HZ)."""
    t = movement.sample_times(COORDINATES_RATE_HZ)
    q = movement.evaluate(t)[0]
    return run_static_optimization(model, mm, t, q, solve_times(movement.duration, rate_hz))


def our_movement(arm, mm: MuscleModel, movement, times: np.ndarray, optimizer=None):
    """Our SO at `times` of a movement: torques by Pinocchio from the movement's exact q, q̇, q̈
    (OpenSim computes its own from the coordinates file), then the per-sample QP in time
    order, warm-started as in the node. Returns (MuscleSeries, torques (N, 20))."""
    from ..muscles import StaticOptimizer

    q, qd, qdd = movement.evaluate(times)
    tau = arm.inverse_dynamics_batch(q, qd, qdd)
    so = optimizer or StaticOptimizer(mm, reserve_optimal_torque=RESERVE_OPTIMAL_TORQUE)
    so.reset()
    return so.solve_many(q, qd, tau), tau
