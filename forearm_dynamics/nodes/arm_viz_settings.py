"""arm_viz's parameters: the torque node's model parameters (imported, not copied: used
until a torque node states its model on its config topic) and the viewer's own."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from ..dynamics import ArmModel, build_model
from ..estimation import DEFAULT_ESTIMATOR
from ..viz.colors import GROUPS
from .params import ParameterError, Params, Spec
from .torque_config import MODEL_SPECS, TORQUE_STD_ONLY, ModelRequest

#: torque_node's model parameters, one definition (estimator settings aside: no estimator
#: here). Live: a change rebuilds the drawn arm, unless a torque node's config is in force.
VIZ_MODEL_SPECS = tuple(replace(s, live=True) for s in MODEL_SPECS
                        if not s.name.startswith("estimator") and s.name not in TORQUE_STD_ONLY)
MODEL_NAMES = tuple(s.name for s in VIZ_MODEL_SPECS)

VIEW_SPECS = (
    Spec("rate_hz", 30.0, "marker publication rate (one MarkerArray per tick, from the newest "
         "joint_torques; none while no new one arrived)", "Hz", 0.1, 1000.0),
    Spec("torque_topic", "joint_torques", "JointState input: position (rad) and effort (N*m) "
         "by joint name, as torque_node publishes them"),
    Spec("config_topic", "torque_node/config", "the torque node's config topic (JSON, latched): "
         "its model, side, body size and payload replace this node's own model parameters, "
         "following every live change; '' = never listen"),
    Spec("muscle_topic", "muscle_forces", "muscle_node's JointState output (name = muscles, "
         "position = activation): while it answers torques within 0.5 s of those drawn, the "
         "forearm's links are coloured by its strongest forearm muscle's activation (viridis, "
         "0..1) and a label '<muscle> <activation>' is drawn beside them (ns muscle/strongest); "
         "'' = never listen"),
    Spec("markers_topic", "arm_markers", "visualization_msgs/MarkerArray output: one marker per "
         "massive link (ns = link name) and optional torque arrows (ns = torque/<joint>)"),
    Spec("description_topic", "robot_description", "std_msgs/String output (transient local): "
         "the URDF of the model drawn, for robot_state_publisher and RViz"),
    Spec("frame_id", "", "frame of every marker; '' = the URDF root link (the humerus, fixed in "
         "the world): poses come from forward kinematics, not from TF"),
    Spec("arrows", False, "also draw one arrow per joint along its axis, length |torque| x "
         "arrow_scale, pointing along +axis for a positive torque", live=True),
    Spec("arrow_scale", 0.05, "arrow length per unit torque", "m/(N*m)", 0.0, 100.0, live=True),
    Spec("alpha", 1.0, "opacity of the link markers", "", 0.0, 1.0, live=True),
    *(Spec(f"color_full_scale.{g}", 0.0, f"|torque| drawn at the top of the colour scale "
           f"(viridis yellow) for the {g} joints; 0 = the movement library's peak for the group",
           "N*m", 0.0, 1000.0, live=True) for g in GROUPS),
)

SPECS = (*VIZ_MODEL_SPECS, *VIEW_SPECS)
LIVE_VIEW = frozenset(s.name for s in VIEW_SPECS if s.live)


def own_model(values: dict[str, Any]) -> ArmModel:
    """The model of this node's own model parameters (ParameterError naming the problem)."""
    values = {**values, "estimator": DEFAULT_ESTIMATOR}  # ModelRequest's other half: unused
    req = ModelRequest.from_values(values)
    try:
        return build_model(req.kind, req.body_size, **req.build_kwargs())
    except ValueError as exc:
        raise ParameterError("model", str(exc)) from None


@dataclass(frozen=True)
class ArmVizSettings:
    rate_hz: float
    torque_topic: str
    config_topic: str
    muscle_topic: str
    markers_topic: str
    description_topic: str
    frame_id: str
    arrows: bool
    arrow_scale: float
    alpha: float
    full_scale: dict[str, float]

    @classmethod
    def from_params(cls, p: Params) -> ArmVizSettings:
        topics = ["torque_topic", "markers_topic", "description_topic"]
        for optional in ("config_topic", "muscle_topic"):
            if p.value(optional):
                topics.append(optional)
        s = cls(p.value("rate_hz"), p.topic("torque_topic"),
                p.topic("config_topic") if p.value("config_topic") else "",
                p.topic("muscle_topic") if p.value("muscle_topic") else "",
                p.topic("markers_topic"), p.topic("description_topic"), p.value("frame_id"),
                *view_values(p.values(LIVE_VIEW)))
        p.distinct_topics(topics)
        return s


def view_values(v: dict[str, Any]) -> tuple[bool, float, float, dict[str, float]]:
    return (bool(v["arrows"]), float(v["arrow_scale"]), float(v["alpha"]),
            {g: float(v[f"color_full_scale.{g}"]) for g in GROUPS})
