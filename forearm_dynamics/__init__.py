"""forearm_dynamics: hand-and-forearm inverse dynamics (segmented forearm model)."""

from .description import DOF_GROUPS, JOINT_NAMES, SIGN_CONVENTIONS
from .dynamics import ArmModel, build_model
from .movements import Movement, get_movement, movement_library

__all__ = [
    "DOF_GROUPS",
    "JOINT_NAMES",
    "SIGN_CONVENTIONS",
    "ArmModel",
    "Movement",
    "build_model",
    "get_movement",
    "movement_library",
]
