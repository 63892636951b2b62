"""Which LowCmd/LowState motor slot drives which joint of the model.

Unitree quadrupeds (Go1/Go2/B1/B2, `unitree_go` messages, 20 motor slots) number the leg motors
FR hip, thigh, calf = 0, 1, 2; FL = 3, 4, 5; RR = 6, 7, 8; RL = 9, 10, 11 (the SDK's
`LegID`). wbmpc's models order legs FL, FR, RL, RR, so the map is not the identity.

Arm mapping (our definition): arm joints, in `robot.joint_names` order, take slots 12, 13, ...
(slots 12-19 are unused on the quadruped). In `wbmpc robot-sim` they are simulated behind the same
topics. On a real B1 + Z1 the Z1 is a separate robot driven by its own UDP SDK (z1_sdk, not on
PyPI): a bridge on the robot forwards slots 12.. of LowCmd to the Z1's joint commands (q, dq, kp,
kd, tau are the same motor law) and fills the Z1's joint states into the same slots of LowState.

A motor is present in LowState when its temperature is reported (> 0 C); an absent slot reads 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.hardware.crc import N_MOTOR_SLOTS
from wbmpc.robots import RobotModel

UNITREE_LEG_SLOTS = {"FR": 0, "FL": 3, "RR": 6, "RL": 9}
_LEG_PARTS = ("hip", "thigh", "calf")
FIRST_ARM_SLOT = 12


@dataclass(frozen=True)
class MotorMap:
    """`slots[j]`: the motor slot of joint j (`robot.joint_names` order)."""

    joint_names: tuple[str, ...]
    slots: tuple[int, ...]

    @property
    def n_motors(self) -> int:
        return len(self.slots)

    def slot_array(self) -> np.ndarray:
        return np.array(self.slots, dtype=int)

    def describe(self) -> str:
        return ", ".join(f"{name}->{slot}" for name, slot in zip(self.joint_names, self.slots))


def unitree_motor_map(robot: RobotModel) -> MotorMap:
    """The map for a Unitree-named quadruped (joints `FL_hip_joint`, ...) with an optional arm."""
    slots = []
    next_arm = FIRST_ARM_SLOT
    for name, is_leg in zip(robot.joint_names, robot.leg_joint_mask):
        if is_leg:
            leg, _, part = name.partition("_")
            part = part.replace("_joint", "")
            if leg not in UNITREE_LEG_SLOTS or part not in _LEG_PARTS:
                raise ConfigError(f"leg joint '{name}' is not named like a Unitree leg joint (FR/FL/RR/RL + "
                                  f"_hip/_thigh/_calf_joint); the Unitree motor map cannot place it")
            slots.append(UNITREE_LEG_SLOTS[leg] + _LEG_PARTS.index(part))
        else:
            slots.append(next_arm)
            next_arm += 1
    if max(slots) >= N_MOTOR_SLOTS:
        raise ConfigError(f"{robot.name} needs {max(slots) + 1} motor slots; unitree_go messages carry {N_MOTOR_SLOTS}")
    if len(set(slots)) != len(slots):
        raise ConfigError(f"two joints of {robot.name} map to the same motor slot: {slots}")
    return MotorMap(tuple(robot.joint_names), tuple(slots))
