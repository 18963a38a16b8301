"""Static optimisation per sample: the muscle activations behind one joint-torque vector.

    minimise   Σ_i a_i²  +  Σ_j (r_j / r_opt_j)²
    subject to Σ_i R_ji · F_i(a_i) + r_j = τ_j − Σ_i R_ji · P_i   (every DOF j)
               0 ≤ a_i ≤ 1

F_i(a) = a · F0 · f_L(l̃) · f_V(ṽ) · cos(α) (rigid tendon, DeGroote-Fregly 2016 curves,
curves.py), P_i the passive fibre force (0 unless passive=True: OpenSim's SO leaves it out
too). r_j is one reserve torque per DOF with optimal torque r_opt (1 N·m by default), weighted
as OpenSim's SO weighs a reserve CoordinateActuator (its activation r/r_opt, squared), so a
torque the muscles cannot carry goes to the reserve, visible in `reserves`, never hidden.

Why daqp (MIT): a dual active-set QP solver made for small dense problems solved again and
again; its workspace (`daqp.Model`) keeps the last sample's active set, so a sample close to
the previous one is solved in a few iterations (warm start). The problem is always feasible
(free reserves) and strictly convex (positive diagonal cost), so the optimum is unique.

The reserves are daqp's own soft constraints, not variables: the QP's unknowns are the n
activations, the torque balance is n_j equality rows marked soft, and daqp prices a row's
violation s as s² / (2ρ) (its `soft_weights`, ρ per row), so ρ_j = r_opt_j² / 2 is the cost
(r_j / r_opt_j)² above; the reserve is then what the activations leave, r = τ − R·F(a), and
the balance holds to rounding. The same optimum as with 20 reserve variables (activations
within 3e-15 over 200 samples with r_opt from 0.3 to 3 N·m and reserves in use), at a
constraint matrix of n_j × n instead of n_j × (n + n_j): daqp's update + solve ~8 µs (17 %)
less a sample (paired, same process, 1 500 samples).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import daqp
import numpy as np

from . import muscle_step
from .curves import UnitForces
from .model import MuscleModel, MuscleModelError, _posture
from .surrogate import clip_ufunc

_EQ_SOFT = 1 + 4 + 8  # daqp sense: ACTIVE | IMMUTABLE (an equality) | SOFT
# daqp's bound tolerance (default 1e-6 in activation): an activation may end that far
# outside [0, 1] before the clip, a change of up to 1e-6 · F0 · r ≈ 1e-5 N·m in what it
# carries; 1e-9 keeps the activations as close to the optimum (the reserves are computed from
# the clipped activations, so the balance itself holds to rounding).
_SETTINGS = {"primal_tol": 1e-9}


@dataclass(frozen=True)
class MuscleSolution:
    """One sample's split of the torques into muscles (vectors in model.names order)."""

    activations: np.ndarray  # (n,) 0..1
    forces: np.ndarray  # (n,) N, tendon force (active + passive if included)
    reserves: np.ndarray  # (20,) N·m, joint_names order
    infeasible: bool  # solver failed, or a muscle at a = 1: the reserve carries the rest
    solve_time: float  # s, the QP alone
    residual: float  # max |R·F + r − τ| N·m
    iterations: int
    exitflag: int


@dataclass(frozen=True)
class MuscleSeries:
    """A recording's solutions: arrays with one row per sample."""

    names: tuple[str, ...]
    joint_names: tuple[str, ...]
    activations: np.ndarray  # (N, n)
    forces: np.ndarray  # (N, n)
    reserves: np.ndarray  # (N, 20)
    infeasible: np.ndarray  # (N,) bool
    solve_time: np.ndarray  # (N,) s
    residual: np.ndarray  # (N,) N·m


