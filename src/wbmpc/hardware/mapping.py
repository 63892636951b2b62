"""Which LowCmd/LowState motor slot drives which joint of the model.

Unitree quadrupeds (Go1/Go2/B1/B2, `unitree_go` messages, 20 motor slots) number the leg motors
FR hip, thigh, calf = 0, 1, 2; FL = 3, 4, 5; RR = 6, 7, 8; RL = 9, 10, 11 (the SDK's
`LegID`). wbmpc's models order legs FL, FR, RL, RR, so the map is not the identity.

A Unitree Z1 arm (joints named as in its URDF: joint1..joint6, jointGripper) is not on the LowCmd
bus: it has its own controller, driven over UDP (`wbmpc.hardware.z1_udp`); `z1_arm_map` says which
model joint is which Z1 joint and holds the joints the model locks at their reference. Other arms
(not Unitree's) take slots 12, 13, ... in `robot.joint_names` order, a convention of `wbmpc
robot-sim` only: no Unitree robot forwards those slots to an arm.

Unitree humanoids (G1, `unitree_hg` messages, 35 motor slots) number their motors in the order of
Unitree's G1 documentation (`G1_MOTOR_ORDER`, the 29-DoF G1; joints named as in Unitree's G1 URDF and
MJCF): legs left then right (hip pitch, roll, yaw, knee, ankle pitch, roll: 0-11), waist yaw, roll,
pitch (12-14), arms left then right (shoulder pitch, roll, yaw, elbow, wrist roll, pitch, yaw: 15-28),
the ankle and waist joints in pitch/roll (`mode_pr` PR) coordinates. Motors whose joints the model locks
(g1's wrists) are `held`: commanded to the locked reference, reported there by robot-sim.

A motor is present in LowState when its temperature is reported (> 0 C); an absent slot reads 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.hardware.crc import N_HG_MOTOR_SLOTS, N_MOTOR_SLOTS
from wbmpc.hardware.z1_messages import N_Z1_JOINTS, Z1_JOINT_NAMES
from wbmpc.robots import RobotModel

UNITREE_LEG_SLOTS = {"FR": 0, "FL": 3, "RR": 6, "RL": 9}
_LEG_PARTS = ("hip", "thigh", "calf")
FIRST_ARM_SLOT = 12
_G1_LEG = ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
_G1_ARM = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw")
G1_MOTOR_ORDER = tuple([f"{side}_{j}_joint" for side in ("left", "right") for j in _G1_LEG]
                       + [f"waist_{j}_joint" for j in ("yaw", "roll", "pitch")]
                       + [f"{side}_{j}_joint" for side in ("left", "right") for j in _G1_ARM])  # slots 0-28
G1_MODE_MACHINE = 5  # the mode_machine a 29-DoF G1 (rev 1.0) reports, as its users publish it (robot-sim's)


@dataclass(frozen=True)
class HeldMotor:
    """A motor whose joint the model locks: held at the model's reference `q_rad` (effort limit `tau_max_nm`)."""

    slot: int
    joint_name: str
    q_rad: float
    tau_max_nm: float


@dataclass(frozen=True)
class MotorMap:
    """`slots[j]`: the motor slot of joint j (`robot.joint_names` order) in `family`'s messages; `held`: motors
    of joints the model locks."""

    joint_names: tuple[str, ...]
    slots: tuple[int, ...]
    family: str = "unitree_go"
    held: tuple[HeldMotor, ...] = ()

    @property
    def n_motors(self) -> int:
        return len(self.slots)

    @property
    def n_slots(self) -> int:
        return N_HG_MOTOR_SLOTS if self.family == "unitree_hg" else N_MOTOR_SLOTS

    @property
    def held_slots(self) -> tuple[int, ...]:
        return tuple(h.slot for h in self.held)

    @property
    def robot_slots(self) -> tuple[int, ...]:
        """Every motor the robot must report: the model's and the held ones."""
        return self.slots + self.held_slots

    def slot_array(self) -> np.ndarray:
        return np.array(self.slots, dtype=int)

    def slot_name(self, slot: int) -> str:
        """Unitree's joint name of a motor slot (e.g. unitree_go 3 -> FL_hip_joint), or `slot N`."""
        if self.family == "unitree_hg":
            return G1_MOTOR_ORDER[slot] if slot < len(G1_MOTOR_ORDER) else f"slot {slot}"
        return slot_joint_name(slot)

    def describe(self) -> str:
        held = "".join(f", {h.joint_name}->{h.slot} (held {h.q_rad:.2f} rad)" for h in self.held)
        return f"{self.family}: " + ", ".join(f"{n}->{s}" for n, s in zip(self.joint_names, self.slots)) + held


