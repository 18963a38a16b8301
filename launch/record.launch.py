"""The torque node and the recorder: everything on the graph that matters into one MCAP file.

    ros2 launch forearm_dynamics record.launch.py output:=session1.mcap body_size:=95

The torque node's arguments are those of torque_node.launch.py (included). The recorder
(bag_recorder) writes joint_states, joint_torques, movement, /diagnostics and the torque
node's config; SIGINT to `ros2 launch` (Ctrl-C) stops both, the file complete.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, OpaqueFunction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "forearm_dynamics"


def recorder(context) -> list:
    get = lambda name: LaunchConfiguration(name).perform(context)
    params = {"output": get("output")} if get("output") else {}
    return [Node(package=PACKAGE, executable="bag_recorder", namespace=get("namespace"),
                 parameters=[params], output="screen", emulate_tty=True)]


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory(PACKAGE)
    return LaunchDescription([
        DeclareLaunchArgument("output", default_value="",
                              description="MCAP file to create ('' = forearm_<date>_<time>.mcap in "
                              "the working directory); an existing file is never overwritten"),
        IncludeLaunchDescription(PythonLaunchDescriptionSource(
            os.path.join(share, "launch", "torque_node.launch.py"))),
        OpaqueFunction(function=recorder),
    ])
