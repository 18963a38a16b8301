"""Rebuild the model a torque node ran, from its config message (`<node>/config`, JSON).

The reader is strict: the message must have exactly the keys torque_node writes
(nodes/torque_config.py), each of the right kind; anything else is a ValueError naming the
key, never a silent guess. The node republishes its config periodically and on every live
change; each message carries `config_id` and `applies_from_stamp_ns` (the header stamp of
the first output computed with it; 0 = from the start; null = built, not applied yet).
`config_in_force` picks, for one sample stamp, the config that computed it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from ..anthropometry import BodySize, resolve_body_size
from ..dynamics import ArmModel, build_model

CONFIG_SCHEMA = 2
DEFAULT_KIND = "segmented"
DEFAULT_SIZE = 50

#: The model part (required) and the node part (optional: a bag writer may state only the
#: model) of a config message.
MODEL_KEYS = frozenset({"schema", "model", "body_size", "side", "payload", "placement", "joint_names"})
NODE_KEYS = frozenset({"config_id", "applies_from_stamp_ns", "node", "version", "estimator",
                       "input_topic", "output_topic", "max_stamp_gap", "output_rate_hz",
                       "input_timeout", "build_ms", "deadline_ms", "realtime", "std"})
PLACEMENT_KEYS = frozenset({"name", "split", "split_rule", "axis_offset_proximal", "axis_offset_distal",
                            "cylinder"})
PAYLOAD_KEYS = frozenset({"mass", "com", "inertia"})


@dataclass
class ModelChoice:
    arm: ArmModel
    percentile: int | None  # for the reference torques; None for a custom body size
    source: str  # "torque_node/config" or "default"
    warnings: list[str] = field(default_factory=list)

    def describe(self) -> str:
        return f"{self.arm.kind}, body size {self.arm.body_size.label} (from {self.source})"


def _require(cond: bool, what: str) -> None:
    if not cond:
        raise ValueError(f"config message: {what}")


def _keys(d, allowed: frozenset, required: frozenset, where: str) -> None:
    _require(isinstance(d, dict), f"{where} must be an object, got {type(d).__name__}")
    unknown = sorted(set(d) - allowed)
    _require(not unknown, f"unknown key(s) {unknown} in {where}")
    missing = sorted(required - set(d))
    _require(not missing, f"missing key(s) {missing} in {where}")


def _percentile_of(label: str) -> int | None:
    m = re.fullmatch(r"p(\d+)", label)
    return int(m.group(1)) if m else None


def _body_size(d) -> tuple[BodySize, int | None]:
    names = {f.name for f in fields(BodySize)}
    _keys(d, frozenset(names), frozenset(names), "body_size")
    try:
        size = BodySize(**{k: (str(v) if k == "label" else float(v)) for k, v in d.items()})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"config message: body_size: {exc}") from None
    pct = _percentile_of(size.label)
    if pct is not None:
        try:
            if resolve_body_size(pct) != size:
                pct = None  # a label that does not match its scale factors: trust the factors
        except ValueError:
            pct = None
    return size, pct


def _build_kwargs(cfg: dict, size: BodySize) -> dict:
    """build_model keywords that rebuild the config's model (checked against it after)."""
    kw: dict = {}
    placement = cfg["placement"]
    if cfg["model"] == "anatomical":
        _require(placement is None, "placement must be null for the anatomical model")
    else:
        _keys(placement, PLACEMENT_KEYS, PLACEMENT_KEYS, "placement")
        kw["cylinder"] = placement["cylinder"]
        if placement["name"] in ("solid", "custom"):
            # Offsets are published at this body size; build_model takes them at the 50th
            # percentile and scales them with the forearm length.
            k = size.forearm
            kw["axis_offset_proximal"] = [x / k for x in placement["axis_offset_proximal"]]
            kw["axis_offset_distal"] = [x / k for x in placement["axis_offset_distal"]]
            if placement["name"] == "custom":
                kw["split"] = placement["split"]
        else:
            kw["placement"] = placement["name"]
    _require(cfg["side"] in ("right", "left"), f"side {cfg['side']!r} is neither right nor left")
    kw["side"] = cfg["side"]
    payload = cfg["payload"]
    if payload is not None:
        _keys(payload, PAYLOAD_KEYS, PAYLOAD_KEYS, "payload")
        kw["payload_mass"] = float(payload["mass"])
        kw["payload_com"] = tuple(payload["com"])
        if payload["inertia"] is not None:
            kw["payload_inertia"] = tuple(payload["inertia"])
    return kw


