"""One σ per torque, per sample: the estimation, lag, model (and subject) parts put together.

`TorqueStd` is what torque_node and the offline API both run after each estimator update
(the torques themselves are pin.rnea's, computed and published first): the derivatives
(∂τ/∂q, ∂τ/∂q̇, M) at the estimate, the estimator's covariance (state_source: the one
adapter), the jerk's recent RMS (lag.JerkTracker) and the per-DOF model term
(model_term). `predict(t_ns)` gives the σ of the estimator's extrapolation to another
stamp (torque_node's output_rate_hz > 0). `parts()` says what the σ contains, for the
node's config message and the bag's metadata.
"""

from __future__ import annotations

import numpy as np

from .lag import JERK_TAU_S, LAG_GAIN, JerkTracker
from .model_term import model_variance
from .propagation import Propagator, extrapolated
from .state_source import state_source
from .subject import subject_spread

#: the σ is evaluated at most this often (s of stream time; at 1 kHz every 4th sample, at
#: 250 Hz and below every sample): the covariance source's refresh, the jerk read and the
#: propagation at the current estimate (computeRNEADerivatives); between evaluations the last
#: σ stands. The jerk term averages over JERK_TAU_S (60 ms) and the derivatives move on the
#: movement's time scale, so a σ up to 4 ms old differs little from a fresh one; evaluated on
#: every sample it cost a 1 kHz node ~85 µs of every callback (benchmarks/uncertainty_cost.py:
#: callback p50 with the σ computed but not written, against without the σ)
EVALUATE_S = 0.004


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
        self.std = self.prop.std
        self._eval_ns: int | None = None  # the stamp of the last evaluation
        self._known = False  # whether the σ of the last update() is known
        self._holds_update = False  # self.std holds the last update()'s σ (not a prediction's)
        self.evaluated_ns: int | None = None  # the stamp the σ in self.std was evaluated at
        self._jerk_ms = self.jerk.ms_jerk  # the mean-square jerk at the last evaluation

    def reset(self) -> None:
        self.jerk.reset()
        self._eval_ns = None
        self._known = self._holds_update = False

    def observe(self, t_ns: int, velocity_given: bool) -> bool:
        """After est.update(t_ns, ...): the jerk tracker keeps the q̈ estimate; every
        EVALUATE_S the covariance source and the jerk read are brought up to date (what
        update() does before propagating; alone when only predictions are output). True when
        it evaluated."""
        self.jerk.push(t_ns, self.est.qdd)
        if self._eval_ns is not None and 0 <= t_ns - self._eval_ns < EVALUATE_S * 1e9:
            return False
        self._eval_ns = t_ns
        src = self.src
        src.refresh(t_ns * 1e-9, velocity_given)
        self._jerk_ms = self.jerk.read(src.baseline, src.delta_noise_var, src.lag_scale2)
        return True

    def update(self, t_ns: int, velocity_given: bool) -> bool:
        """After est.update(t_ns, ...): σ into self.std, evaluated at the estimate every
        EVALUATE_S (the last one stands in between); False (σ unknown) while the estimator
        has no covariance yet or its noise is not measured."""
        if not self.observe(t_ns, velocity_given) and self._holds_update:
            return self._known
        self._holds_update = True
        est = self.est
        cov = self.src.cov()
        self._known = cov is not None
        if cov is None:
            return False
        if self.subject is not None:  # at the same cadence as the estimation part
            self.subject.variance(est.q, est.qd, est.qdd, out=self.prop.var_subject)
        self.prop(est.q, est.qd, est.qdd, cov, self.src.lag if self.use_lag else None, self._jerk_ms, True)
        self.evaluated_ns = t_ns
        return True

    def predict(self, t_ns: int) -> bool:
        """After est.predict(t_ns): σ of the extrapolated estimate into self.std (False while
        there is no covariance): the covariance and the lag moved over the horizon h =
        t_ns - est.stamp_ns (propagation.extrapolated), linearised at the extrapolated state
        on every call (the subject part too), so the result depends on the last update and
        t_ns only (not on earlier predictions)."""
        est, src = self.est, self.src
        cov = src.cov()
        if cov is None or est.stamp_ns is None:
            return False
        h = max((t_ns - est.stamp_ns) * 1e-9, 0.0)  # as est.predict extrapolates
        cov_h, lag = extrapolated(cov, src.lag if self.use_lag else None, h)
        if self.subject is not None:
            self.subject.variance(est.q, est.qd, est.qdd, out=self.prop.var_subject)
        self.prop(est.q, est.qd, est.qdd, cov_h, lag, self._jerk_ms, True)
        self._holds_update = False  # self.std is this prediction's: update() propagates afresh
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
            "evaluated_every_s": EVALUATE_S,
            "prediction": "an output extrapolated h ahead of the estimate (output_rate_hz > 0): "
                          "covariance F(h) Σ F(h)ᵀ and lag per unit jerk F(h) e - (h³/6, h²/2, h), "
                          "F the constant-acceleration transition, linearised at the extrapolated "
                          "state (uncertainty/propagation.py extrapolated)",
            "model": (f"model simplification, per DOF constant: {self.model_source}"
                      if self.use_model else "off"),
            "model_std_nm": dict(zip(self.arm.joint_names, np.sqrt(self.model_var).round(6).tolist(),
                                     strict=True)),
            "subject_parameters": (self.subject.description if self.subject is not None else
                                   "off (subject none: the spread of segment parameters at this "
                                   "stature and body mass is not in the sigma; subject ansur adds it)"),
        }
