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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import ca_model

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


class _Group:
    """Joints that share a noise level: one covariance recursion."""

    __slots__ = ("M", "P", "dt", "idx", "k", "key", "r", "rv", "seated_at", "settling", "still")

    def __init__(self, key: tuple[int, int], r: float, rv: float, idx: np.ndarray):
        self.key, self.r, self.rv, self.idx = key, r, rv, idx
        self.P: tuple | None = None
        self.M: tuple = (0.0,) * 6
        self.k: tuple = ()
        self.dt = -1.0
        self.still = False
        self.settling = False  # seated diffuse by a restart, not yet back at steady state
        self.seated_at = 0.0  # P is the steady state at this nominal period (0: it is not)


class NoiseGroups:
    """Mixin of KalmanCA: the groups, their recursions, the per-joint gains; see above."""

    @property
    def groups_version(self) -> int:
        """Changes whenever the noise groups (levels, members, velocity mode) change, and at a
        restart (the groups are seated diffuse: their gains move until they settle)."""
        return self._groups_version

    def noise_groups(self) -> list[NoiseGroup]:
        """The groups of joints sharing a noise level and a gain, as the last step used them
        (for torque uncertainty: issue 19's state_source reads these, nothing private)."""
        out = []
        for g in self._groups:
            if g.P is None or not g.k:
                continue
            m = len(g.k) // 3
            out.append(NoiseGroup(g.idx.copy(), g.r, g.rv if m == 2 else None,
                                  np.array(g.k).reshape(3, m), ca_model.to_matrix(g.M), g.dt))
        return out

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
        old = {g.key: g for g in self._groups}
        keys: dict[tuple[int, int], list[int]] = {}
        for j in range(self.n):
            keys.setdefault((int(self._bins[0, j]), int(self._bins[1, j])), []).append(j)
        groups = []
        for i, (key, idx) in enumerate(sorted(keys.items())):
            r = self._floor * math.exp(key[0] * BIN) if self._fixed_r is None else self._fixed_r
            rv = (self._floor * math.exp(key[1] * BIN) if self._fixed_rv is None else self._fixed_rv)
            g = old.get(key) if vel == self._vel else None
            if g is None:
                g = _Group(key, r, rv, np.array(idx, np.intp))
            else:
                g.idx = np.array(idx, np.intp)
            self._gidx[g.idx] = i
            groups.append(g)
        self._groups = groups
        self._groups_version += 1
        self._vel = vel
        self._Kg = np.zeros((6, len(groups)))
        self._Sg = np.zeros(len(groups))
        for g in groups:
            g.still = False
            if g.P is None:  # seat it at its steady state (cached per period and noise bin)
                period = self.noise_estimator.period_s or dt
                g.P = ca_model.steady_posterior(period, g.r, g.rv if vel else None, self.psd)
                g.seated_at = period
        if self._smoother is not None:
            self._smooth_dt = 0.0  # new gains at the next step

    def _covariance_step(self, dt: float, vel: bool) -> None:
        """Each group's recursion at dt; the per-joint gains and innovation stds.

        A group seated at the steady state of the nominal period (new, or settled after a
        restart) keeps that covariance: its gain is one step's from it, computed again only
        when the step leaves JITTER of the period (a dropped sample, a gap) and then once
        more when it is back. On a jittered stream (a sensor's clock, the publisher's wall
        clock: a new dt every sample) the recursion ran on every sample otherwise: 32 of 91 us
        of update() at 1 kHz with velocities, paced like the node (/tmp A/B, load 2.5)."""
        changed = False
        period = self.noise_estimator.period_s or dt
        if self._restarted:  # seated diffuse: the recursion runs until it is steady again
            self._restarted = False
            for g in self._groups:
                g.P = ca_model.restart_posterior(g.r, g.rv if vel else None, self.psd,
                                                 RESTART_HORIZON_S)
                g.still = False
                g.settling = True
                g.seated_at = 0.0
            self._groups_version += 1
        near = abs(dt - period) <= JITTER * period
        kg, sg = self._Kg, self._Sg
        for i, g in enumerate(self._groups):
            if g.still and dt == g.dt:
                continue
            seated = g.seated_at and abs(g.seated_at - period) <= JITTER * period
            if seated and g.still and near:
                continue  # its gain is a step's from the steady state within JITTER: kept
            m = ca_model.prior(g.P, dt, self.psd)
            r2 = g.r * g.r
            k, p = ca_model.measurement_update(m, r2, g.rv * g.rv if vel else None)
            old = g.P
            if seated:  # the steady state stays: this step's gain is all that moves
                p = old
                g.still = near
            else:
                g.seated_at = 0.0
                if g.settling:  # (q̇, q̈) back within SETTLED of the steady state: seated there
                    ss = ca_model.steady_posterior(period, g.r, g.rv if vel else None, self.psd)
                    if all(abs(p[i] - ss[i]) <= SETTLED * abs(ss[i]) for i in (3, 4, 5)):
                        p, g.settling, g.seated_at = ss, False, period
                g.still = dt == g.dt and all(abs(a - b) <= 1e-12 * abs(a) + 1e-300 for a, b in zip(p, old))
            g.P, g.M, g.k, g.dt = p, m, k, dt
            if vel:
                kg[0, i], kg[3, i], kg[1, i], kg[4, i], kg[2, i], kg[5, i] = k
            else:
                kg[0, i], kg[1, i], kg[2, i] = k
            sg[i] = m[0]
            changed = True
        if changed:
            gi = self._gidx
            np.take(kg[:3], gi, axis=1, out=self._Kp)
            if vel:
                np.take(kg[3:], gi, axis=1, out=self._Kv)
            self._innovation_std()

    def _innovation_std(self) -> None:
        """Per joint innovation std with the noise as measured: the group's prior variance
        plus the gate's r^2."""
        sig = self._sig
        np.take(self._Sg, self._gidx, out=sig)
        np.multiply(self._r_gate, self._r_gate, out=self._tmp)
        sig += self._tmp
        np.sqrt(sig, out=sig)
