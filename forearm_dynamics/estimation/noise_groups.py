"""The Kalman filter's noise groups: joints that share a noise level share one covariance.

Why apart from the filter (kalman.py): the grouping is the filter's cost model, not its
estimate. Joints are binned by noise (bins a factor sqrt(2) apart, with hysteresis), each
group carries one covariance recursion in plain floats (ca_model), converged groups skip
it at a repeating dt, and a new group is seated at its steady state at the stream's nominal
period (ca_model.steady_posterior: one Riccati solve per period and noise bin, cached), so it
is converged ("still") from its first steps. The seat scaled from the group a joint came from
(an approximation, kept while the solves were not cached) left groups converging for
seconds: with velocities at 1 kHz, 5e-6 relative per step after 1.6 s, so on the library's
movements the recursions never stopped (19 753 of them in 9 000 samples; update() p50 50 ->
43 us, test_estimation_parts). A restart seats every group diffuse on (q̇, q̈)
(ca_model.restart_posterior; why: kalman.py), and a group "settling" from it is seated at
its exact steady state as soon as its (q̇, q̈) covariance is within SETTLED of it: q's own
slow mode (velocities given, its variance falls from r^2 as the velocities integrate, 2 000-
70 000 steps at 1 kHz to 1e-3) is not what the restart got wrong, and would keep the
recursion running for seconds. `NoiseGroups` is a mixin of
KalmanCA: it reads the filter's noise beliefs (_r, _rv, _r_gate, _floor,
_fixed_r, _fixed_rv) and writes the per-joint gains (_Kp, _Kv) and innovation stds (_sig).

The groups' numbers live in one array, a row per group (`Col`), so that the step of seated
groups, the one a node runs at every sample its clock moves by more than JITTER, is one
compiled call with the per-joint gains after it (kalman_step.bind_gains): in Python it was
a loop of ~20 lines per group and 5 numpy calls, 8 us p50 of a 20-joint node's update()
(benchmarks/estimator_probe). Python's loop (_python_covariance_step) is the reference and
does the rest (a restart, a group settling, a new rate); test_group_step.py compares them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import ca_model, kalman_step

BIN = math.log(math.sqrt(2.0))  # noise bins a factor sqrt(2) apart
HYSTERESIS = 0.6  # a joint leaves its bin when 0.6 bin away from its centre
RESTART_HORIZON_S = 1.0  # a restart's q̇, q̈ spread: what a white jerk gives them in 1 s
SETTLED = 1e-3  # a restarted group this close to its steady posterior is seated there
#: a seated group keeps its gain while the step is within this fraction of the nominal period
JITTER = 0.1


@dataclass(frozen=True)
class NoiseGroup:
    """Joints `idx` filtered with one noise level (r, r_v; r_v None without velocities):
    the gain (3, m) and prior covariance M (3, 3) of the last step, at period dt."""

    idx: np.ndarray
    r: float
    r_v: float | None
    gain: np.ndarray
    prior: np.ndarray
    dt: float


class Col:
    """A group's row in NoiseGroups._gstate (plain ints; the extension checks them by name):
    posterior P and prior M (ca_model.Cov layout), gain K (rows q, q̇, q̈ of the position gain,
    then of the velocity gain), the last step's dt (-1: none yet), STILL (its gain is kept
    at a repeating dt), SEATED (P is the steady state at this nominal period; 0: it is not),
    the noise R, RV, and SETTLING (seated diffuse by a restart, not yet back at steady state)."""

    P = 0
    M = 6
    K = 12
    DT = 18
    STILL = 19
    SEATED = 20
    R = 21
    RV = 22
    SETTLING = 23
    WIDTH = 24

    @classmethod
    def layout(cls) -> dict[str, int]:
        return {k: v for k, v in vars(cls).items() if k.isupper()}


@dataclass(frozen=True)
class _Group:
    """Joints that share a noise level (a bin pair `key`): one covariance recursion, whose
    numbers are the group's row of NoiseGroups._gstate."""

    key: tuple[int, int]
    r: float
    rv: float
    idx: np.ndarray


def _new_row(r: float, rv: float) -> np.ndarray:
    row = np.zeros(Col.WIDTH)
    row[Col.DT] = -1.0
    row[Col.R], row[Col.RV] = r, rv
    return row


