"""arm_viz: the arm and its torques as markers, for RViz and Foxglove, without TF.

    ros2 run forearm_dynamics arm_viz [--ros-args -p arrows:=true]

Subscribes `joint_torques` (the torque node's output: position and effort by joint name)
and the torque node's latched config topic; publishes, at rate_hz (30), `arm_markers`
(visualization_msgs/MarkerArray: every massive link as its URDF visual solid, ns = the
link's name, posed by forward kinematics in the URDF root frame and coloured by the
|torque| of the joint that moves it: viridis over |torque| / the DOF group's full scale,
viz/colors.py) and, latched, `robot_description` (the URDF of the model drawn).

The model is the torque node's, read from its config message and followed through every
live change (body size, side, payload ...); until one arrives, or with config_topic '',
this node's own model parameters (the torque node's definitions, config/nodes/arm_viz.yaml).
A separate process, so the 1 kHz torque path is untouched: the joint_torques subscription
only keeps the newest message's bytes (no decoding at 1 kHz); the timer decodes one, runs
forward kinematics and publishes CDR bytes made by viz/marker_cdr.py.

Muscles (issue 31): while muscle_node answers on `muscle_topic` (muscle_forces) within 0.5 s
of the torques drawn, the forearm's links are coloured by the activation of its strongest
forearm muscle instead of their joints' torques (viridis over 0..1), and a label
"<muscle> <activation>" (TEXT_VIEW_FACING, ns muscle/strongest) is drawn beside them
(viz/muscles.py).

Bad input (a config that cannot be built, torques without the model's joints): one warning
line naming it, and the node carries on with what it had.
"""

from __future__ import annotations

import json

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from ..codec.jointstate import MuscleReader, TorqueReader
from ..dynamics import ArmModel
from ..model_config import model_from_config
from ..viz import ArmScene, MarkerMaker, TorqueColours
from ..viz.marker_cdr import marker_array_cdr
from ..viz.muscles import MAX_SKEW_NS, strongest
from .arm_viz_settings import LIVE_VIEW, MODEL_NAMES, SPECS, ArmVizSettings, own_model, view_values
from .common import latched_qos, main_for, stream_qos
from .params import ParameterError, Params, init_node


