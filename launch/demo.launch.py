"""What `make demo` does, as a launch file: the torque node and the recorder, the replay of
the 65 library movements at 1 kHz (trajectory_publisher, once it sees both listening), then
the nodes stopped (SIGINT) and the bag checked (check_bag: exit 0 = the data are right).

    ros2 launch forearm_dynamics demo.launch.py                 # ~100 s, all 65 movements
    ros2 launch forearm_dynamics demo.launch.py movements:=1,26,51 out:=/tmp/demo

The check's verdict is its last lines and its exit code (shown by launch as
"process has finished cleanly" or "process has died ... exit code 1"); its JSON report is
written beside the bag (check.json).
"""

import os
import signal
import sys
import time

from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    ExecuteProcess,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
)
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.events.process import SignalProcess
from launch_ros.actions import Node
from launch_ros.substitutions import ExecutableInPackage

from launch import LaunchDescription

PACKAGE = "forearm_dynamics"
QUIET_S = 2.0

#: Ends once joint_torques has been quiet for argv[1] s (a hang guard: 300 s at most).
SETTLE = """
import sys, time
import rclpy
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
quiet = float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("demo_wait_for_last_answers")
last = [None]  # the newest answer seen (monotonic s); from 1 s after the node was seen
node.create_subscription(JointState, "joint_torques", lambda m: last.__setitem__(0, time.monotonic()),
                         QoSProfile(depth=1000))
end = time.monotonic() + 300
while time.monotonic() < end and (last[0] is None or time.monotonic() - last[0] < quiet):
    rclpy.spin_once(node, timeout_sec=0.1)
    if last[0] is None and node.count_publishers("joint_torques"):
        last[0] = time.monotonic() + 1.0  # its writer seen: our reader is matched within ~1 s
node.destroy_node()
rclpy.try_shutdown()
"""


def movement_ids(text: str) -> list[int]:
    """'1,26,51' -> [1, 26, 51]; '' -> [] (all 65); anything else: one clear error."""
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"movements must be comma-separated movement ids (1-65), got {text!r}") from None


def setup(context) -> list:
    get = lambda name: context.launch_configurations[name]
    ids = movement_ids(get("movements"))
    out = os.path.abspath(os.path.join(get("out"), time.strftime("launch_%Y%m%d_%H%M%S")))
    os.makedirs(out, exist_ok=False)
    bag = os.path.join(out, "run.mcap")
    torque = Node(package=PACKAGE, executable="torque_node", output="screen", emulate_tty=True)
    recorder = Node(package=PACKAGE, executable="bag_recorder", parameters=[{"output": bag}],
                    output="screen", emulate_tty=True)
    replay = {"loop": False, "min_subscribers": 2, **({"movements": ids} if ids else {})}
    publisher = Node(package=PACKAGE, executable="trajectory_publisher", parameters=[replay],
                     output="screen", emulate_tty=True)
    settle = ExecuteProcess(cmd=[sys.executable, "-c", SETTLE, str(QUIET_S)], output="screen",
                            name="wait_for_last_answers")
    check = ExecuteProcess(
        cmd=[ExecutableInPackage("check_bag", PACKAGE), bag, "--json", os.path.join(out, "check.json")],
        output="screen", name="check_bag")

    def stop(action):  # SIGINT to one node, by its process (as `make demo` does, by PID)
        return EmitEvent(event=SignalProcess(signal_number=signal.SIGINT,
                                             process_matcher=lambda proc: proc is action))

    return [
        LogInfo(msg=f"demo: replaying {len(ids) or 65} movements; bag {bag}"),
        torque, recorder, publisher,
        # the replay is over: once the torque node has answered its last sample (its output
        # quiet for QUIET_S: a loaded machine may hold a backlog of a second or more), stop
        # both nodes
        RegisterEventHandler(OnProcessExit(target_action=publisher, on_exit=[settle])),
        RegisterEventHandler(OnProcessExit(target_action=settle, on_exit=[
            stop(torque), stop(recorder)])),
        # the bag is complete once the recorder has exited: check it
        RegisterEventHandler(OnProcessExit(target_action=recorder, on_exit=[check])),
        RegisterEventHandler(OnProcessExit(target_action=check, on_exit=[
            LogInfo(msg=f"demo: report {os.path.join(out, 'check.json')}"),
            EmitEvent(event=Shutdown(reason="demo finished"))])),
    ]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("movements", default_value="",
                              description="comma-separated movement ids, e.g. 1,26,51 ('' = all 65)"),
        DeclareLaunchArgument("out", default_value="demo_out",
                              description="directory for the run (a launch_<date>_<time> "
                              "folder: run.mcap, check.json)"),
        OpaqueFunction(function=setup),
    ])
