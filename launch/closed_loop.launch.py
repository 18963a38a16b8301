"""The virtual arm in closed loop (docs/virtual-arm.md): arm_sim (the arm, 1 kHz), the torque
node (feed-forward: inverse dynamics of the reference), trajectory_publisher (the reference
movements) and the example computed-torque controller (examples/closed_loop.py --attach,
installed beside this file). Prints each movement's tracking error; ends when the reference
has ended.

    ros2 launch forearm_dynamics closed_loop.launch.py movements:=1,26,51
"""

import os
import sys
import tempfile

from ament_index_python.packages import get_package_share_directory
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    ExecuteProcess,
    OpaqueFunction,
    RegisterEventHandler,
)
from launch.event_handlers import OnProcessExit, OnProcessIO
from launch.events import Shutdown
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "forearm_dynamics"
GAP_S = 0.3  # between two movements (the controller's tracking skips its hold)


def setup(context) -> list:
    from forearm_dynamics import JOINT_NAMES, get_movement  # the first movement's start posture

    get = lambda name: context.launch_configurations[name]
    try:
        ids = [int(x) for x in get("movements").split(",") if x.strip()]
        start = get_movement(ids[0]).start
    except (ValueError, IndexError) as exc:
        raise ValueError(f"movements must be comma-separated movement ids (1-65), "
                         f"got {get('movements')!r} ({exc})") from None
    out = get("out") or tempfile.mkdtemp(prefix="closed_loop_")
    posture = {f"initial_posture.{n}": float(x) for n, x in zip(JOINT_NAMES, start, strict=True)}
    arm_sim = Node(package=PACKAGE, executable="arm_sim", output="screen", emulate_tty=True,
                   parameters=[{**posture, "command_timeout": 0.5, "lockstep": False}])
    torque = Node(package=PACKAGE, executable="torque_node", output="screen", emulate_tty=True,
                  parameters=[{"input_topic": "reference/joint_states",
                               "output_topic": "reference/joint_torques", "estimator": "backward"}])
    publisher = Node(package=PACKAGE, executable="trajectory_publisher", output="screen",
                     emulate_tty=True, parameters=[{
                         "movements": ids, "output_topic": "reference/joint_states",
                         "start_delay": 0.5, "gap": GAP_S, "min_subscribers": 1, "loop": False}])
    script = os.path.join(get_package_share_directory(PACKAGE), "examples", "closed_loop.py")
    controller = ExecuteProcess(
        cmd=[sys.executable, script, "--attach", "--movements", ",".join(map(str, ids)), "--out", out]
        + (["--plot"] if get("plot") == "true" else []),
        output="screen", name="closed_loop_controller")

    def on_output(event):  # the controller is ready: the reference may start
        if b"closed_loop: ready" in event.text:
            return [publisher]
        return None

    return [arm_sim, torque, controller,
            RegisterEventHandler(OnProcessIO(target_action=controller, on_stdout=on_output)),
            RegisterEventHandler(OnProcessExit(target_action=controller, on_exit=[
                EmitEvent(event=Shutdown(reason="closed loop finished"))]))]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("movements", default_value="1,26,51",
                              description="comma-separated library movement ids (1-65) to track"),
        DeclareLaunchArgument("out", default_value="",
                              description="directory for results.json (and the plot); '' = a new "
                              "temporary directory"),
        DeclareLaunchArgument("plot", default_value="false", choices=["true", "false"],
                              description="draw reference vs simulated angles (closed_loop.png)"),
        OpaqueFunction(function=setup),
    ])
