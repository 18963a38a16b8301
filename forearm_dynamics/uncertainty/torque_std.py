"""One σ per torque, per sample: the estimation, lag, model (and subject) parts put together.

`TorqueStd` is what torque_node and the offline API both run after each estimator update:
computeRNEADerivatives at the estimate (it returns τ as well, so the caller publishes
`tau` and runs no separate RNEA), the estimator's covariance (state_source: the one
adapter), the jerk's recent RMS (lag.JerkTracker) and the per-DOF model term
(model_term). `parts()` says what the σ contains, for the node's config message and the
bag's metadata.
"""

from __future__ import annotations

import numpy as np

from .lag import JERK_TAU_S, LAG_GAIN, JerkTracker
from .model_term import model_variance
from .propagation import Propagator
from .state_source import state_source
from .subject import subject_spread

#: the derivatives (∂τ/∂q, ∂τ/∂q̇, M), and with them the estimation part and the lag
#: weights, are re-evaluated every RELINEARISE_S of stream time (at 1 kHz every 4th sample;
#: at 250 Hz and below every sample) and whenever the covariance changed; τ and the jerk
#: term are computed on every sample (propagation.Propagator)
RELINEARISE_S = 0.004


class NoCovariance(ValueError):
    """The estimator carries no covariance: no σ can be propagated from it."""


class TorqueStd:
    """σ (N·m) of the torques of `arm` at the estimates of `est`, one call per update.

    lag: include the calibrated lag part; model: include the model-simplification part;
    subject: "none" (default) or "ansur" (subject.py: the spread of the segment parameters
    at this stature and body mass), subject_measured the dimensions the user measured.
    """

    def __init__(self, arm, est, *, lag: bool = True, model: bool = True, gain: float = LAG_GAIN,
                 tau_s: float = JERK_TAU_S, covariance: str = "noise", subject: str = "none",
                 subject_measured=()):
        src = state_source(est, covariance)
        if src is None:
            raise NoCovariance(f"estimator {est.name!r} carries no covariance: no torque σ "
                               "(use estimator kalman)")
        self.arm, self.est, self.src = arm, est, src
        self.use_lag, self.use_model = bool(lag), bool(model)
        mvar, self.model_source = model_variance(arm)
        self.model_var = mvar if model else np.zeros_like(mvar)
        self.prop = Propagator(arm.model, arm.model.createData(), self.model_var, gain)
        self.subject = subject_spread(arm, subject, subject_measured)
        self.jerk = JerkTracker(arm.nv, tau_s)
        self.gain, self.tau_s = float(gain), float(tau_s)
        self.tau = self.prop.tau
        self.std = self.prop.std
        self._lin_cov: tuple | None = None  # the covariance object of the last linearisation
        self._lin_t = 0.0

    def reset(self) -> None:
        self.jerk.reset()
        self._lin_cov = None

    def update(self, t_ns: int, velocity_given: bool) -> bool:
        """After est.update(t_ns, ...): τ into self.tau, σ into self.std; False (both
        untouched) while the estimator has no covariance yet (its first sample)."""
        est, src = self.est, self.src
        t_s = t_ns * 1e-9
        src.refresh(t_s, velocity_given)
        jerk = self.jerk.update(t_ns, est.qdd, src.baseline, src.delta_noise_var)
        cov = src.cov()
        if cov is None:
            return False
        lin = cov is not self._lin_cov or not 0.0 <= t_s - self._lin_t < RELINEARISE_S
        if lin:
            self._lin_cov, self._lin_t = cov, t_s
            if self.subject is not None:  # at the same cadence as the estimation part
                self.subject.variance(est.q, est.qd, est.qdd, out=self.prop.var_subject)
        self.prop(est.q, est.qd, est.qdd, cov, src.lag if self.use_lag else None, jerk, lin)
        return True

    def parts(self) -> dict:
        """What the σ contains (the config message's `std` entry)."""
        return {
            "meaning": "one standard deviation (N·m) of each torque: estimation, lag and model parts "
                       "added in quadrature" + (", and the subject part" if self.subject is not None else ""),
            "estimation": self.src.description["estimation"],
            "lag": (f"calibrated lag bias: gain {self.gain:g} x the estimator's error per unit jerk "
                    "x the RMS jerk (change of the qdd estimate over one qdd lag, noise part removed, "
                    f"mean square over {self.tau_s:g} s), through the same "
                    "derivatives (uncertainty/lag.py)") if self.use_lag else "off",
            "linearised_every_s": RELINEARISE_S,
            "model": (f"model simplification, per DOF constant: {self.model_source}"
                      if self.use_model else "off"),
            "model_std_nm": dict(zip(self.arm.joint_names, np.sqrt(self.model_var).round(6).tolist(),
                                     strict=True)),
            "subject_parameters": (self.subject.description if self.subject is not None else
                                   "off (subject none: the spread of segment parameters at this "
                                   "stature and body mass is not in the sigma; subject ansur adds it)"),
        }
