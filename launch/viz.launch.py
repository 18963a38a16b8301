"""The viewer: arm_viz draws the arm, posed and coloured by joint_torques, as a MarkerArray
(arm_markers) for RViz2 or Foxglove, and publishes robot_description (docs/visualisation.md).

    ros2 launch forearm_dynamics viz.launch.py arrows:=true
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "forearm_dynamics"


def typed(text: str):
    """'30' -> 30.0; anything else is passed as given and refused by the node in one line."""
    try:
        return float(text)
    except ValueError:
        return text


def viewer(context) -> list:
    get = lambda name: LaunchConfiguration(name).perform(context)
    params = {"rate_hz": typed(get("rate_hz")), "arrows": get("arrows") == "true"}
    if get("torque_topic"):
        params["torque_topic"] = get("torque_topic")
    return [Node(package=PACKAGE, executable="arm_viz", namespace=get("namespace"),
                 parameters=[params], output="screen", emulate_tty=True)]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="",
                              description="ROS namespace of the viewer and its topics ('' = none)"),
        DeclareLaunchArgument("rate_hz", default_value="30.0",
                              description="marker publication rate, Hz"),
        DeclareLaunchArgument("arrows", default_value="false", choices=["true", "false"],
                              description="also draw one arrow per joint, length |torque|"),
        DeclareLaunchArgument("torque_topic", default_value="",
                              description="JointState torques to draw ('' = joint_torques)"),
        OpaqueFunction(function=viewer),
    ])
