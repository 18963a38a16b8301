"""torque_node's model parameters: validation, the immutable bundle a sample is computed
with, and the config message that states it.

A live change (`ros2 param set`, several at once with set_parameters_atomically) goes:
validate here (`ModelRequest.from_values`, cheap: no model is built, on the executor
thread) -> accepted or refused with the reason -> built on the node's worker thread
(`build_bundle`, ~1 ms) -> swapped in by the subscription callback between two samples (one
reference) -> config message republished with its `config_id` and the stamp of the first
sample computed with it (`applies_from_stamp_ns`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from ..anthropometry import DIMENSIONS, resolve_body_size
from ..builders import MODEL_KINDS
from ..description import JOINT_NAMES
from ..dynamics import ArmModel, build_model
from ..estimation import (
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    StateEstimator,
    all_settings,
    make_estimator,
)
from ..model_config import model_config
from ..paths import config_file
from ..payload import make_payload
from ..shoulder import SHOULDER_CHOICES
from ..uncertainty import NoCovariance, TorqueStd
from .spec import ParameterError, Settings, Spec

SIDES = ("right", "left")
PLACEMENTS = ("", "paper", "parallel", "oblique")
_DIM_UNITS = {"body_mass": "kg"}


def _dimension_bounds() -> dict[str, tuple[float, float]]:
    bounds = yaml.safe_load(config_file("body_sizes.yaml").read_text())["bounds"]
    return {k: tuple(v) for k, v in bounds.items()}


def _model_specs() -> tuple[Spec, ...]:
    bounds = _dimension_bounds()
    est = tuple(
        Spec(f"estimator.{s.name}", float(s.default), s.description, s.unit, s.lo, s.hi, live=True)
        for s in all_settings().values()
    )
    return (
        Spec("model", "segmented", "model kind", choices=MODEL_KINDS, live=True),
        Spec("body_size", 50, "body size: an ANSUR II percentile given as an integer (5, 50, 95: men) "
             "or a string ('50', 'male_95', 'female_5': ANSUR II men's and women's sizes); "
             "ignored when custom anthropometry is set. The one parameter that takes two types",
             live=True, dynamic=True),
        Spec("side", "right", "which arm (the left is the mirror image; same joint names and signs)",
             choices=SIDES, live=True),
        Spec("payload_mass", 0.0, "mass of an object held in the hand; 0 = empty hand", "kg",
             0.0, 50.0, live=True),
        Spec("payload_com", [0.0, 0.0, 0.0], "the object's centre of mass (x, y, z) in the hand "
             "frame (origin at the wrist centre, x toward the thumb, y toward the elbow, z toward "
             "the back of the hand); all zeros = the default power-grasp point in the palm",
             "m", -0.5, 0.5, live=True),
        Spec("payload_inertia", [0.0] * 6, "the object's inertia about its centre of mass "
             "(Ixx, Iyy, Izz, Ixy, Ixz, Iyz); all zeros = a point mass", "kg*m^2", -10.0, 10.0,
             live=True),
        Spec("placement", "", "pro/sup axis placement of the simplified models; '' = the model's "
             "default", choices=PLACEMENTS, live=True),
        *(Spec(d, 0.0, f"custom anthropometry: {d.replace('_', ' ')}; 0 = unused (any non-zero "
               "value replaces body_size; body_mass and stature, or all three segment lengths, "
               "are then needed)", _DIM_UNITS.get(d, "m"), 0.0, bounds[d][1], live=True)
          for d in DIMENSIONS),
        Spec("split", -1.0, "segmented model: fraction of the forearm proximal to the pro/sup split, "
             "in [0, 1]; -1 = config/model.yaml", "", -1.0, 1.0, live=True),
        Spec("estimator", DEFAULT_ESTIMATOR, "state estimator for velocity and acceleration",
             choices=tuple(ESTIMATORS), live=True),
        *est,
        Spec("subject_std", "none", "the torque sigma's subject part (with publish_std): none, or "
             "ansur = the ANSUR II spread of forearm and hand lengths and masses at this stature "
             "and body mass (custom segment lengths given count as measured: no spread); "
             "docs/uncertainty.md part 4", choices=("none", "ansur"), live=True),
    )


MODEL_SPECS = _model_specs()
#: model parameters that only shape the torque σ: not for nodes without one (arm_sim, arm_viz)
TORQUE_STD_ONLY = frozenset({"subject_std"})
_SUBJECT_DEFAULT = next(s.default for s in MODEL_SPECS if s.name == "subject_std")
LIVE = frozenset(s.name for s in MODEL_SPECS)

#: Partial joint sets (a mocap lab's arm, a glove's fingers): read-only
INPUT_SPECS = (
    Spec("missing_joints", "reject", "What to do with a model joint absent from an input "
         "message: reject the message (naming the joints), or hold the joint at "
         "hold_posture.<joint> with zero velocity and acceleration (listed in ~/config and "
         "/diagnostics). One sensor per node: two sensors with disjoint joint sets on one node "
         "are not merged.",
         choices=("reject", "hold")),
    *(Spec(f"hold_posture.{j}", 0.0, f"With missing_joints hold, the angle {j} is held at when "
           "the input lacks it.", "rad", -2 * np.pi, 2 * np.pi) for j in JOINT_NAMES),
    Spec("shoulder", "none", "The humerus' orientation as three more inputs (docs/shoulder.md): "
         "none = welded vertical and still (the 20-joint model); mobl = MoBL-ARMS angles "
         "(shoulder_elevation_plane, shoulder_elevation, shoulder_rotation; or elv_angle, "
         "shoulder_elv, shoulder_rot); fullbody = OpenSim full-body angles (arm_flexion, "
         "arm_adduction, arm_rotation; or arm_flex_r, arm_add_r, arm_rot_r, _l for the left "
         "side). The angles come in joint_states (or from imu_topic); the output then holds "
         "23 names: the shoulder's generalized forces last",
         choices=SHOULDER_CHOICES),
    Spec("imu_topic", "", "sensor_msgs/Imu on the upper arm: its orientation gives the shoulder "
         "angles (needs shoulder mobl or fullbody; joint_states then need not carry them, and "
         "their velocities are estimated from the angles); '' = off"),
    Spec("imu_mount", [0.0, 0.0, 0.0, 1.0], "the humerus frame in the Imu's frame, as a "
         "quaternion (x, y, z, w); identity = the sensor's x anterior, y along the humerus "
         "toward the shoulder, z lateral. The Imu's world is REP 103's (z up, ENU); only its "
         "tilt matters to the torques", "", -1.0, 1.0),
)

OUTPUT_SPECS = (
    Spec("output_rate_hz", 0.0, "0 = one output per input; > 0 = publish from a timer at this "
         "rate, each message stamped with its publication time (system clock) and computed from "
         "the estimator's prediction to that time", "Hz", 0.0, 10000.0),
    Spec("input_timeout", 0.2, "with output_rate_hz > 0: stop publishing when no input arrived "
         "for this long (never extrapolate further)", "s", 0.001, 3600.0),
    Spec("publish_std", False, "publish std_topic: for every output, the same header and names with "
         "effort = one standard deviation of each torque (N*m; estimation, lag and model parts, "
         "and the subject part with subject_std ansur, stated in ~/config; docs/uncertainty.md); "
         "with output_rate_hz > 0 that of each extrapolated output, its growth over the horizon "
         "included. Needs an estimator with a covariance (kalman); otherwise nothing is published "
         "there and ~/config says why. Off by default: a second message per sample costs more "
         "than the budget at 1 kHz (benchmarks/uncertainty_cost.py)"),
    Spec("std_topic", "joint_torques_std", "JointState topic of the torques' standard deviations "
         "(remappable too)"),
)


@dataclass(frozen=True)
class OutputSettings(Settings):
    """The torque node's output parameters (OUTPUT_SPECS), read once at start-up."""

    output_rate_hz: float
    input_timeout: float
    publish_std: bool
    std_topic: str


