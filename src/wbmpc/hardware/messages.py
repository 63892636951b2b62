"""LowState_ / LowCmd_ <-> wbmpc arrays, with the checks a robot makes; both Unitree families:
`unitree_go` (quadrupeds: header 0xFE 0xEF, level flag, 20 motor slots) and `unitree_hg` (humanoids such
as G1: `mode_pr`, `mode_machine`, 35 motor slots); the motor map (`MotorMap.family`) says which.

`LowState`: IMU (quaternion w, x, y, z; gyroscope rad/s; accelerometer m/s^2, base frame), per
motor q, dq (rad, rad/s), temperature, (unitree_go) foot contact forces, `tick` (ms). `LowCmd`: per
motor mode (0x01 servo, 0x00 off), q, dq, kp, kd, tau: the motor applies tau + kp (q - q_m) + kd (dq - dq_m),
which is eq. (10) run on the motor side. unitree_hg commands carry the robot's `mode_machine` (echoed from
its LowState, as Unitree's examples do) and `mode_pr` 0: ankles and waist in pitch/roll coordinates, the
model's joints (1, AB, would address the parallel linkages' motors). In lock-step simulation the LowCmd's
reserve word echoes the LowState tick it answers (a real robot ignores it).

`low_state_defects` lists what a LowState leaves unset or wrong; a robot fills every field, Unitree's
simulator (unitree_mujoco) leaves the header, CRC, tick and motor temperatures at 0 (`UNSET`): the
robot link (`wbmpc.hardware.link`) decides which defects it accepts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from wbmpc.errors import WbmpcError
from wbmpc.estimation.sensors import SensorReadings
from wbmpc.hardware.crc import is_hg, low_cmd_crc, low_state_crc
from wbmpc.hardware.sdk import load_sdk

if TYPE_CHECKING:  # mapping imports the Z1 messages, which import MessageError from here
    from wbmpc.hardware.mapping import MotorMap

HEAD = (0xFE, 0xEF)
LOWLEVEL = 0xFF
MODE_SERVO, MODE_OFF = 0x01, 0x00
MODE_PR = 0  # unitree_hg: serial pitch/roll coordinates of ankles and waist (1: AB, the parallel motors)
PRESENT_TEMPERATURE_C = 30
# the fields Unitree's simulator leaves at 0 (unset), by defect name
UNSET = ("header [0, 0]", "CRC 0", "tick 0", "motor temperatures 0")


class MessageError(WbmpcError, ValueError):
    """A LowState/LowCmd failed a check (CRC, header, motor set, non-finite values); `reasons` names each."""

    def __init__(self, message: str, reasons: tuple[str, ...] = ()):
        super().__init__(message)
        self.reasons = reasons or (message,)


@dataclass
class MotorCommand:
    """Per joint (`robot.joint_names` order) targets and gains of the motor law."""

    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau_nm: np.ndarray

    @staticmethod
    def damping(n: int, kd: float) -> "MotorCommand":
        z = np.zeros(n)
        return MotorCommand(z.copy(), z.copy(), z.copy(), np.full(n, kd), z.copy())

    def torque(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """The motor law (eq. 10 on the motor side)."""
        return self.tau_nm + self.kp * (self.q_rad - q) + self.kd * (self.dq_rad_s - dq)


def _temperatures(motor, hg: bool) -> int:
    return int(motor.temperature[0]) if hg else int(motor.temperature)


# ---------------------------------------------------------------------------- LowState
_STATE_MESSAGES: dict = {}


def encode_low_state(reading: SensorReadings, motors: MotorMap, tick_ms: int, foot_force_n: np.ndarray | None = None,
                     mode_machine: int = 0):
    """A LowState for `reading` (joints in `motors.joint_names` order; held motors at their reference). One
    message object per motor map is reused (building the IDL object costs more than the rest of a 500 Hz
    tick): write it before the next call."""
    hg = motors.family == "unitree_hg"
    msg = _STATE_MESSAGES.get(motors)
    if msg is None:
        msg = _STATE_MESSAGES[motors] = load_sdk().idl(motors.family).new_low_state()
    if hg:
        msg.mode_pr, msg.mode_machine = MODE_PR, int(mode_machine)
    else:
        msg.head, msg.level_flag = list(HEAD), LOWLEVEL
    x, y, z, w = (float(c) for c in reading.quaternion_xyzw)
    msg.imu_state.quaternion = [w, x, y, z]
    msg.imu_state.gyroscope = [float(c) for c in reading.gyro_rad_s]
    msg.imu_state.accelerometer = [float(c) for c in reading.accel_m_s2]
    temperature = [PRESENT_TEMPERATURE_C, PRESENT_TEMPERATURE_C] if hg else PRESENT_TEMPERATURE_C
    slots = list(motors.slots) + list(motors.held_slots)
    q = list(reading.joint_position_rad) + [h.q_rad for h in motors.held]
    dq = list(reading.joint_velocity_rad_s) + [0.0] * len(motors.held)
    for slot, q_j, dq_j in zip(slots, q, dq):
        m = msg.motor_state[slot]
        m.mode = MODE_SERVO
        m.q, m.dq = float(q_j), float(dq_j)
        m.temperature = list(temperature) if hg else temperature
    if foot_force_n is not None and not hg:
        msg.foot_force = [int(np.clip(f, 0, 32767)) for f in foot_force_n[:4]] + [0] * (4 - min(4, len(foot_force_n)))
    msg.tick = int(tick_ms) & 0xFFFFFFFF
    msg.crc = low_state_crc(msg)
    return msg


def leave_unset(msg) -> None:
    """Blank what Unitree's simulator (unitree_mujoco) leaves at 0: header, level flag, tick, motor modes and
    temperatures, foot forces, mode_pr and mode_machine, CRC (robot-sim --robot-link sim)."""
    hg = is_hg(msg)
    if hg:
        msg.mode_pr, msg.mode_machine = 0, 0
    else:
        msg.head, msg.level_flag, msg.foot_force = [0, 0], 0, [0, 0, 0, 0]
    for m in msg.motor_state:
        m.mode = 0
        m.temperature = [0, 0] if hg else 0
    msg.tick = 0
    msg.crc = 0


def present_slots(msg) -> list[int]:
    hg = is_hg(msg)
    return [i for i, m in enumerate(msg.motor_state) if _temperatures(m, hg) > 0]


def low_state_defects(msg) -> list[str]:
    """What this LowState leaves unset (`UNSET`) or gets wrong ("header [...]", "CRC mismatch"), in `UNSET`'s
    order; the motor set and values are checked by `decode_low_state`."""
    defects = []
    if not is_hg(msg) and list(msg.head) != list(HEAD):
        defects.append("header [0, 0]" if list(msg.head) == [0, 0] else f"header {list(msg.head)}")
    if msg.crc != low_state_crc(msg):
        defects.append("CRC 0" if msg.crc == 0 else "CRC mismatch")
    if msg.tick == 0:
        defects.append("tick 0")
    if not present_slots(msg):
        defects.append("motor temperatures 0")
    return defects


def decode_low_state(msg, motors: MotorMap, accept: tuple[str, ...] = (), defects: list[str] | None = None) -> SensorReadings:
    """Checked LowState -> `SensorReadings` (time from `tick`, joints in `motors.joint_names` order);
    MessageError on any defect not in `accept` (`UNSET` for Unitree's simulator; `defects`: the message's
    `low_state_defects` if known). With "motor temperatures 0" accepted and no temperature reported, the
    model's motors are taken as present."""
    defects = [d for d in (low_state_defects(msg) if defects is None else defects) if d not in accept]
    if defects:
        raise MessageError(f"LowState rejected: {', '.join(defects)}", tuple(defects))
    present = present_slots(msg)
    if present and sorted(present) != sorted(motors.robot_slots):
        missing = [motors.slot_name(s) for s in sorted(set(motors.robot_slots) - set(present))]
        extra = [motors.slot_name(s) for s in sorted(set(present) - set(motors.robot_slots))]
        raise MessageError(
            f"the robot reports {len(present)} motors; the model has {len(motors.robot_slots)} on this link: "
            f"missing on the robot: {', '.join(missing) or 'none'}; extra on the robot: {', '.join(extra) or 'none'}. "
            "Run the controller with the robot's model (--robot)", ("motor set",))
    w, x, y, z = msg.imu_state.quaternion
    quat = np.array([x, y, z, w], dtype=float)
    q = np.array([msg.motor_state[s].q for s in motors.slots], dtype=float)
    dq = np.array([msg.motor_state[s].dq for s in motors.slots], dtype=float)
    gyro = np.array(msg.imu_state.gyroscope, dtype=float)
    accel = np.array(msg.imu_state.accelerometer, dtype=float)
    values = np.concatenate([quat, q, dq, gyro, accel])
    if not np.all(np.isfinite(values)) or abs(np.linalg.norm(quat) - 1.0) > 1e-2:
        raise MessageError("LowState carries non-finite values or a non-unit IMU quaternion", ("non-finite",))
    # foot_force is a raw, uncalibrated sensor count on Unitree robots, not newtons: stance comes from the
    # gait schedule in the estimator (EstimatorConfig.use_contact_sensors stays off on hardware)
    contact = np.full(4, np.nan)
    return SensorReadings(msg.tick / 1e3, quat, gyro, accel, q, dq, contact)


