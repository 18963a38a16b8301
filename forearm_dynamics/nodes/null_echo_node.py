"""null_echo_node: torque_node's pipeline without the dynamics, to benchmark ROS overhead.

Same subscription, QoS, validation and output message build (names in model order,
position/velocity copied, stamp and frame_id copied); effort is all zeros and an empty
input velocity is echoed as zeros. Compare its latency with torque_node's to see what
the inverse dynamics and estimation cost.
"""

from __future__ import annotations

from ..description import JOINT_NAMES
from .common import main_for
from .params import Params
from .stream_node import JointStreamNode


class NullEchoNode(JointStreamNode):
    """JointStreamNode whose compute() leaves effort at zero."""

    def __init__(self, node_name: str = "null_echo_node"):
        super().__init__(node_name)

    def configure(self, params: Params) -> tuple[str, ...]:  # noqa: ARG002 - the hook's signature
        return JOINT_NAMES

    def compute(self, t_ns: int, reset: bool, velocity_given: bool) -> bool:  # noqa: ARG002 - as above
        if not velocity_given:
            self.qd.fill(0.0)
        return True


def main() -> None:
    main_for(NullEchoNode, "null_echo_node")


if __name__ == "__main__":
    main()