@dataclass(frozen=True)
class ModelRequest:
    """Validated model and estimator parameters (what to build)."""

    kind: str
    body_size: Any  # int, str or dict of custom anthropometry
    side: str
    payload_mass: float
    payload_com: tuple[float, ...]
    payload_inertia: tuple[float, ...] | None
    placement: str
    split: float | None
    estimator: str
    estimator_settings: tuple[tuple[str, float], ...]
    subject_std: str = "none"  # the σ's subject part (uncertainty/subject.py)
    shoulder: str = "none"  # the moving humerus' convention (read-only parameter; shoulder.py)

    @classmethod
    def from_values(cls, v: dict[str, Any]) -> ModelRequest:
        """Check the values rclpy cannot (body size, combinations); ParameterError names one."""
        kind = v["model"]
        custom = {d: float(v[d]) for d in DIMENSIONS if v[d] > 0.0}
        size = custom or _body_size_value(v["body_size"])
        try:
            resolve_body_size(size)
        except ValueError as exc:
            raise _body_size_error(str(exc), bool(custom), v["body_size"]) from None
        split = float(v["split"])
        if split != -1.0 and not 0.0 <= split <= 1.0:
            raise ParameterError("split", f"{split!r}: must be in [0, 1], or -1 for the default")
        if split != -1.0 and kind != "segmented":
            raise ParameterError("split", f"applies to the segmented model only (model is {kind})")
        placement = v["placement"]
        if placement and kind == "anatomical":
            raise ParameterError("placement", "applies to the solid and segmented models only")
        inertia = tuple(float(x) for x in v["payload_inertia"])
        if len(inertia) not in (0, 6):
            raise ParameterError("payload_inertia", f"needs 6 values (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) "
                                 f"or none, got {len(inertia)}")
        com = tuple(float(x) for x in v["payload_com"])
        if len(com) != 3:
            raise ParameterError("payload_com", f"needs 3 values (x, y, z) in m, got {len(com)}")
        req = cls(kind, size, v["side"], float(v["payload_mass"]), com,
                  inertia if any(inertia) else None, placement, None if split == -1.0 else split,
                  v["estimator"], tuple((k.removeprefix("estimator."), float(x))
                                        for k, x in sorted(v.items()) if k.startswith("estimator.")),
                  v.get("subject_std", _SUBJECT_DEFAULT), v.get("shoulder", "none"))
        try:  # the core's own checks (cheap), so a refused payload never reaches the worker
            make_payload(req.payload_mass, req.com_or_default(), req.payload_inertia, np.zeros(3))
        except ValueError as exc:
            raise ParameterError(str(exc).split(" ", 1)[0], str(exc)) from None
        try:
            make_estimator(req.estimator, 1, req.settings_for(req.estimator))
        except ValueError as exc:
            raise ParameterError("estimator", str(exc)) from None
        delay = dict(req.estimator_settings).get("delay_s", 0.0)
        if delay > 0.0 and "delay_s" not in req.settings_for(req.estimator):
            raise ParameterError("estimator.delay_s", f"{delay:g} s needs an estimator that smooths "
                                 f"with a delay (kalman); {req.estimator} is causal only")
        return req

    def subject_measured(self) -> tuple[str, ...]:
        """The segment lengths the user gave (custom anthropometry): measured, no spread."""
        size = self.body_size if isinstance(self.body_size, dict) else {}
        return tuple(d for d in ("forearm_length", "hand_length", "hand_breadth") if d in size)

    def settings_for(self, method: str) -> dict[str, float]:
        names = {s.name for s in ESTIMATORS[method].settings}
        return {k: x for k, x in self.estimator_settings if k in names}

    def com_or_default(self) -> tuple[float, ...] | None:
        """payload_com, or None (the core's default grasp point) when all zeros."""
        return None if not any(self.payload_com) else self.payload_com

    def build_kwargs(self) -> dict[str, Any]:
        """Keywords for build_model: only those that differ from their defaults."""
        kw: dict[str, Any] = {}
        if self.side != "right":
            kw["side"] = self.side
        if self.payload_mass != 0.0:
            kw["payload_mass"] = self.payload_mass
            kw["payload_com"] = self.com_or_default()
            if self.payload_inertia is not None:
                kw["payload_inertia"] = self.payload_inertia
        if self.placement:
            kw["placement"] = self.placement
        if self.split is not None:
            kw["split"] = self.split
        if self.shoulder != "none":
            kw["shoulder"] = self.shoulder
        return kw

    def same_estimator(self, other: ModelRequest) -> bool:
        return (self.estimator, self.settings_for(self.estimator)) == \
            (other.estimator, other.settings_for(other.estimator))


