"""Held-out tests a reviewer accepts: leave one hand movement out, and bodies that are not
scaled copies of the 50th percentile.

Leave-one-movement-out (LOMO): 13 folds, one per hand movement (its 5 elbow conditions are
scored); the fit sees none of the held-out movement's *mirror group* either (the same DOFs
moving the other way: pronation/supination, close/open ...), so a mirror image cannot leak
the answer. Every fit starts from the neutral placement (axis on the cylinder's centreline,
split at mid-length), not from the all-movement optimum.

Body proportions: the ANSUR II men's 5th-95th spread of forearm length, hand size and body
mass combined in ways similarity scaling never produces (long forearm with a small hand,
heavy and short ...), and the women's sizes. The anatomical torques of those bodies come
from Pinocchio's anatomical model (equal to the OpenSim reference to 1e-11 N·m,
test_reference.py); the placements are the shipped 50th-percentile fits, not refitted.
"""

from __future__ import annotations

import numpy as np

from ..anthropometry import resolve_body_size
from ..builders import build_tree
from ..dynamics import ArmModel
from ..movements import movement_library
from .comparison import Trials, filtered_torques
from .errors import global_range, summarize
from .placement import VARIANTS, FitCache, Scorer, fit, objective_of

VERSION = 1  # part of every cache key of this module
#: Hand movements moving the same DOFs in opposite directions (config/movements.yaml).
MIRROR_GROUPS = ((1, 2), (3, 4), (5, 6), (7, 10), (8, 9), (11, 12), (13,))
LOMO_VARIANTS = ("solid_parallel_axis", "parallel", "solid_fitted_axis", "oblique")
NEUTRAL_SPLIT = 0.5

#: ANSUR II 2012 men's 5th / 50th / 95th (config/body_sizes.yaml), combined across
#: dimensions: each case keeps the others at the 50th.
_M = {"forearm_length": (0.244, 0.267, 0.295), "hand_length": (0.177, 0.193, 0.210),
      "hand_breadth": (0.081, 0.088, 0.096), "body_mass": (64.4, 84.6, 110.7)}


def _dims(forearm: int, hand: int, mass: int) -> dict:
    return {"forearm_length": _M["forearm_length"][forearm], "hand_length": _M["hand_length"][hand],
            "hand_breadth": _M["hand_breadth"][hand], "body_mass": _M["body_mass"][mass]}


#: name -> body_size argument (index 0 / 1 / 2 = 5th / 50th / 95th of that dimension).
BODIES = {
    "long_forearm_small_hand": _dims(2, 0, 1),
    "short_forearm_large_hand": _dims(0, 2, 1),
    "heavy_short": _dims(0, 0, 2),
    "light_long": _dims(2, 2, 0),
    "female_5": "female_5", "female_50": "female_50", "female_95": "female_95",
}


def mirror_group(hand_number: int) -> tuple[int, ...]:
    return next(g for g in MIRROR_GROUPS if hand_number in g)


def lomo_folds() -> list[dict]:
    """[{held_out: hand movement, train: movement ids, test: movement ids}] x 13."""
    lib = movement_library()
    out = []
    for k in range(1, 14):
        excluded = mirror_group(k)
        out.append({"held_out": k, "excluded_from_fit": list(excluded),
                    "train": [m.id for m in lib if m.hand_number not in excluded],
                    "test": [m.id for m in lib if m.hand_number == k]})
    return out


def neutral_start(name: str) -> tuple:
    """The neutral placement in the variant's `free` order: centreline axis, split 0.5."""
    return tuple(NEUTRAL_SPLIT if f == "split" else (0.0, 0.0) for f in VARIANTS[name].free)


def _fold_errors(scorer: Scorer, name: str, overrides: dict) -> dict:
    e = scorer.errors(VARIANTS[name], **overrides)
    return {"objective": objective_of(e), "prosup_nrmse": e.nrmse[:, 1].tolist(),
            "prosup_nrmse_global": e.nrmse_global[:, 1].tolist(),
            "elbow_nrmse_global": e.nrmse_global[:, 0].tolist()}


