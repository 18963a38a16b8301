"""The paper's comparison: each model's filtered torques against the anatomical reference."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dynamics import ArmModel
from ..filtering import lowpass
from ..movements import default_stop_rule, movement_library
from ..reference import ReferenceTorques
from .errors import ErrorSet, movement_errors


@dataclass(frozen=True)
class Trials:
    """Kinematics of the 65 movements sampled once, reused by every model evaluation."""

    rate_hz: float
    movement_ids: tuple[int, ...]
    q: np.ndarray  # (M*N, 20) all movements stacked
    qd: np.ndarray
    qdd: np.ndarray
    n: int  # samples per movement
    stop_rule: str | None = None

    @classmethod
    def sample(cls, rate_hz: float = 1000.0, movement_ids=None, stop_rule: str | None = None) -> Trials:
        lib = movement_library(stop_rule)
        ids = tuple(movement_ids or (m.id for m in lib))
        parts = [lib[i - 1].evaluate(lib[i - 1].sample_times(rate_hz)) for i in ids]
        n = parts[0][0].shape[0]
        q, qd, qdd = (np.concatenate([p[k] for p in parts]) for k in range(3))
        return cls(rate_hz, ids, q, qd, qdd, n, stop_rule)

    def split(self, stacked: np.ndarray) -> np.ndarray:
        return stacked.reshape(len(self.movement_ids), self.n, -1)

    def subset(self, movement_ids) -> Trials:
        rows = [self.movement_ids.index(i) for i in movement_ids]
        pick = lambda x: self.split(x)[rows].reshape(-1, x.shape[1])
        return Trials(self.rate_hz, tuple(movement_ids), pick(self.q), pick(self.qd),
                      pick(self.qdd), self.n, self.stop_rule)


def filtered_torques(model: ArmModel, trials: Trials) -> np.ndarray:
    """(M, N, 20) torques low-pass filtered per movement."""
    tau = trials.split(model.inverse_dynamics(trials.q, trials.qd, trials.qdd))
    return lowpass(tau, trials.rate_hz, axis=1)


def reference_filtered(ref: ReferenceTorques, trials: Trials, body_size: int) -> np.ndarray:
    step = ref.rate_hz / trials.rate_hz
    if abs(step - round(step)) > 1e-9:
        raise ValueError(f"trials at {trials.rate_hz} Hz cannot be taken from {ref.rate_hz} Hz data")
    if trials.stop_rule not in (None, default_stop_rule()):
        raise ValueError("the shipped reference holds the default movements only; compute the "
                         "anatomical torques for other movements with filtered_torques")
    step = round(step)
    raw = np.stack([ref.torques(mid, body_size)[::step] for mid in trials.movement_ids])
    return lowpass(raw, trials.rate_hz, axis=1)


def compare(model: ArmModel, reference: np.ndarray, trials: Trials,
            global_ptp: np.ndarray | None = None) -> ErrorSet:
    test = filtered_torques(model, trials)
    return movement_errors(list(test), list(reference), global_ptp=global_ptp)