def _body_size_value(value: Any) -> Any:
    if isinstance(value, str) and value.strip().isdigit():
        return int(value.strip())
    return value


def _body_size_error(msg: str, custom: bool, value: Any) -> ParameterError:
    """resolve_body_size's message, in ROS parameters (no 'dict')."""
    if custom:
        if "needs body_mass" in msg:
            return ParameterError("body_mass", "custom anthropometry needs body_mass (kg) too")
        if "needs stature" in msg:
            return ParameterError("stature", "custom anthropometry needs stature (m), or all of "
                                  "forearm_length, hand_length and hand_breadth")
        culprit = next((d for d in DIMENSIONS if msg.startswith(d)), "body_mass")
        return ParameterError(culprit, msg)
    return ParameterError("body_size", f"{value!r} is not a body size: give 5, 50 or 95 (ANSUR II "
                          "men's percentiles), a string 'male_5' ... 'female_95', or set custom "
                          "anthropometry (body_mass, stature)")


@dataclass(frozen=True)
class ModelBundle:
    """Everything one sample is computed with; never modified once built (swapped whole)."""

    config_id: int
    request: ModelRequest
    arm: ArmModel
    model: pin.Model
    data: pin.Data
    estimator: StateEstimator
    model_config: dict  # the model part of the config message
    build_ms: float
    std: TorqueStd | None = None  # the torque σ, when asked for and the estimator has a covariance
    std_config: dict | None = None  # what the config message says about it

    def summary(self) -> str:
        """What the log lines say the node computes with: model, size, side, payload, estimator."""
        arm = self.arm
        payload = "empty hand" if arm.payload is None else f"payload {arm.payload.mass:g} kg"
        return (f"model {arm.kind}, body size {arm.body_size.label}, {arm.side} arm, {payload}, "
                f"estimator {self.request.estimator}")


