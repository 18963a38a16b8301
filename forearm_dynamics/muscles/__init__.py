"""Muscle forces behind the joint torques (issue 31): model, moment-arm surrogates, static
optimisation.

Why a package of its own: the torque path (dynamics, estimation, nodes) must stay untouched
and usable without it; the muscle layer takes the torques and the state and splits each
torque into muscle forces. It knows nothing of ROS (the muscle node and the offline tools
sit above it). docs/muscles-api.md is the contract the node codes against.

- `model.py` — `MuscleModel` (parameters, spans, source and licence) and
  `load_muscle_model` (shipped MyoArm-derived default or a user's file; body size, side).
- `surrogate.py` — polynomial moment arms and lengths of the posture (fast path).
- `curves.py` — DeGroote-Fregly 2016 force-length-velocity curves (rigid tendon).
- `static_opt.py` — `StaticOptimizer`: min Σa² + Σ(r/r_opt)² s.t. R·F(a) + r = τ, daqp.
- `fit.py` — `python -m forearm_dynamics.muscles.fit`: derives the shipped data file from
  MyoSuite's myo_sim MyoArm (MuJoCo; optional extra `muscles-fit`).
- `source_osim.py` — `python -m forearm_dynamics.muscles.source_osim MODEL.osim -o FILE`:
  the same file from a user's own OpenSim model (e.g. MoBL-ARMS; optional extra `reference`).
"""

from __future__ import annotations

from .model import MuscleModel, MuscleModelError, load_muscle_model
from .static_opt import MuscleSeries, MuscleSolution, StaticOptimizer

__all__ = [
    "MuscleModel",
    "MuscleModelError",
    "MuscleSeries",
    "MuscleSolution",
    "StaticOptimizer",
    "load_muscle_model",
]