class NoiseGroups:
    """Mixin of KalmanCA: the groups, their recursions, the per-joint gains; see above."""

    _gfast = None  # kalman_step.Gains on _gstate (None: Python's loop)
    _gcompiled = True  # False: Python's loop always (python_gains())

    @property
    def groups_version(self) -> int:
        """Changes whenever the noise groups (levels, members, velocity mode) change, and at a
        restart (the groups are seated diffuse: their gains move until they settle)."""
        return self._groups_version

    def noise_groups(self) -> list[NoiseGroup]:
        """The groups of joints sharing a noise level and a gain, as the last step used them
        (for torque uncertainty: issue 19's state_source reads these, nothing private)."""
        out = []
        m = 2 if self._vel else 1
        for i, g in enumerate(self._groups):
            gain = self._group_gain(i, m)
            if gain is None:
                continue
            row = self._gstate[i]
            out.append(NoiseGroup(g.idx.copy(), g.r, g.rv if m == 2 else None, gain,
                                  ca_model.to_matrix(row[Col.M:Col.M + 6].tolist()),
                                  float(row[Col.DT])))
        return out

    def _group_gain(self, i: int, m: int) -> np.ndarray | None:
        """Group i's gain (3, m) of its last step; None before one, or if it was for the other
        measurement set (m: 1 positions, 2 with velocities)."""
        row = self._gstate[i]
        if row[Col.DT] < 0.0 or m != (2 if self._vel else 1):
            return None
        k = row[Col.K:Col.K + 3 * m]
        return k.reshape(m, 3).T.copy()

    def _group_covariance(self, i: int) -> np.ndarray:
        return ca_model.to_matrix(self._gstate[i, Col.P:Col.P + 6].tolist())

    def python_gains(self):
        """Step the groups in Python from now on, after a regroup too (the compiled step's
        reference: test_group_step.py; the tests that count ca_model.prior calls); returns
        self."""
        self._gcompiled = False
        self._gfast = None
        return self

    def _bind_gains(self) -> None:
        """The seated groups' step as one compiled call on this filter's arrays (None: Python's
        loop): bound again whenever the groups (so _gstate) change."""
        if not self._gcompiled:
            return
        self._gfast = kalman_step.bind_gains(self._gstate, Col.layout(), self._gidx,
                                             self._r_gate, self._Kp, self._Kv, self._sig)

    def _regroup(self, vel: bool, dt: float) -> None:
        """Bin each joint's noise (hysteresis) and rebuild the groups if the bins changed."""
        changed = vel != self._vel
        for row, r in ((0, self._r), (1, self._rv)):
            if row == 1 and not vel:
                if (self._bins[1] != 0).any():
                    self._bins[1].fill(0)
                    changed = True
                continue
            pos = np.log(np.maximum(r, 1e-300) / self._floor) / BIN
            cur = self._bins[row]
            move = np.abs(pos - cur) > 0.5 + (HYSTERESIS - 0.5) * (cur > -10**5)
            if move.any():
                cur[move] = np.rint(pos[move]).astype(int)
                changed = True
        if not changed and self._groups:
            return
        old = {g.key: i for i, g in enumerate(self._groups)} if vel == self._vel else {}
        keys: dict[tuple[int, int], list[int]] = {}
        for j in range(self.n):
            keys.setdefault((int(self._bins[0, j]), int(self._bins[1, j])), []).append(j)
        groups = []
        state = np.zeros((len(keys), Col.WIDTH))
        period = self.noise_estimator.period_s or dt
        for i, (key, idx) in enumerate(sorted(keys.items())):
            r = self._floor * math.exp(key[0] * BIN) if self._fixed_r is None else self._fixed_r
            rv = (self._floor * math.exp(key[1] * BIN) if self._fixed_rv is None else self._fixed_rv)
            g = _Group(key, r, rv, np.array(idx, np.intp))
            if key in old:  # the same recursion goes on
                state[i] = self._gstate[old[key]]
            else:  # seated at its steady state (cached per period and noise bin)
                state[i] = _new_row(r, rv)
                state[i, Col.P:Col.P + 6] = ca_model.steady_posterior(period, r, rv if vel else None,
                                                                      self.psd)
                state[i, Col.SEATED] = period
            state[i, Col.STILL] = 0.0
            self._gidx[g.idx] = i
            groups.append(g)
        self._groups = groups
        self._gstate = state
        self._groups_version += 1
        self._vel = vel
        self._bind_gains()
        if self._smoother is not None:
            self._smooth_dt = 0.0  # new gains at the next step

    def _covariance_step(self, dt: float, vel: bool) -> None:
        """Each group's recursion at dt; the per-joint gains and innovation stds.

        A group seated at the steady state of the nominal period (new, or settled after a
        restart) keeps that covariance: its gain is one step's from it, computed again only
        when the step leaves JITTER of the period (a dropped sample, a gap) and then once
        more when it is back. On a jittered stream (a sensor's clock, the publisher's wall
        clock: a new dt every sample) the recursion ran on every sample otherwise: 32 of 91 us
        of update() at 1 kHz with velocities, paced like the node (/tmp A/B, load 2.5).
        Seated groups: one compiled call (module docstring); the rest: Python's loop."""
        period = self.noise_estimator.period_s or dt
        if self._restarted:  # seated diffuse: the recursion runs until it is steady again
            self._restarted = False
            state = self._gstate
            for i, g in enumerate(self._groups):
                state[i, Col.P:Col.P + 6] = ca_model.restart_posterior(
                    g.r, g.rv if vel else None, self.psd, RESTART_HORIZON_S)
                state[i, Col.STILL] = state[i, Col.SEATED] = 0.0
                state[i, Col.SETTLING] = 1.0
            self._groups_version += 1
        if self._gfast is not None and self._gfast.step(dt, period, self.psd, vel, JITTER) >= 0:
            return
        self._python_covariance_step(dt, vel, period)

    def _python_covariance_step(self, dt: float, vel: bool, period: float) -> None:
        """_covariance_step's loop in Python: the reference, and the step of groups that are
        not seated (a restart settling, a new rate)."""
        changed = False
        near = abs(dt - period) <= JITTER * period
        state = self._gstate
        for i in range(len(self._groups)):
            row = state[i].tolist()
            still, gdt = row[Col.STILL] != 0.0, row[Col.DT]
            if still and dt == gdt:
                continue
            seated_at = row[Col.SEATED]
            seated = seated_at != 0.0 and abs(seated_at - period) <= JITTER * period
            if seated and still and near:
                continue  # its gain is a step's from the steady state within JITTER: kept
            old = tuple(row[Col.P:Col.P + 6])
            m = ca_model.prior(old, dt, self.psd)
            r, rv = row[Col.R], row[Col.RV]  # the noise the compiled step reads too
            k, p = ca_model.measurement_update(m, r * r, rv * rv if vel else None)
            if seated:  # the steady state stays: this step's gain is all that moves
                p = old
                still = near
            else:
                seated_at = 0.0
                if row[Col.SETTLING]:  # (q̇, q̈) back within SETTLED of the steady state: seated
                    ss = ca_model.steady_posterior(period, r, rv if vel else None, self.psd)
                    if all(abs(p[i] - ss[i]) <= SETTLED * abs(ss[i]) for i in (3, 4, 5)):
                        p, seated_at = ss, period
                        state[i, Col.SETTLING] = 0.0
                still = dt == gdt and all(abs(a - b) <= 1e-12 * abs(a) + 1e-300 for a, b in zip(p, old))
            state[i, Col.P:Col.P + 6] = p
            state[i, Col.M:Col.M + 6] = m
            if vel:  # k: (k00, k01, k10, k11, k20, k21), row by row
                state[i, Col.K:Col.K + 6] = k[0::2] + k[1::2]
            else:
                state[i, Col.K:Col.K + 3] = k
            state[i, Col.DT] = dt
            state[i, Col.STILL] = still
            state[i, Col.SEATED] = seated_at
            changed = True
        if changed:
            self._joint_gains(vel)

    def _joint_gains(self, vel: bool) -> None:
        """The per-joint gains from their groups', and the innovation stds."""
        gi, state = self._gidx, self._gstate
        np.take(state[:, Col.K:Col.K + 3].T, gi, axis=1, out=self._Kp)
        if vel:
            np.take(state[:, Col.K + 3:Col.K + 6].T, gi, axis=1, out=self._Kv)
        self._innovation_std()

    def _innovation_std(self) -> None:
        """Per joint innovation std with the noise as measured: the group's prior variance
        plus the gate's r^2."""
        sig = self._sig
        np.take(self._gstate[:, Col.M], self._gidx, out=sig)
        np.multiply(self._r_gate, self._r_gate, out=self._tmp)
        sig += self._tmp
        np.sqrt(sig, out=sig)