def unitree_motor_map(robot: RobotModel) -> MotorMap:
    """The LowCmd map of a Unitree-named robot: a G1 (joints named as `G1_MOTOR_ORDER`) on unitree_hg, else a
    quadruped (joints `FL_hip_joint`, ...) on unitree_go: its legs, and the joints of an arm that is not a Z1
    (a robot-sim convention, see the module's docstring)."""
    if is_g1(robot):
        return g1_motor_map(robot)
    slots, names = [], []
    next_arm = FIRST_ARM_SLOT
    z1 = has_z1_arm(robot)
    for name, is_leg in zip(robot.joint_names, robot.leg_joint_mask):
        if not is_leg and z1:
            continue
        names.append(name)
        if is_leg:
            leg, _, part = name.partition("_")
            part = part.replace("_joint", "")
            if leg not in UNITREE_LEG_SLOTS or part not in _LEG_PARTS:
                raise ConfigError(f"leg joint '{name}' is not named like a Unitree leg joint (quadrupeds: FR/FL/RR/RL + "
                                  "_hip/_thigh/_calf_joint; G1: left/right_hip_pitch_joint, ...); the Unitree motor "
                                  "map cannot place it")
            slots.append(UNITREE_LEG_SLOTS[leg] + _LEG_PARTS.index(part))
        else:
            slots.append(next_arm)
            next_arm += 1
    if slots and max(slots) >= N_MOTOR_SLOTS:
        raise ConfigError(f"{robot.name} needs {max(slots) + 1} motor slots; unitree_go messages carry {N_MOTOR_SLOTS}")
    if len(set(slots)) != len(slots):
        raise ConfigError(f"two joints of {robot.name} map to the same motor slot: {slots}")
    return MotorMap(tuple(names), tuple(slots))


def is_g1(robot: RobotModel) -> bool:
    """Every joint of the model, locked ones included, is one of G1's motors."""
    names = set(robot.joint_names) | set(robot.spec.locked_joints)
    return bool(robot.joint_names) and names <= set(G1_MOTOR_ORDER)


def g1_motor_map(robot: RobotModel) -> MotorMap:
    """G1 on unitree_hg: each model joint on its slot of `G1_MOTOR_ORDER`, locked joints held at their reference."""
    if not is_g1(robot):
        other = sorted((set(robot.joint_names) | set(robot.spec.locked_joints)) - set(G1_MOTOR_ORDER))
        raise ConfigError(f"{robot.name}: joints {', '.join(other)} are not G1 motors ({', '.join(G1_MOTOR_ORDER)})")
    slots = tuple(G1_MOTOR_ORDER.index(n) for n in robot.joint_names)
    held = tuple(HeldMotor(G1_MOTOR_ORDER.index(name), name, q, tau) for name, q, tau in _locked_joints(robot))
    return MotorMap(tuple(robot.joint_names), slots, "unitree_hg", held)


def slot_joint_name(slot: int) -> str:
    """The Unitree name of a leg motor slot (e.g. 3 -> FL_hip_joint), or `slot N` beyond the legs."""
    for leg, first in UNITREE_LEG_SLOTS.items():
        if first <= slot < first + 3:
            return f"{leg}_{_LEG_PARTS[slot - first]}_joint"
    return f"slot {slot}"


def has_z1_arm(robot: RobotModel) -> bool:
    """The model's arm joints are Z1 joints (its URDF names)."""
    arm = [n for n, leg in zip(robot.joint_names, robot.leg_joint_mask) if not leg]
    return bool(arm) and all(n in Z1_JOINT_NAMES for n in arm)


@dataclass(frozen=True)
class Z1ArmMap:
    """Z1 joint k (0-5: joints 1-6, 6: gripper) is model joint `model_index[k]` (index into
    `robot.joint_names`), or locked in the model (-1) and held at `locked_position_rad[k]`."""

    model_index: tuple[int, ...]
    locked_position_rad: tuple[float, ...]

    @property
    def driven(self) -> np.ndarray:
        return np.array(self.model_index) >= 0

    def describe(self) -> str:
        return ", ".join(f"{name}->{'model' if i >= 0 else 'held %.2f rad' % self.locked_position_rad[k]}"
                         for k, (name, i) in enumerate(zip(Z1_JOINT_NAMES, self.model_index)))


def z1_arm_map(robot: RobotModel) -> Z1ArmMap:
    """The Z1 joints of `robot`: driven by the MPC where the model has them, held where the model locks them."""
    if not has_z1_arm(robot):
        raise ConfigError(f"{robot.name} has no Z1 arm (arm joints named {', '.join(Z1_JOINT_NAMES[:6])}); the Z1 link "
                          "needs a model with one (--robot b1_z1)")
    locked = {name: q for name, q, _ in _locked_joints(robot)}
    index, held = [], []
    for name in Z1_JOINT_NAMES:
        if name in robot.joint_names:
            index.append(robot.joint_names.index(name))
            held.append(0.0)
        elif name in locked:
            index.append(-1)
            held.append(float(locked[name]))
        else:
            raise ConfigError(f"{robot.name}'s arm lacks Z1 joint '{name}' (neither modelled nor locked): the Z1 has "
                              f"{N_Z1_JOINTS} joints ({', '.join(Z1_JOINT_NAMES)})")
    return Z1ArmMap(tuple(index), tuple(held))


def _locked_joints(robot: RobotModel) -> list[tuple[str, float, float]]:
    """(name, position in the model's reference pose, effort limit) of each locked joint: where the reduced
    model froze it, from the full model."""
    if not robot.spec.locked_joints:
        return []
    full, limits = robot.full_model, {}
    if robot.mjcf is not None:  # an MJCF's torque limits are its actuators' (pinocchio's parser leaves them out)
        from wbmpc.robots.mjcf import force_limits, mjcf_joints

        own = mjcf_joints(robot.mjcf)
        limits = {n: min(-lo, hi) for n, (lo, hi, _) in
                  force_limits(robot.mjcf, [n for n in robot.spec.locked_joints if n in own]).items()}
    return [(name, robot.locked_positions[name],
             limits.get(name, float(full.effortLimit[full.idx_vs[full.getJointId(name)]])))
            for name in robot.spec.locked_joints]
