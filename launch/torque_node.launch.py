"""The torque node alone: joint_states -> joint_torques (docs/ros.md, "Launch files").

    ros2 launch forearm_dynamics torque_node.launch.py body_size:=95 side:=left
    ros2 launch forearm_dynamics torque_node.launch.py managed:=true   # then ros2 lifecycle set

An argument left empty ('') is not passed: the node's default applies (shown in each
argument's description, read from the installed config/nodes/torque_node.yaml, the one
source of the defaults), and so does a value given in params_file. A value the node
refuses is one error line from the node naming the parameter (exit code 2).
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "forearm_dynamics"

#: launch argument -> (node parameter, what it is, choices or None)
ARGUMENTS = {
    "model": ("model", "model kind", ("anatomical", "solid", "segmented")),
    "body_size": ("body_size", "ANSUR II percentile (5, 50, 95: men) or e.g. 'female_50'", None),
    "side": ("side", "which arm", ("right", "left")),
    "payload_mass": ("payload_mass", "mass held in the hand, kg (0 = empty hand)", None),
    "estimator": ("estimator", "velocity/acceleration estimator",
                  ("kalman", "backward", "butterworth", "savgol")),
    "delay": ("estimator.delay_s", ("output the fixed-lag smoothed estimate this far back, s "
                                    "(0 = causal)"), None),
    "missing_joints": ("missing_joints", ("a joint absent from the input: reject the message, "
                                          "or hold it at hold_posture"), ("reject", "hold")),
    "publish_std": ("publish_std", "also publish joint_torques_std (one sigma per torque)",
                    ("true", "false")),
    "output_rate_hz": ("output_rate_hz", ("0 = one output per input; > 0 = a timer at this "
                                          "rate, Hz"), None),
}


def node_defaults() -> dict:
    """The installed defaults (config/nodes/torque_node.yaml, section /**)."""
    try:
        path = os.path.join(get_package_share_directory(PACKAGE), "config", "nodes", "torque_node.yaml")
        with open(path, encoding="utf-8") as f:
            return (yaml.safe_load(f) or {}).get("/**", {}).get("ros__parameters", {})
    except Exception:  # noqa: BLE001 - only the descriptions lack the default then
        return {}


def declare() -> list:
    defaults = node_defaults()
    out = []
    for arg, (param, what, choices) in ARGUMENTS.items():
        shown = defaults.get(param, "see docs/nodes.md")
        out.append(DeclareLaunchArgument(
            arg, default_value="", choices=None if choices is None else ["", *choices],
            description=f"{what}; parameter {param}; '' = the node's default ({shown!r})"))
    out += [
        DeclareLaunchArgument("namespace", default_value="",
                              description="ROS namespace of the node and its topics ('' = none)"),
        DeclareLaunchArgument("node_name", default_value="torque_node", description="node name"),
        DeclareLaunchArgument("params_file", default_value="",
                              description="a ROS parameters YAML file (e.g. a copy of the installed "
                              "config/nodes/torque_node.yaml); the arguments above override it"),
        DeclareLaunchArgument("managed", default_value="false", choices=["true", "false"],
                              description="true: the lifecycle node torque_lifecycle_node (starts "
                              "unconfigured; ros2 lifecycle set <node> configure, activate)"),
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"],
                              description="the node's log level"),
    ]
    return out


def typed(text: str):
    """A launch argument's text as a ROS parameter value ('50' -> 50, 'true' -> True)."""
    value = yaml.safe_load(text)
    return value if isinstance(value, (bool, int, float)) else text


def make_node(context, *, name_suffix: str = "") -> list:
    get = lambda name: LaunchConfiguration(name).perform(context)
    params = []
    if get("params_file"):
        params.append(get("params_file"))
    given = {param: typed(get(arg)) for arg, (param, _, _) in ARGUMENTS.items() if get(arg) != ""}
    if given:
        params.append(given)
    managed = get("managed") == "true"
    return [Node(
        package=PACKAGE,
        executable="torque_lifecycle_node" if managed else "torque_node",
        name=get("node_name") + name_suffix,
        namespace=get("namespace"),
        parameters=params,
        ros_arguments=["--log-level", get("log_level")],
        output="screen",
        emulate_tty=True,
    )]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([*declare(), OpaqueFunction(function=make_node)])
