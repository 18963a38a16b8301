"""Held-out validation of the fitted placements: fit on half the movements, score the rest.

Two halvings of the 65 movements (odd vs even hand movements; elbow still vs elbow moving),
each in both directions, and across body sizes (the 50th-percentile fit scored at the 5th
and 95th against a fit made at that size). Every score uses the same global normalisation
(ranges over all 65 movements), so the halves are on one scale.
"""

from __future__ import annotations

import numpy as np

from ..movements import movement_library
from .errors import summarize
from .placement import VARIANTS, FitCache, Scorer, fit, start_of

VALIDATED = ("solid_parallel_axis", "parallel", "solid_fitted_axis", "oblique")


def halves() -> dict[str, tuple[tuple[int, ...], tuple[int, ...]]]:
    """name -> (fit movements, held-out movements); each pair covers the 65 once."""
    lib = movement_library()
    odd = tuple(m.id for m in lib if m.hand_number % 2)
    even = tuple(m.id for m in lib if not m.hand_number % 2)
    still = tuple(m.id for m in lib if m.start[0] == m.stop[0])
    moving = tuple(m.id for m in lib if m.start[0] != m.stop[0])
    return {"odd_to_even": (odd, even), "even_to_odd": (even, odd),
            "still_to_moving": (still, moving), "moving_to_still": (moving, still)}


def _score(scorer: Scorer, name: str, overrides: dict) -> dict:
    e = scorer.errors(VARIANTS[name], **overrides)
    return {"objective": float(np.nanmean(e.nrmse_global[:, 1]) + np.nanmean(e.nrmse_global[:, 0])),
            "prosup_nrmse": summarize(e.nrmse[:, 1]),
            "prosup_nrmse_global_mean": float(np.nanmean(e.nrmse_global[:, 1]))}


def held_out(scorer: Scorer, full_fits: dict, cache: FitCache, rate_hz: float, tick=None) -> dict:
    """For each halving and fitted variant: the fit on one half scored on the other (held
    out), beside the other half's own fit scored on itself (in-sample: the best possible)."""
    out = {}
    hv = halves()
    own: dict[tuple, dict] = {}
    for name in VALIDATED:
        v = VARIANTS[name]
        for split_name, (train, _test) in hv.items():
            spec = {"what": "fit", "variant": name, "movements": list(train), "body_size": 50,
                    "rate_hz": rate_hz}
            own[(name, train)] = cache.get_or_compute(
                spec, lambda v=v, train=train: fit(v, scorer.subset(train),
                                                   start=start_of(v, full_fits[v.name]["overrides"]),
                                                   callback=tick))
    for split_name, (train, test) in hv.items():
        rows = {}
        sub = scorer.subset(test)
        for name in VALIDATED:
            trained = own[(name, train)]["overrides"]
            best_on_test = own[(name, test)]["overrides"]
            rows[name] = {
                "fit_on": list(train), "scored_on": list(test),
                "fitted": trained,
                "held_out": _score(sub, name, trained),
                "in_sample": _score(sub, name, best_on_test),
                "all_65_fit": _score(sub, name, full_fits[name]["overrides"]),
            }
        out[split_name] = rows
    return out


def across_sizes(scorers: dict, full_fits: dict, cache: FitCache, rate_hz: float, tick=None) -> dict:
    """The 50th-percentile fit scored at other sizes (held out) vs a fit at that size."""
    out = {}
    for size, scorer in scorers.items():
        rows = {}
        for name in VALIDATED:
            v = VARIANTS[name]
            spec = {"what": "fit", "variant": name, "movements": "all", "body_size": size,
                    "rate_hz": rate_hz}
            own = cache.get_or_compute(spec, lambda v=v, scorer=scorer: fit(
                v, scorer, start=start_of(v, full_fits[v.name]["overrides"]), callback=tick))
            rows[name] = {"fitted_at_size": own["overrides"],
                          "held_out": _score(scorer, name, full_fits[name]["overrides"]),
                          "in_sample": _score(scorer, name, own["overrides"])}
        out[f"p{size}"] = rows
    return out
