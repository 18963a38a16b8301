"""forearm_dynamics: hand-and-forearm inverse dynamics (segmented forearm model)."""

from .description import DOF_GROUPS, JOINT_NAMES, SIGN_CONVENTIONS
from .dynamics import ArmModel, build_model

__all__ = ["DOF_GROUPS", "JOINT_NAMES", "SIGN_CONVENTIONS", "ArmModel", "build_model"]
