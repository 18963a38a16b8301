"""Torque uncertainty: a calibrated 1σ per joint torque, ROS-free (issue 19).

Layer: above estimation (it reads an estimator's covariance through state_source, the one
adapter), below analysis/offline/nodes. Parts: propagation (the state covariance through
the linearised RNEA), lag (the bias a causal estimate has under jerk), model_term (the
segmented model vs the anatomical reference, from the paper's results), torque_std (the
three put together, per sample), api (the offline entry point). docs/uncertainty.md says
what the σ means and what it does not contain.
"""

from .api import TorquesWithStd, inverse_dynamics_with_std
from .torque_std import NoCovariance, TorqueStd

__all__ = ["NoCovariance", "TorqueStd", "TorquesWithStd", "inverse_dynamics_with_std"]