# ---------------------------------------------------------------------------- LowCmd
def encode_low_cmd(command: MotorCommand, motors: MotorMap, echo_tick: int = 0, mode_machine: int = 0,
                   held: MotorCommand | None = None):
    """A LowCmd: `command` on the model's motors, `held` (in `motors.held` order; None: off) on the held ones;
    unitree_hg carries `mode_machine` (the robot's, from its LowState) and mode_pr PR."""
    msg = load_sdk().idl(motors.family).new_low_cmd()
    hg = motors.family == "unitree_hg"
    if hg:
        msg.mode_pr, msg.mode_machine = MODE_PR, int(mode_machine)
    else:
        msg.head, msg.level_flag = list(HEAD), LOWLEVEL
    rows = [(motors.slots, command)] + ([(motors.held_slots, held)] if held is not None else [])
    for slots, values in rows:
        for j, slot in enumerate(slots):
            m = msg.motor_cmd[slot]
            m.mode = MODE_SERVO
            m.q, m.dq = float(values.q_rad[j]), float(values.dq_rad_s[j])
            m.kp, m.kd, m.tau = float(values.kp[j]), float(values.kd[j]), float(values.tau_nm[j])
    echo = int(echo_tick) & 0xFFFFFFFF
    if hg:
        msg.reserve = [echo, 0, 0, 0]
    else:
        msg.reserve = echo
    msg.crc = low_cmd_crc(msg)
    return msg