def build_bundle(request: ModelRequest, config_id: int, n: int,
                 previous: ModelBundle | None = None, std: str | None = None) -> ModelBundle:
    """Build the model (and the estimator, unless its settings are unchanged: then the
    running one carries on with its history). ValueError if the core refuses.

    std: None = no σ asked for; else the topic the σ goes to: a TorqueStd is built when the
    estimator carries a covariance (it keeps the jerk history of the previous one when the
    estimator carries on), and `std_config` states it or why there is none."""
    t0 = time.perf_counter()
    arm = build_model(request.kind, request.body_size, **request.build_kwargs())
    if previous is not None and request.same_estimator(previous.request):
        est = previous.estimator
    else:
        est = make_estimator(request.estimator, n, request.settings_for(request.estimator))
    torque_std, std_config = None, {"published": False, "why": "publish_std is false"}
    if std is not None:
        try:
            torque_std = TorqueStd(arm, est, subject=request.subject_std,
                                   subject_measured=request.subject_measured()
                                   if request.subject_std != "none" else ())
        except NoCovariance as exc:
            std_config = {"published": False, "why": str(exc)}
        else:
            if previous is not None and previous.std is not None and previous.estimator is est:
                torque_std.jerk = previous.std.jerk
            std_config = {"published": True, "topic": std, **torque_std.parts()}
    ms = (time.perf_counter() - t0) * 1e3
    return ModelBundle(config_id, request, arm, arm.model, arm.data, est,
                       model_config(arm), ms, torque_std, std_config)
