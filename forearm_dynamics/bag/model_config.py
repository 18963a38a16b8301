"""Rebuild the model a torque node ran, from its latched `torque_node/config` JSON.

Tolerant of the key variants seen so far: "model" or "kind"; "body_size" as a percentile
(50, "50", "p50"), as scale factors {"label", "forearm", "hand_length", "hand_breadth",
"mass"} (what torque_node publishes), {"percentile": 50} or raw anthropometry
{"stature", "body_mass", ...}; overrides under "simplified" or at the top level.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..anthropometry import DIMENSIONS, BodySize, resolve_body_size
from ..description import load_description
from ..dynamics import ArmModel, build_model

DEFAULT_KIND = "segmented"
DEFAULT_SIZE = 50
_SCALES = ("forearm", "hand_length", "hand_breadth", "mass")


@dataclass
class ModelChoice:
    arm: ArmModel
    percentile: int | None  # for the reference torques; None for a custom body size
    source: str  # "torque_node/config" or "default"
    warnings: list[str] = field(default_factory=list)

    def describe(self) -> str:
        return f"{self.arm.kind}, body size {self.arm.body_size.label} (from {self.source})"


def _percentile_of(label) -> int | None:
    m = re.fullmatch(r"p?(\d+)(?:th)?", str(label).strip())
    return int(m.group(1)) if m else None


def _body_size(value) -> tuple[BodySize, int | None]:
    if isinstance(value, dict):
        if all(k in value for k in _SCALES):
            label = str(value.get("label", "custom"))
            size = BodySize(label, *(float(value[k]) for k in _SCALES))
            pct = _percentile_of(label)
            if pct is not None and resolve_body_size(pct) != size:
                pct = None  # a label that does not match its scale factors: trust the factors
            return size, pct
        if "percentile" in value:
            pct = int(value["percentile"])
            return resolve_body_size(pct), pct
        dims = {k: v for k, v in value.items() if k in DIMENSIONS}
        return resolve_body_size(dims), None
    pct = _percentile_of(value)
    if pct is None:
        raise ValueError(f"body_size {value!r} is neither a percentile nor a dict")
    return resolve_body_size(pct), pct


def _overrides(cfg: dict, kind: str) -> dict:
    src = cfg.get("simplified") if isinstance(cfg.get("simplified"), dict) else cfg
    keys = {"segmented": ("split", "axis_offset_proximal", "axis_offset_distal"),
            "solid": ("axis_offset_proximal", "axis_offset_distal")}.get(kind, ())
    out = {k: src[k] for k in keys if src.get(k) is not None}
    if kind == "solid":
        # torque_node states the description's (segmented) axis offsets for a solid model
        # too, while build_model("solid") uses the cylinder's own axis unless told: offsets
        # equal to those defaults say nothing about the solid model, so they are dropped.
        s = load_description().simplified
        defaults = {"axis_offset_proximal": s.axis_offset_proximal,
                    "axis_offset_distal": s.axis_offset_distal}
        out = {k: v for k, v in out.items() if not np.allclose(np.asarray(v, float), defaults[k])}
    return out


def model_from_config(cfg: dict | None) -> ModelChoice:
    """The model of the config (ValueError if it names one that cannot be built)."""
    if cfg is None:
        return ModelChoice(build_model(DEFAULT_KIND, DEFAULT_SIZE), DEFAULT_SIZE, "default",
                           [(f"no torque_node/config in the bag: assuming the {DEFAULT_KIND} "
                             f"model at body size {DEFAULT_SIZE}")])
    kind = str(cfg.get("model") or cfg.get("kind") or DEFAULT_KIND)
    warnings = [] if ("model" in cfg or "kind" in cfg) else \
        [f"config names no model kind: assuming {DEFAULT_KIND}"]
    size, pct = _body_size(cfg.get("body_size", DEFAULT_SIZE))
    arm = build_model(kind, size, **_overrides(cfg, kind))
    names = cfg.get("joint_names")
    if names is not None and tuple(names) != arm.joint_names:
        warnings.append("config joint_names differ from the model's; torques are matched by name")
    return ModelChoice(arm, pct, "torque_node/config", warnings)