def _same_placement(built: dict | None, stated: dict | None) -> bool:
    if built is None or stated is None:
        return built is stated
    return all(
        np.allclose(built[k], stated[k], rtol=0.0, atol=1e-12) if k.startswith(("axis", "split"))
        and k != "split_rule" else built[k] == stated[k]
        for k in PLACEMENT_KEYS
    )


def model_from_config(cfg: dict | None) -> ModelChoice:
    """The model of the config (ValueError naming the problem if it cannot be read or built)."""
    if cfg is None:
        return ModelChoice(build_model(DEFAULT_KIND, DEFAULT_SIZE), DEFAULT_SIZE, "default",
                           [(f"no torque_node/config in the bag: assuming the {DEFAULT_KIND} "
                             f"model at body size {DEFAULT_SIZE}")])
    _keys(cfg, MODEL_KEYS | NODE_KEYS, MODEL_KEYS, "the message")
    _require(cfg["schema"] == CONFIG_SCHEMA,
             f"schema {cfg['schema']!r} (this forearm_dynamics reads schema {CONFIG_SCHEMA})")
    size, pct = _body_size(cfg["body_size"])
    arm = build_model(str(cfg["model"]), size, **_build_kwargs(cfg, size))
    _require(_same_placement(None if arm.placement is None else arm.placement.as_dict(),
                             cfg["placement"]),
             "placement differs from the model this forearm_dynamics builds from it "
             "(another version's placements?)")
    _require(tuple(cfg["joint_names"]) == arm.joint_names,
             "joint_names differ from the model's (not this model's config)")
    return ModelChoice(arm, pct, "torque_node/config", [])


def config_in_force(configs: Sequence[tuple[int, dict]], stamp_ns: int) -> dict | None:
    """The config that computed the output stamped `stamp_ns`.

    configs: (log time ns, config message) in recording order (periodic repeats included).
    The one in force is the applied config (applies_from_stamp_ns not null) with the latest
    applies_from_stamp_ns <= stamp_ns (ties: the highest config_id). A config recorded with
    no config_id (a writer that states only the model) applies to everything. None if no
    config applies yet.
    """
    best, key = None, None
    for _log, cfg in configs:
        start = cfg.get("applies_from_stamp_ns", 0) if "config_id" in cfg else 0
        if start is None or start > stamp_ns:
            continue
        k = (start, cfg.get("config_id", 0))
        if key is None or k >= key:
            best, key = cfg, k
    return best


def _placement(arm: ArmModel) -> dict | None:
    """The pro/sup placement that was built (None for the anatomical model): name, split,
    split rule, axis offsets (m, at this body size) and cylinder, as the core reports it."""
    return None if arm.placement is None else arm.placement.as_dict()


def model_config(arm: ArmModel) -> dict:
    """The model part of the config message: exactly what was built (model_from_config
    reads it back, strictly). Written here beside its reader so the two cannot drift.."""
    payload = None
    if arm.payload is not None:
        payload = arm.payload.as_dict()
    out = {
        "schema": CONFIG_SCHEMA,
        "model": arm.kind,
        "body_size": dataclasses.asdict(arm.body_size),
        "side": arm.side,
        "payload": payload,
        "placement": _placement(arm),
        "joint_names": list(arm.joint_names),
    }
    if any(isinstance(x, float) and not math.isfinite(x) for x in out["body_size"].values()):
        raise ValueError("body size scale factors are not finite")
    return out