class StaticOptimizer:
    """Warm-started static optimisation of one muscle model (see the module docstring)."""

    def __init__(self, model: MuscleModel, *, reserve_optimal_torque: float | np.ndarray = 1.0,
                 passive: bool = False, velocity: bool = True, saturation_tol: float = 1e-6):
        nj = len(model.joint_names)
        r_opt = np.broadcast_to(np.asarray(reserve_optimal_torque, float), (nj,)).copy()
        if np.any(~np.isfinite(r_opt)) or np.any(r_opt <= 0):
            raise MuscleModelError(f"reserve_optimal_torque must be > 0 N·m, got {reserve_optimal_torque!r}")
        self.model = model
        self.reserve_optimal_torque = r_opt
        self.passive = bool(passive)
        self.velocity = bool(velocity)
        self.saturation_tol = float(saturation_tol)
        n = model.n
        self._n, self._nj = n, nj
        self._unit = UnitForces(model.params(), use_velocity=self.velocity, passive=self.passive)
        self._H = np.diag(np.full(n, 2.0))  # ½ aᵀHa = Σ a²
        self._f = np.zeros(n)
        self._A = np.zeros((nj, n))  # A[j, i] = R[i, j] · unit[i], rewritten each sample
        self._bu = np.concatenate([np.ones(n), np.zeros(nj)])  # 0 <= a <= 1, then A·a = τ'
        self._bl = np.concatenate([np.zeros(n), np.zeros(nj)])
        self._sense = np.concatenate([np.zeros(n), np.full(nj, _EQ_SOFT)]).astype(np.int32)
        # each row's soft weight: violation s costs s² / (2ρ) = (s / r_opt)² (module docstring);
        # the bounds' entries are not soft (sense 0): daqp ignores them
        self._rho = np.concatenate([np.ones(n), r_opt ** 2 / 2.0])
        self._qp = None
        self._rhs_u, self._rhs_l = self._bu[n:], self._bl[n:]
        self._res = np.empty(nj)  # the residual's scratch
        self._muscles = np.empty(nj)  # solve_into's R·F(a), aligned for BLAS as A @ a makes it
        self._saturated = 1.0 - self.saturation_tol
        self._step = None  # (geometry outputs, compiled step or None): solve_sample_into's

    def reset(self) -> None:
        """Forget the warm start (a new recording, a changed model)."""
        self._qp = None

    def _problem(self, R: np.ndarray, L: np.ndarray, V: np.ndarray, tau: np.ndarray):
        unit, pas = self._unit(L, V)
        np.multiply(R.T, unit, out=self._A)  # A[j, i] = R[i, j] · unit[i]
        rhs = tau - R.T @ pas if self.passive else tau
        self._rhs_u[:] = rhs
        self._rhs_l[:] = rhs
        return unit, pas

    def _cold(self):
        self._qp = daqp.Model()
        self._qp.setup(self._H, self._f, self._A, self._bu, self._bl, self._sense)
        self._qp.settings = _SETTINGS
        self._qp.soft_weights(rho_l=self._rho, rho_u=self._rho)

    def _run(self):
        t0 = time.perf_counter()
        if self._qp is None:
            self._cold()
        else:
            self._qp.update(A=self._A, bupper=self._bu, blower=self._bl)
        x, _, flag, info = self._qp.solve()
        if flag < 1:  # a warm start gone wrong: solve once more from scratch
            self._cold()
            x, _, flag, info = self._qp.solve()
        # x is daqp's own copy, new each solve (Model.solve returns a copy of its buffer):
        # _finish may write into it
        return x, int(flag), int(info.get("iterations", 0)), time.perf_counter() - t0

    def _finish(self, x, flag, iters, dt, R, unit, pas, tau) -> MuscleSolution:
        n = self._n
        if flag < 1:
            a = np.full(n, np.nan)
            r = np.full(self._nj, np.nan)
            return MuscleSolution(a, a.copy(), r, True, dt, float("nan"), iters, flag)
        a = x  # this solve's own array (n,): clipped in place
        clip_ufunc(a, 0.0, 1.0, out=a)  # np.clip's ufunc, not its ~5 µs wrapper
        muscles = self._A @ a  # R·(a·unit): what the activations carry, N·m
        r = np.subtract(self._rhs_u, muscles)  # the reserves: what they leave of τ (− R·P)
        forces = a * unit
        res = self._res  # R·F + r − τ (rounding: r is defined by it)
        if self.passive:
            forces += pas
            np.matmul(R.T, forces, out=res)
            res += r
        else:  # A = R·unit (_problem): A·a is R·F
            np.add(muscles, r, out=res)
        res -= tau
        d = res.tolist()  # 20 numbers: Python's max beats np.abs and a reduction
        residual = max(max(d), -min(d))
        infeasible = bool(a.max() >= self._saturated)
        return MuscleSolution(a, forces, r, infeasible, dt, residual, iters, flag)

    def solve(self, q, qd, tau) -> MuscleSolution:
        """One sample: q (rad), qd (rad/s), tau (N·m), each (20,) in joint_names order."""
        tau = _posture(tau, "tau")
        if tau.ndim != 1:
            raise MuscleModelError("solve() takes one sample; solve_many() takes (N, 20)")
        R, L, V = self.model.geometry(q, qd)
        unit, pas = self._problem(R, L, V, tau)
        return self._finish(*self._run(), R, unit, pas, tau)

    def solve_geometry(self, R, L, V, tau) -> MuscleSolution:
        """As solve(), with the geometry already evaluated (model.geometry)."""
        unit, pas = self._problem(R, L, V, tau)
        return self._finish(*self._run(), R, unit, pas, tau)

    def solve_into(self, R, L, V, tau, activations, forces, reserves) -> tuple[int, bool, float]:
        """solve_geometry for a node's per-sample path: the activations, forces and reserves
        written into the caller's arrays (its output messages' views), the same numbers to the
        bit; no MuscleSolution and no residual (R·F + r − τ is τ's rounding by construction of
        r; solve_geometry reports it). Returns (exitflag, infeasible, QP time s)."""
        unit, pas = self._problem(R, L, V, tau)
        x, flag, _, dt = self._run()
        return self._write(x, flag, dt, unit, pas, activations, forces, reserves)

    def _write(self, x, flag, dt, unit, pas, activations, forces,
               reserves) -> tuple[int, bool, float]:
        """solve_into's second half: daqp's answer x into the caller's arrays."""
        if flag < 1:
            activations.fill(np.nan)
            forces.fill(np.nan)
            reserves.fill(np.nan)
            return flag, True, dt
        clip_ufunc(x, 0.0, 1.0, out=x)
        # A @ x from daqp's own (aligned) array, the product _finish makes, whatever buffer
        # the caller's views live in (numpy hands only aligned arrays to BLAS)
        np.matmul(self._A, x, out=self._muscles)
        np.subtract(self._rhs_u, self._muscles, out=reserves)
        np.multiply(x, unit, out=forces)
        if self.passive:
            forces += pas
        np.copyto(activations, x)
        return flag, bool(x.max() >= self._saturated), dt

    def solve_sample_into(self, q, qd, tau, geo, activations, forces,
                          reserves) -> tuple[int, bool, float]:
        """model.geometry(q, qd, geo) then solve_into: a node's whole per-sample path (geo =
        model.geometry_outputs(), R, L and V written there as geometry writes them). Where the
        compiled step is built (muscle_step.py) the arithmetic before and after daqp's solve
        is one call each; else numpy's way. The same numbers to rounding; returns solve_into's
        (exitflag, infeasible, QP time s)."""
        step = self._step[1] if self._step is not None and self._step[0] is geo else self._bind(geo)
        if step is not None:
            try:
                step.problem(q, qd, tau)  # checks its arguments before it writes anything
            except (ValueError, BufferError):  # not contiguous float64 (20,) each
                step = None
        if step is None:  # numpy's way
            R, L, V = self.model.geometry(q, qd, geo)
            return self.solve_into(R, L, V, tau, activations, forces, reserves)
        x, flag, _, dt = self._run()
        if flag >= 1:
            try:
                return flag, step.finish(x, activations, forces, reserves) >= self._saturated, dt
            except (ValueError, BufferError):  # outputs it cannot take: numpy's way
                pass
        return self._write(x, flag, dt, self._unit._unit, self._unit._zeros, activations,
                           forces, reserves)

    def _bind(self, geo):
        """The compiled step on geo's arrays (kept for the next sample), or None."""
        buf = self.model.surrogate.output_buffer(geo[0], geo[1])
        step = None
        if buf is not None and geo[2].flags.c_contiguous:
            step = muscle_step.bind(self.model.surrogate, self._unit, buf, geo[2], self._A,
                                    self._rhs_u, self._rhs_l)
        self._step = (geo, step)
        return step

    def solve_many(self, q, qd, tau) -> MuscleSeries:
        """A recording (N, 20) each, in time order (each sample warm-starts the next)."""
        q, qd, tau = (_posture(x, w) for x, w in ((q, "q"), (qd, "qd"), (tau, "tau")))
        q, qd, tau = np.atleast_2d(q), np.atleast_2d(qd), np.atleast_2d(tau)
        if not (q.shape == qd.shape == tau.shape):
            raise MuscleModelError(f"q, qd, tau must have one shape, got {q.shape}, {qd.shape}, {tau.shape}")
        N, n = len(q), self._n
        Rs = self.model.moment_arms(q)
        Ls = self.model.lengths(q)
        Vs = -np.einsum("kij,kj->ki", Rs, qd)
        out = {k: np.empty((N, n)) for k in ("a", "f")}
        res = np.empty((N, self._nj))
        inf = np.zeros(N, bool)
        st = np.empty(N)
        resid = np.empty(N)
        for k in range(N):
            s = self.solve_geometry(Rs[k], Ls[k], Vs[k], tau[k])
            out["a"][k], out["f"][k], res[k] = s.activations, s.forces, s.reserves
            inf[k], st[k], resid[k] = s.infeasible, s.solve_time, s.residual
        return MuscleSeries(self.model.names, tuple(self.model.joint_names), out["a"], out["f"],
                            res, inf, st, resid)
