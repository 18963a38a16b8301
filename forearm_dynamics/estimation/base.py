"""The interface every state estimator implements, and how it describes its settings."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass(frozen=True)
class SettingSpec:
    """One estimator setting: what the node declares as ROS parameter `estimator.<name>`."""

    name: str
    default: float
    unit: str  # e.g. "Hz", "s", "rad"
    description: str
    lo: float = 0.0
    hi: float = 1e6


class StateEstimator(ABC):
    """q, q̇, q̈ (model order, (n,) float64) from stamped samples, causally.

    Contract:
    - `update(t_ns, q, qd)` takes the sample at t_ns (qd None: positions only); afterwards
      `self.q`, `self.qd`, `self.qdd` hold the estimate at t_ns. Returns `warm`: False while
      the history is too short for a real estimate (the caller counts such outputs).
      The caller guarantees t_ns increases; it calls `reset()` on a stamp jump. A sample
      with NaN/inf or a stamp not after the last one raises ValueError and leaves the
      state untouched (`check()`), so a rejected sample never enters the filter.
    - `predict(t_ns)` overwrites q, qd, qdd with the extrapolation to t_ns ≥ stamp_ns
      (for a fixed output rate); it never changes the filter state.
    - `stamp_ns`: the stamp the estimate in q, qd, qdd belongs to (the last update's, or
      an older sample's with a delay; None: nothing to output yet). Every update()
      starts with `check()` (which also counts the sample for predict()).
    - No allocation per sample: q, qd, qdd are preallocated and filled in place.
    - `describe(dt)` states the method, its settings, the lag of each estimate (s) at
      sample period dt and the noise level it believes in (rad, None if it has none).
    """

    name: ClassVar[str]
    settings: ClassVar[tuple[SettingSpec, ...]] = ()

    def __init__(self, n: int, settings: Mapping[str, float]):
        known = {s.name: s for s in self.settings}
        unknown = sorted(set(settings) - set(known))
        if unknown:
            raise ValueError(f"estimator {self.name!r} has no setting {', '.join(unknown)}")
        values = {s.name: float(settings.get(s.name, s.default)) for s in self.settings}
        for k, x in values.items():
            s = known[k]
            if not math.isfinite(x) or not s.lo <= x <= s.hi:
                raise ValueError(f"estimator setting {k} = {x!r} is outside [{s.lo}, {s.hi}] {s.unit}")
        self.values = values
        self.n = n
        self.q = np.zeros(n)
        self.qd = np.zeros(n)
        self.qdd = np.zeros(n)
        self._t_ns: int | None = None  # stamp of the last update
        #: the stamp q, qd, qdd are the estimate of: the last update's for a causal
        #: estimator, an older sample's with a delay (kalman delay_s), None = nothing to output
        self.stamp_ns: int | None = None
        self._seq = 0  # accepted samples (check() passed): predict() knows a new update came
        self._snap_seq = -1
        self._snapshot = np.zeros((4, n))  # q, qd, qdd of the last update, scratch

    def check(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> None:
        """ValueError (state unchanged) for non-finite input or a stamp not after the last.

        One reduction on every sample: q.qd (or the sum of q) is NaN or inf if any element
        is; only then are the elements looked at (a finite overflow is not refused).
        """
        if self._t_ns is not None and t_ns <= self._t_ns:
            raise ValueError(f"stamp {t_ns} ns is not after the previous sample ({self._t_ns} ns)")
        if not math.isfinite(q.sum() if qd is None else q.dot(qd)) and not (
                np.isfinite(q).all() and (qd is None or np.isfinite(qd).all())):
            raise ValueError("non-finite position or velocity: sample refused")
        self._seq += 1
        self.stamp_ns = t_ns

    def run(self, t_ns: np.ndarray, q: np.ndarray, qd: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Offline: feed (N,) stamps and (N, n) samples in order; (q, qd, qdd, warm) per sample.

        The same update() calls a node makes (no batch shortcut), so results are the
        node's; one estimator may carry several streams with the same stamps as columns.
        With a delay, each output goes to the row of the sample it estimates (stamp_ns) and
        the last ones are drained at the end; a row never output keeps the raw sample.
        """
        n_s = len(t_ns)
        out = np.zeros((3, n_s, self.n))
        warm = np.zeros(n_s, bool)
        delayed = getattr(self, "delay_s", 0.0) > 0.0
        if not delayed:
            for k in range(n_s):
                warm[k] = self.update(int(t_ns[k]), q[k], None if qd is None else qd[k])
                out[0, k], out[1, k], out[2, k] = self.q, self.qd, self.qdd
            return out[0], out[1], out[2], warm
        out[0] = q
        if qd is not None:
            out[1] = qd
        rows = {int(t): k for k, t in enumerate(t_ns)}
        for k in range(n_s):
            w = self.update(int(t_ns[k]), q[k], None if qd is None else qd[k])
            if self.stamp_ns is not None:
                i = rows[self.stamp_ns]
                warm[i] = w
                out[0, i], out[1, i], out[2, i] = self.q, self.qd, self.qdd
        for stamp, x in self.drain():
            i = rows[stamp]
            warm[i] = True
            out[:, i] = x
        return out[0], out[1], out[2], warm

    def drain(self) -> list[tuple[int, np.ndarray]]:
        """With a delay: the estimates not yet output, [(stamp, (3, n))]; causal: none."""
        return []

    @abstractmethod
    def reset(self) -> None:
        """Forget the history (after a stamp jump): the next samples warm up again."""

    @abstractmethod
    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> bool:
        """Take the sample at t_ns; fill self.q/qd/qdd; return warm."""

    def learn(self) -> None:
        """The last sample's work that its estimate does not wait for (the Kalman's noise
        statistics): a node calls this after publishing; otherwise the next update() (or a
        reader of what it changes) does it first, so results never depend on the call."""

    def predict(self, t_ns: int) -> None:
        """Constant-acceleration extrapolation from the last update's estimate.

        Repeated calls (a 1 kHz output timer between 100 Hz samples) all extrapolate from
        that estimate, kept aside at the first call after each update; no allocation.
        """
        if self.stamp_ns is None:
            return
        snap = self._snapshot
        if self._snap_seq != self._seq:
            np.copyto(snap[0], self.q)
            np.copyto(snap[1], self.qd)
            np.copyto(snap[2], self.qdd)
            self._snap_seq = self._seq
        dt = max((t_ns - self.stamp_ns) * 1e-9, 0.0)
        tmp = snap[3]
        np.multiply(snap[2], 0.5 * dt * dt, out=self.q)
        np.multiply(snap[1], dt, out=tmp)
        self.q += tmp
        self.q += snap[0]
        np.multiply(snap[2], dt, out=self.qd)
        self.qd += snap[1]
        np.copyto(self.qdd, snap[2])

    @abstractmethod
    def lag(self, dt: float, velocity_given: bool) -> dict[str, float]:
        """Low-frequency delay (s) of the q, qd, qdd estimates at sample period dt."""

    def noise(self) -> float | None:
        """The position noise (rad, standard deviation) the estimator believes in."""
        return None

    def describe(self, dt: float, velocity_given: bool = False) -> dict:
        return {
            "method": self.name,
            "settings": dict(self.values),
            "lag_s": self.lag(dt, velocity_given),
            "at_sample_period_s": dt,
            "velocity_given": velocity_given,
            "noise_rad": self.noise(),
        }