def command_echo(msg) -> int:
    """The LowState tick a LowCmd answers (lock-step simulation)."""
    return int(msg.reserve[0]) if is_hg(msg) else int(msg.reserve)


def decode_low_cmd(msg, motors: MotorMap, checked: bool = True, mode_machine: int | None = None) -> MotorCommand:
    """LowCmd -> `MotorCommand` on the model's joints; MessageError on a bad CRC, header, mode_pr, mode_machine
    (when given: the robot's), motor set or value. `checked=False` skips the CRC, header, mode and motor-set
    checks, as Unitree's simulator does (it applies what arrives)."""
    hg = is_hg(msg)
    if checked:
        if hg:
            if msg.mode_pr != MODE_PR:
                raise MessageError(f"LowCmd mode_pr {msg.mode_pr} is not {MODE_PR} (PR: ankles and waist in pitch/roll "
                                   "coordinates, the model's joints)", ("mode_pr",))
            if mode_machine is not None and msg.mode_machine != mode_machine:
                raise MessageError(f"LowCmd mode_machine {msg.mode_machine} is not the robot's ({mode_machine}, in its "
                                   "LowState): rejected", ("mode_machine",))
        elif list(msg.head) != list(HEAD) or msg.level_flag != LOWLEVEL:
            raise MessageError(f"LowCmd header {list(msg.head)}/level {msg.level_flag} is not a low-level command",
                               ("header",))
        if msg.crc != low_cmd_crc(msg):
            raise MessageError("LowCmd CRC mismatch: rejected", ("crc",))
        active = [i for i, m in enumerate(msg.motor_cmd) if m.mode != MODE_OFF]
        unknown = sorted(set(active) - set(motors.robot_slots))
        if unknown:
            raise MessageError(f"LowCmd commands motor slots {unknown} this robot does not have ({motors.describe()})",
                               ("motor set",))
    rows = np.array([[msg.motor_cmd[s].q, msg.motor_cmd[s].dq, msg.motor_cmd[s].kp, msg.motor_cmd[s].kd,
                      msg.motor_cmd[s].tau] if msg.motor_cmd[s].mode != MODE_OFF or not checked else [0, 0, 0, 0, 0]
                     for s in motors.slots], dtype=float)
    if not np.all(np.isfinite(rows)) or np.any(rows[:, 2:4] < 0):
        raise MessageError("LowCmd carries non-finite values or negative gains", ("non-finite",))
    return MotorCommand(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4])