def lomo(scorer: Scorer, cache: FitCache, rate_hz: float, tick=None,
         variants=LOMO_VARIANTS) -> dict:
    """Per variant: the all-65 fit from neutral, and 13 folds (fit without the held-out
    movement's mirror group, from neutral; score the held-out movement's 5 conditions)."""
    folds = lomo_folds()
    out = {"folds": [{k: f[k] for k in ("held_out", "excluded_from_fit", "test")} for f in folds],
           "start": "neutral: axis on the centreline, split 0.5", "rate_hz": rate_hz,
           "variants": {}}
    for name in variants:
        v = VARIANTS[name]
        start = neutral_start(name)

        def fit_on(movements, v=v, start=start):
            spec = {"what": "fit", "version": VERSION, "variant": v.name, "start": "neutral",
                    "movements": movements, "body_size": 50, "rate_hz": rate_hz}
            sub = scorer if movements == "all" else scorer.subset(movements)
            return cache.get_or_compute(spec, lambda: fit(v, sub, start=start, callback=tick))

        full = fit_on("all")
        rows = []
        for f in folds:
            trained = fit_on(f["train"])
            test = scorer.subset(f["test"])
            rows.append({"held_out": f["held_out"], "fitted": trained["overrides"],
                         "evaluations": trained["evaluations"],
                         "held_out_errors": _fold_errors(test, name, trained["overrides"]),
                         "all_65_fit_errors": _fold_errors(test, name, full["overrides"])})
        held = np.concatenate([r["held_out_errors"]["prosup_nrmse"] for r in rows])
        insample = np.concatenate([r["all_65_fit_errors"]["prosup_nrmse"] for r in rows])
        out["variants"][name] = {
            "all_65_fit_from_neutral": full, "folds": rows,
            "prosup_nrmse_held_out": summarize(held),
            "prosup_nrmse_all_65_fit": summarize(insample),
        }
    return out


def body_scorer(body, rate_hz: float, desc=None) -> Scorer:
    """A scorer against Pinocchio's anatomical model of `body` (any body_size argument)."""
    size = resolve_body_size(body)
    trials = Trials.sample(rate_hz)
    scorer = Scorer(np.zeros((65, trials.n, 20)), trials, np.ones(20), size, desc)
    r = filtered_torques(ArmModel(build_tree("anatomical", scorer.desc, size)), trials)
    return replace_reference(scorer, r)


def replace_reference(scorer: Scorer, reference: np.ndarray) -> Scorer:
    return Scorer(reference, scorer.trials, global_range(list(reference)), scorer.size, scorer.desc)


def body_proportions(overrides: dict[str, dict], cache: FitCache, rate_hz: float,
                     models=("solid", "paper", "parallel", "oblique"), tick=None) -> dict:
    """Each body of BODIES: every model's pro/sup and elbow errors (shipped placements)."""
    out = {}
    for body, arg in BODIES.items():
        spec = {"what": "body_proportions", "version": VERSION, "body": arg, "models": list(models),
                "overrides": overrides, "rate_hz": rate_hz}

        def compute(arg=arg):
            sc = body_scorer(arg, rate_hz)
            res = {}
            for name in models:
                e = sc.errors(VARIANTS[name], **overrides.get(name, {}))
                res[name] = {"prosup_nrmse": e.nrmse[:, 1].tolist(),
                             "prosup_nrmse_global": e.nrmse_global[:, 1].tolist(),
                             "elbow_nrmse_global": e.nrmse_global[:, 0].tolist(),
                             "elbow_rmse": e.rmse[:, 0].tolist()}
            return res

        size = resolve_body_size(arg)
        out[body] = {"body_size": arg, "ratios": {"forearm": size.forearm, "hand_length": size.hand_length,
                                                  "hand_breadth": size.hand_breadth, "mass": size.mass},
                     "models": cache.get_or_compute(spec, compute)}
        if tick:
            tick()
    return out


__all__ = ["BODIES", "MIRROR_GROUPS", "body_proportions", "lomo", "lomo_folds", "neutral_start"]