class ArmVizNode(Node):
    def __init__(self):
        init_node(self, "arm_viz")
        self.params = Params(self, SPECS, "arm_viz")
        self.settings = ArmVizSettings.from_params(self.params)
        self.params.warn_unknown()
        s = self.settings
        self._torques = TorqueReader()
        self._published_seq = 0
        self._warned: set[str] = set()
        self._config_text: str | None = None  # the model part of the torque node's config
        self.source = "own parameters"
        self.arrays = 0
        self.markers_pub = self.create_publisher(MarkerArray, s.markers_topic, stream_qos(10))
        self.description_pub = self.create_publisher(String, s.description_topic, latched_qos())
        self._view = view_values(self.params.values(LIVE_VIEW))
        self._use(own_model(self.params.values(MODEL_NAMES)), "own parameters")
        # Best effort, depth 1: only the newest torques are drawn, and a best-effort reader
        # asks nothing of the torque node's writer (no acknowledgements, no resends).
        self.create_subscription(JointState, s.torque_topic, self._torques.keep,
                                 stream_qos(1, reliable=False), raw=True)
        if s.config_topic:
            self.create_subscription(String, s.config_topic, self._on_config, latched_qos())
        self._muscles = MuscleReader()
        if s.muscle_topic:  # as the torques: the newest message's bytes, best effort
            self.create_subscription(JointState, s.muscle_topic, self._muscles.keep,
                                     stream_qos(1, reliable=False), raw=True)
        self.add_on_set_parameters_callback(self._on_set)
        self.create_timer(1.0 / s.rate_hz, self._tick)
        self.get_logger().info(
            f"arm_viz: {s.torque_topic} -> {self.markers_pub.topic_name} at {s.rate_hz:g} Hz in "
            f"frame '{self.frame_id}'; model {self.arm.kind}, {self.arm.side} arm, body size "
            f"{self.arm.body_size.label} ({self.source})"
            + (f"; following {s.config_topic}" if s.config_topic else ""))

    # -- the model drawn ------------------------------------------------------------------
    def _use(self, arm: ArmModel, source: str) -> None:
        arrows, arrow_scale, alpha, full_scale = self._view
        self.arm, self.source = arm, source
        self.scene = ArmScene(arm)
        self.maker = MarkerMaker(self.scene, TorqueColours(arm.joint_names, full_scale),
                                 arrows=arrows, arrow_scale=arrow_scale, alpha=alpha)
        self.frame_id = self.settings.frame_id or self.scene.root_frame
        self._delete_all = True  # the first array of a model clears what another drew
        self.description_pub.publish(String(data=arm.to_urdf()))

    def _on_config(self, msg: String) -> None:
        try:
            cfg = json.loads(msg.data)
            model_part = json.dumps({k: cfg[k] for k in sorted(cfg)
                                     if k in ("model", "body_size", "side", "payload",
                                              "placement", "joint_names", "schema")})
            if model_part == self._config_text:
                return  # a periodic repeat, or an estimator-only change
            arm = model_from_config(cfg).arm
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            self._warn("config", f"ignoring a config message on {self.settings.config_topic} "
                       f"({str(exc).splitlines()[0]}); still drawing {self.arm!r}")
            return
        self._config_text = model_part
        self._use(arm, self.settings.config_topic)
        self.get_logger().info(f"drawing {arm.kind}, {arm.side} arm, body size "
                               f"{arm.body_size.label}"
                               + (f", payload {arm.payload.mass:g} kg" if arm.payload else "")
                               + f" (from {self.settings.config_topic})")

    def _on_set(self, params) -> SetParametersResult:
        changed = {p.name: p.value for p in params}
        if not set(changed) & (set(MODEL_NAMES) | LIVE_VIEW):
            return SetParametersResult(successful=True)
        values = {**self.params.values(MODEL_NAMES), **self.params.values(LIVE_VIEW), **changed}
        for name, value in changed.items():
            why = self.params.specs[name].check(value) if name in self.params.specs else None
            if why:
                return SetParametersResult(successful=False, reason=f"{name}: {why}")
        try:
            view = view_values(values)
            TorqueColours(self.arm.joint_names, view[3])
            arm = own_model({k: values[k] for k in MODEL_NAMES}) \
                if set(changed) & set(MODEL_NAMES) else None
        except (ParameterError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self._view = view
        if arm is not None and self._config_text is None:
            self._use(arm, "own parameters")
        else:  # view settings, or own model parameters while a torque node's config rules
            self._use(self.arm, self.source)
        return SetParametersResult(successful=True)

    # -- output ---------------------------------------------------------------------------
    def _warn(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def _strongest(self, stamp: int) -> tuple[str, float] | None:
        """The forearm's strongest muscle at about `stamp` (muscle_forces), or None."""
        if self._muscles.data is None:
            return None
        try:
            m_stamp, names, a = self._muscles.decode()
            if abs(m_stamp - stamp) > MAX_SKEW_NS:
                return None
            return strongest(names, a)
        except ValueError as exc:
            self._warn("muscles", f"not colouring by muscle_forces: {exc}")
            return None

    def _tick(self) -> None:
        t = self._torques
        if t.data is None or t.seq == self._published_seq:
            return
        self._published_seq = t.seq
        try:
            stamp, q, tau = t.decode(self.arm.joint_names)
            frame = self.maker.frame(q, tau, self._strongest(stamp))
        except ValueError as exc:
            self._warn("torques", f"not drawing joint_torques: {exc}")
            return
        self.markers_pub.publish(marker_array_cdr(frame, self.frame_id, stamp, self._delete_all))
        self._delete_all = False
        self.arrays += 1


def main() -> None:
    main_for(ArmVizNode, "arm_viz")


if __name__ == "__main__":
    main()
