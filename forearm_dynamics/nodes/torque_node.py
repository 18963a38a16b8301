"""torque_node: joint_states -> joint_torques (inverse dynamics of the forearm-hand model).

Input  sensor_msgs/JointState on `joint_states`: names in any order (extra names ignored),
       position required, velocity optional (empty -> estimated from positions).
Output sensor_msgs/JointState on `joint_torques`: the model's 20 joints in joint_names
       order; position and velocity as used (velocity = the estimate when the input had
       none); effort = RNEA torques (N·m); header (stamp, frame_id) copied from the input.

Accelerations come from consecutive header stamps (estimation/backward.py: backward difference,
optional first-order low-pass). Lag: dt/2 (0.5 ms at 1 kHz) from given velocities, dt
(1 ms) from positions only, plus 1/(2 pi fc) per enabled low-pass. Warm-up: the first
sample after start or a reset is answered with qdd = 0 (and qd = 0 if estimated), counted
as `warmup_total` in /diagnostics; the second (third without velocities) is a real estimate.

Bad samples are dropped and counted per reason (validation.py); stamp jumps beyond
max_stamp_gap reset the estimator (stream_node.py). The model is stated once, latched,
on `torque_node/config` (JSON) so a bag records which model ran. Parameters are read at
start-up only (config/torque_node.yaml); an invalid one -> one error line, exit code 2.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pinocchio as pin
from std_msgs.msg import String

from ..anthropometry import DIMENSIONS, resolve_body_size
from ..builders import MODEL_KINDS
from ..description import load_description
from ..dynamics import ArmModel, build_model
from ..estimation import make_estimator
from . import validation as v
from .common import CONFIG_TOPIC, latched_qos, main_for, package_version
from .params import ParameterError, Params, Spec
from .stream_node import STREAM_SPECS, JointStreamNode

MODEL_SPECS = (
    Spec("model", "segmented", "model kind: segmented, solid or anatomical"),
    Spec("body_size", 50, "ANSUR II percentile 5, 50 or 95 (ignored with custom anthropometry)"),
    *(Spec(d, 0.0, f"custom anthropometry: {d} (m or kg); 0 = unused") for d in DIMENSIONS),
    Spec("split", -1.0, "segmented model split fraction in [0, 1]; -1 = config/model.yaml"),
    Spec("estimator.accel_cutoff_hz", 0.0, "first-order low-pass on qdd (Hz); 0 = off"),
    Spec("estimator.velocity_cutoff_hz", 0.0, "low-pass on qd estimated from positions; 0 = off"),
)


def _model_from_params(p: Params) -> tuple[ArmModel, float | None]:
    """Build the model the parameters ask for; ParameterError names the culprit."""
    kind = p.string("model", MODEL_KINDS)
    percentile = p.integer("body_size")
    dims = {d: p.number(d, 0.0) for d in DIMENSIONS}
    custom = {d: x for d, x in dims.items() if x > 0.0}
    try:
        size = resolve_body_size(custom or percentile)
    except ValueError as exc:
        culprit = next((d for d in DIMENSIONS if d in str(exc)), "body_mass") if custom else "body_size"
        raise ParameterError(culprit, str(exc)) from None
    split = p.number("split")
    overrides = {} if split == -1.0 else {"split": split}
    try:
        return build_model(kind, size, **overrides), overrides.get("split")
    except ValueError as exc:
        raise ParameterError("split" if overrides else "model", str(exc)) from None


def model_config(model: ArmModel, split: float | None) -> dict:
    """What a bag needs to know about the model that produced the torques."""
    size = model.body_size
    simplified = None
    if model.kind != "anatomical":
        s = load_description().simplified
        default_split = 0.0 if model.kind == "solid" else s.split
        simplified = {
            "split": default_split if split is None else split,
            "axis_offset_proximal": s.axis_offset_proximal.tolist(),
            "axis_offset_distal": s.axis_offset_distal.tolist(),
        }
    return {
        "model": model.kind,
        "body_size": {
            "label": size.label,
            "forearm": size.forearm,
            "hand_length": size.hand_length,
            "hand_breadth": size.hand_breadth,
            "mass": size.mass,
        },
        "simplified": simplified,
        "joint_names": list(model.joint_names),
    }


class TorqueNode(JointStreamNode):
    """Inverse dynamics per sample: pin.rnea on preallocated q, qd, qdd."""

    specs = (*STREAM_SPECS, *MODEL_SPECS)

    def __init__(self, node_name: str = "torque_node"):
        super().__init__(node_name)
        self.config_pub = self.create_publisher(String, CONFIG_TOPIC, latched_qos())
        info = {
            "node": self.get_fully_qualified_name(),
            "version": package_version(),
            **model_config(self.arm, self._split),
            "estimator": self.estimator.describe(1e-3),
            "input_topic": self.sub.topic_name,
            "output_topic": self.pub.topic_name,
            "max_stamp_gap": self.settings.max_stamp_gap,
        }
        self.config_pub.publish(String(data=json.dumps(info)))
        self.get_logger().info(
            f"model {self.arm.kind}, body size {self.arm.body_size.label}; "
            f"config on {self.config_pub.topic_name}"
        )

    def configure(self, params: Params) -> tuple[str, ...]:
        self.arm, self._split = _model_from_params(params)
        self.estimator = make_estimator("backward", self.arm.nv, {
            "accel_cutoff_hz": params.number("estimator.accel_cutoff_hz", 0.0, 1e6),
            "velocity_cutoff_hz": params.number("estimator.velocity_cutoff_hz", 0.0, 1e6),
        })
        self._pin_model, self._pin_data = self.arm.model, self.arm.data
        return self.arm.joint_names

    def compute(self, t_ns: int, reset: bool, velocity_given: bool) -> bool:
        est = self.estimator
        if reset:
            est.reset()
        warm = est.update(t_ns, self.q, self.qd if velocity_given else None)
        if not velocity_given:
            np.copyto(self.qd, est.qd)
        tau = pin.rnea(self._pin_model, self._pin_data, self.q, self.qd, est.qdd)
        if not math.isfinite(tau.sum()):
            est.reset()  # it has taken in the absurd sample: the next one starts afresh
            raise v.Rejection(v.NON_FINITE_TORQUE, "torque overflowed (absurd inputs?)")
        np.copyto(self.effort, tau)
        return warm


def main() -> None:
    main_for(TorqueNode, "torque_node")


if __name__ == "__main__":
    main()
