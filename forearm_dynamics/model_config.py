"""The config message (`<node>/config`, JSON): written and read by this one module.

Every writer (torque_node, bag_torques) builds its message with `config_message`, which
refuses a key the reader does not know; the reader (`model_from_config`, check_bag) is
strict: the message must have the model keys, each of the right kind, and nothing but the
keys listed here; anything else is a ConfigMessageError naming the key, never a silent
guess. The node republishes its config periodically and on every live
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

from .anthropometry import BodySize, resolve_body_size
from .dynamics import ArmModel, build_model
from .errors import ConfigMessageError
from .shoulder import SHOULDER_CHOICES

CONFIG_SCHEMA = 2
DEFAULT_KIND = "segmented"
DEFAULT_SIZE = 50

#: The model part (required, written by `model_config`) of a config message.
MODEL_KEYS = frozenset({"schema", "model", "body_size", "side", "payload", "placement", "joint_names"})
#: optional model keys: written only when the model has one (a shoulder: shoulder.py)
OPTIONAL_MODEL_KEYS = frozenset({"shoulder"})
#: The node part (optional: a bag writer may state only the model): who computed the torques
#: and how. Each key a writer may add, with what it holds.
NODE_FIELDS = {
    "config_id": "integer, 1 at start-up, +1 per live change built",
    "applies_from_stamp_ns": "header stamp of the first output computed with this config; "
                             "0 = from the start; null = built, not applied yet",
    "node": "the writer: the node's fully qualified name, or the offline tool's name",
    "version": "forearm_dynamics version of the writer",
    "estimator": "the state estimator: method, settings, lag per estimate, assumed noise",
    "input_topic": "the JointState topic read",
    "output_topic": "the torque topic written",
    "max_stamp_gap": "s: a larger stamp step resets the estimator",
    "output_rate_hz": "0 = one output per input; > 0 = a timer's rate",
    "input_timeout": "s: with output_rate_hz > 0, silence after this long without input",
    "build_ms": "how long building this model took",
    "source_bag": "offline runs: the bag the inputs were read from",
    "deadline_ms": "the node's per-sample deadline (0 = none); misses are counted in /diagnostics",
    "realtime": "the scheduling the node asked for and got (policy, priority, memory lock, CPUs)",
    "std": "the torque σ (joint_torques_std): its topic and parts, or why none is published",
    "input": "missing_joints (reject | hold), the joints held because the input lacks them "
             "and the posture (rad) they are held at",
}
NODE_KEYS = frozenset(NODE_FIELDS)
PLACEMENT_KEYS = frozenset({"name", "split", "split_rule", "axis_offset_proximal", "axis_offset_distal",
                            "cylinder"})
PAYLOAD_KEYS = frozenset({"mass", "com", "inertia"})


@dataclass
class ModelChoice:
    arm: ArmModel
    percentile: int | None  # for the reference torques; None for a custom body size
    source: str  # "torque_node/config" or "default"
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """The model as check_bag's JSON report states it."""
        arm = self.arm
        return {"kind": arm.kind, "body_size": arm.body_size.label, "side": arm.side,
                "payload_kg": 0.0 if arm.payload is None else float(arm.payload.mass),
                "source": self.source}

    def describe(self) -> str:
        arm = self.arm
        extra = "" if arm.side == "right" else f", {arm.side} arm"
        if arm.payload is not None:
            extra += f", payload {arm.payload.mass:g} kg"
        return f"{arm.kind}, body size {arm.body_size.label}{extra} (from {self.source})"


def _require(cond: bool, what: str) -> None:
    if not cond:
        raise ConfigMessageError(f"config message: {what}")


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
        raise ConfigMessageError(f"config message: body_size: {exc}") from None
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
    if "shoulder" in cfg:
        _require(cfg["shoulder"] in SHOULDER_CHOICES, f"shoulder {cfg['shoulder']!r} is not one of "
                 f"{SHOULDER_CHOICES}")
        kw["shoulder"] = cfg["shoulder"]
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
    """The model of the config (ConfigMessageError naming the problem if it cannot be read;
    the core's ValueError if it cannot be built)."""
    if cfg is None:
        return ModelChoice(build_model(DEFAULT_KIND, DEFAULT_SIZE), DEFAULT_SIZE, "default",
                           [(f"no torque_node/config in the bag: assuming the {DEFAULT_KIND} "
                             f"model at body size {DEFAULT_SIZE}")])
    _keys(cfg, MODEL_KEYS | OPTIONAL_MODEL_KEYS | NODE_KEYS, MODEL_KEYS, "the message")
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
    reads it back, strictly). Written here beside its reader so the two cannot drift."""
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
    if getattr(arm, "shoulder", None) is not None:  # absent without one: configs as before
        out["shoulder"] = arm.shoulder.name
    if any(isinstance(x, float) and not math.isfinite(x) for x in out["body_size"].values()):
        raise ValueError("body size scale factors are not finite")
    return out


def config_message(model_part: dict, **node) -> dict:
    """The whole message: the model part (`model_config`) and the writer's node part.

    A node key the reader would refuse is a programming error (KeyError) here, at the
    writer, instead of a bag that check_bag cannot read.
    """
    unknown = sorted(set(node) - NODE_KEYS)
    if unknown:
        raise KeyError(f"config message: {unknown} not among the node keys {sorted(NODE_KEYS)}")
    return {**model_part, **node}
