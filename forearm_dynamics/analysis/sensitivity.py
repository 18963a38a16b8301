"""How much the headline numbers move with the assumptions behind them.

Cases: the three readings of "stop at 45 % of the range" (movements.STOP_RULES), the
assumed hand geometry (prism thickness, digit radii, MCP positions, the thumb base's CMC
position) at 0.8x and 1.2x, the CMC moved palmar/dorsal, the thumb angle +-10 deg, and
each fitted placement coordinate moved by 1 mm. A case that changes the movements or the
hand changes the anatomical model's torques too: those references are computed with
Pinocchio's anatomical model (which matches the OpenSim reference to 1e-11 N·m,
test_reference.py); the baseline uses the shipped OpenSim reference.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..anthropometry import resolve_body_size
from ..builders import build_tree
from ..description import ModelDescription, load_description
from ..dynamics import ArmModel
from ..movements import STOP_RULES, default_stop_rule
from .comparison import Trials, filtered_torques, reference_filtered
from .errors import global_range, summarize
from .placement import HEADLINE, VARIANTS, FitCache, Scorer

SENSITIVITY_RATE_HZ = 200.0
HAND_FACTORS = (0.8, 1.2)
THUMB_PALMAR = (-0.25, 0.25)  # the CMC moved dorsal / palmar by a quarter of the palm thickness
THUMB_ANGLE_STEPS = (-10.0, 10.0)  # deg added to config/model.yaml's thumb_angle_deg
MM = 1e-3
VERSION = 2  # part of the cache key: bump when what a case computes changes


def _hand(desc: ModelDescription, what: str, k: float) -> ModelDescription:
    h = desc.hand
    if what == "prism_thickness":
        h = replace(h, thickness_fraction=h.thickness_fraction * k)
    elif what == "digit_radii":
        h = replace(h, finger_radius_fraction=h.finger_radius_fraction * k,
                    thumb_radius_fraction=h.thumb_radius_fraction * k)
    elif what == "mcp_positions":
        h = replace(h, mcp_x_fraction={f: x * k for f, x in h.mcp_x_fraction.items()})
    elif what == "thumb_cmc_position":  # radial and distal position of the CMC, scaled
        h = replace(h, thumb_cmc_fraction=h.thumb_cmc_fraction * np.array([k, k, 1.0]))
    elif what == "thumb_cmc_palmar":  # moved palmar (+) or dorsal (-) by k x the palm thickness
        h = replace(h, thumb_cmc_fraction=h.thumb_cmc_fraction + np.array([0.0, 0.0, -k]))
    elif what == "thumb_angle":  # rest direction in the palm plane, k degrees added
        h = replace(h, thumb_angle=h.thumb_angle + np.deg2rad(k))
    else:
        raise ValueError(what)
    return replace(desc, hand=h)


def headline_numbers(scorer: Scorer, overrides: dict[str, dict]) -> dict:
    """Per variant: pro/sup NRMSE (floored mean, median; global mean) and elbow RMSE."""
    out = {}
    for name in HEADLINE:
        e = scorer.errors(VARIANTS[name], **overrides.get(name, {}))
        s = summarize(e.nrmse[:, 1])
        out[name] = {"prosup_mean": s["mean"], "prosup_median": s["median"],
                     "prosup_global": float(np.nanmean(e.nrmse_global[:, 1])),
                     "elbow_rmse": float(np.mean(e.rmse[:, 0])), "excluded": int(e.excluded[1])}
    return out


def _case_scorer(desc: ModelDescription, stop_rule: str | None, ref) -> Scorer:
    trials = Trials.sample(SENSITIVITY_RATE_HZ, stop_rule=stop_rule)
    if desc is load_description() and stop_rule in (None, default_stop_rule()):
        r = reference_filtered(ref, trials, 50)
    else:  # Pinocchio's anatomical model for the changed movements or hand
        size = resolve_body_size(50)
        r = filtered_torques(ArmModel(build_tree("anatomical", desc, size)), trials)
    return Scorer(r, trials, global_range(list(r)), 50, desc)


def cases() -> list[dict]:
    out = [{"case": "baseline", "group": "baseline"}]
    out += [{"case": f"stop rule: {rule}", "group": "stop_rule", "stop_rule": rule}
            for rule in STOP_RULES if rule != default_stop_rule()]
    for what in ("prism_thickness", "digit_radii", "mcp_positions", "thumb_cmc_position"):
        out += [{"case": f"{what.replace('_', ' ')} x{k:g}", "group": "hand", "hand": what, "k": k}
                for k in HAND_FACTORS]
    out += [{"case": f"thumb CMC {'palmar' if k > 0 else 'dorsal'} {abs(k):g} x palm thickness",
             "group": "hand", "hand": "thumb_cmc_palmar", "k": k} for k in THUMB_PALMAR]
    base = float(np.rad2deg(load_description().hand.thumb_angle))
    out += [{"case": f"thumb angle {base + k:g} deg (assumed {base:g})",
             "group": "hand", "hand": "thumb_angle", "k": k} for k in THUMB_ANGLE_STEPS]
    return out


def placement_perturbations(overrides: dict[str, dict], length: float) -> list[dict]:
    """Every fitted coordinate of parallel and oblique moved by +-1 mm (split: 1 mm along
    the forearm's length)."""
    out = []
    for name in ("parallel", "oblique"):
        base = overrides[name]
        for key in ("split", "axis_offset_proximal", "axis_offset_distal"):
            if key not in base:
                continue
            if key == "split":
                for sgn in (-1, 1):
                    out.append({"variant": name, "what": f"split {sgn:+d} mm",
                                "overrides": {**base, "split": base["split"] + sgn * MM / length}})
                continue
            if name == "parallel" and key == "axis_offset_distal":
                continue  # the parallel offset is one 2-D coordinate used at both ends
            for i, axis in enumerate(("anterior", "lateral")):
                for sgn in (-1, 1):
                    v = list(base[key])
                    v[i] += sgn * MM
                    ov = {**base, key: v}
                    if name == "parallel":
                        ov["axis_offset_distal"] = v
                    out.append({"variant": name, "what": f"{key} {axis} {sgn:+d} mm", "overrides": ov})
    return out


def sensitivity(ref, overrides: dict[str, dict], cache: FitCache, length: float, tick=None) -> dict:
    """{cases: [{case, group, numbers}], placement: [{variant, what, numbers}]}."""
    desc = load_description()
    rows = []
    for c in cases():
        spec = {"what": "sensitivity", "version": VERSION, **c, "overrides": overrides,
                "rate_hz": SENSITIVITY_RATE_HZ}

        def compute(c=c):
            d = _hand(desc, c["hand"], c["k"]) if "hand" in c else desc
            return headline_numbers(_case_scorer(d, c.get("stop_rule"), ref), overrides)

        rows.append({**c, "numbers": cache.get_or_compute(spec, compute)})
        if tick:
            tick()
    perturbed = placement_perturbations(overrides, length)
    spec = {"what": "placement_sensitivity", "version": VERSION, "perturbed": perturbed,
            "rate_hz": SENSITIVITY_RATE_HZ}

    def compute_placement():
        scorer = _case_scorer(desc, None, ref)
        out = []
        for p in perturbed:
            e = scorer.errors(VARIANTS[p["variant"]], **p["overrides"])
            s = summarize(e.nrmse[:, 1])
            out.append({"variant": p["variant"], "what": p["what"], "numbers": {
                "prosup_mean": s["mean"], "prosup_median": s["median"],
                "prosup_global": float(np.nanmean(e.nrmse_global[:, 1])),
                "elbow_rmse": float(np.mean(e.rmse[:, 0]))}})
        return out

    return {"rate_hz": SENSITIVITY_RATE_HZ, "cases": rows,
            "placement": cache.get_or_compute(spec, compute_placement)}
