"""A minimal rclpy client: send one posture to torque_node, print the torques it answers.

    torque_node &                      # or: ros2 run forearm_dynamics torque_node
    python examples/torque_client.py   # same ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE

Publishes a sensor_msgs/JointState on `joint_states` (elbow at 90°, everything else at 0,
at rest) once torque_node subscribes, and prints the `joint_torques` message that carries the
same header stamp: at rest these are the gravity torques of that posture, in N·m.
"""

from __future__ import annotations

import math
import sys
import time

import rclpy
from sensor_msgs.msg import JointState

# the 20 joint names in model order (torque_node/config states them too)
from forearm_dynamics import JOINT_NAMES


def main(timeout_s: float = 30.0) -> int:
    rclpy.init()
    node = rclpy.create_node("torque_client")
    answers: list[JointState] = []
    sub = node.create_subscription(JointState, "joint_torques", answers.append, 10)
    pub = node.create_publisher(JointState, "joint_states", 10)
    try:
        # 1. wait until torque_node's subscription and publisher have matched ours
        deadline = time.monotonic() + timeout_s
        while pub.get_subscription_count() == 0 or sub.get_publisher_count() == 0:
            if time.monotonic() > deadline:
                print("no torque_node on joint_states/joint_torques (same ROS_DOMAIN_ID?)",
                      file=sys.stderr)
                return 1
            rclpy.spin_once(node, timeout_sec=0.1)
        # 2. publish one posture; its header stamp identifies the answer
        msg = JointState(name=list(JOINT_NAMES), position=[0.0] * len(JOINT_NAMES),
                         velocity=[0.0] * len(JOINT_NAMES))
        msg.position[JOINT_NAMES.index("elbow_flexion")] = math.pi / 2
        answer = None
        while answer is None and time.monotonic() < deadline:
            # a fresh stamp per try: discovery can match one side a moment before the other
            msg.header.stamp = node.get_clock().now().to_msg()
            pub.publish(msg)
            retry = time.monotonic() + 1.0
            while answer is None and time.monotonic() < retry:
                rclpy.spin_once(node, timeout_sec=0.05)
                answer = next((a for a in answers if a.header.stamp == msg.header.stamp), None)
        if answer is None:
            print("torque_node did not answer", file=sys.stderr)
            return 1
        # 3. print it: effort[i] is the torque of name[i], N·m
        print(f"torques for stamp {answer.header.stamp.sec}.{answer.header.stamp.nanosec:09d}:")
        for name, tau in zip(answer.name, answer.effort, strict=True):
            print(f"  {name:<22} {tau:+.6f} N·m")
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
