"""What a viewer draws of the arm, without ROS: link shapes posed by forward kinematics,
coloured by joint torque. nodes/arm_viz.py and cli/bag_viz.py turn these into MarkerArrays."""

from .colors import TorqueColours, library_peaks
from .markers import MarkerFrame, MarkerMaker
from .scene import ArmScene, LinkShape, PosedShape

__all__ = [
           "ArmScene",
           "LinkShape",
           "MarkerFrame",
           "MarkerMaker",
           "PosedShape",
           "TorqueColours",
           "foxglove_layout",
           "library_peaks",
]
