"""Robot models: URDF/SRDF -> pinocchio model with limits, feet and arm end-effector."""

from wbmpc.robots.model import (
    GRAVITY_M_S2,
    JointValues,
    RobotModel,
    RobotSpec,
    joint_values,
)
from wbmpc.robots.presets import PRESET_NAMES, custom_spec, load_robot, preset_spec

__all__ = [
    "GRAVITY_M_S2", "PRESET_NAMES", "JointValues", "RobotModel", "RobotSpec", "custom_spec", "joint_values", "load_robot",
    "preset_spec",
]  # fmt: skip
