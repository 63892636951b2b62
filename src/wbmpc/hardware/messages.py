"""LowState_ / LowCmd_ (unitree_go IDL) <-> wbmpc arrays, with the checks a robot makes.

`LowState`: IMU (quaternion w, x, y, z; gyroscope rad/s; accelerometer m/s^2, base frame), per
motor q, dq (rad, rad/s), temperature, foot contact forces, `tick` (ms). `LowCmd`: per motor mode
(0x01 servo, 0x00 off), q, dq, kp, kd, tau: the motor applies tau + kp (q - q_m) + kd (dq - dq_m),
which is eq. (10) run on the motor side. In lock-step simulation LowCmd's `reserve` field echoes the
LowState tick it answers (a real robot ignores it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from wbmpc.errors import WbmpcError
from wbmpc.estimation.sensors import SensorReadings
from wbmpc.hardware.crc import low_cmd_crc, low_state_crc
from wbmpc.hardware.sdk import load_sdk

if TYPE_CHECKING:  # mapping imports the Z1 messages, which import MessageError from here
    from wbmpc.hardware.mapping import MotorMap

HEAD = (0xFE, 0xEF)
LOWLEVEL = 0xFF
MODE_SERVO, MODE_OFF = 0x01, 0x00
PRESENT_TEMPERATURE_C = 30


class MessageError(WbmpcError, ValueError):
    """A LowState/LowCmd failed a check (CRC, header, motor set, non-finite values)."""


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


# ---------------------------------------------------------------------------- LowState
_STATE_MESSAGES: dict = {}


def encode_low_state(reading: SensorReadings, motors: MotorMap, tick_ms: int, foot_force_n: np.ndarray | None = None):
    """A LowState for `reading`. One message object per motor map is reused (building the IDL
    object costs more than the rest of a 500 Hz tick): write it before the next call."""
    msg = _STATE_MESSAGES.get(motors)
    if msg is None:
        msg = _STATE_MESSAGES[motors] = load_sdk().new_low_state()
        msg.head = list(HEAD)
        msg.level_flag = LOWLEVEL
    x, y, z, w = (float(c) for c in reading.quaternion_xyzw)
    msg.imu_state.quaternion = [w, x, y, z]
    msg.imu_state.gyroscope = [float(c) for c in reading.gyro_rad_s]
    msg.imu_state.accelerometer = [float(c) for c in reading.accel_m_s2]
    for j, slot in enumerate(motors.slots):
        m = msg.motor_state[slot]
        m.mode = MODE_SERVO
        m.q = float(reading.joint_position_rad[j])
        m.dq = float(reading.joint_velocity_rad_s[j])
        m.temperature = PRESENT_TEMPERATURE_C
    if foot_force_n is not None:
        msg.foot_force = [int(np.clip(f, 0, 32767)) for f in foot_force_n[:4]] + [0] * (4 - min(4, len(foot_force_n)))
    msg.tick = int(tick_ms) & 0xFFFFFFFF
    msg.crc = low_state_crc(msg)
    return msg


def present_slots(msg) -> list[int]:
    return [i for i, m in enumerate(msg.motor_state) if m.temperature > 0]


def decode_low_state(msg, motors: MotorMap) -> SensorReadings:
    """Checked LowState -> `SensorReadings` (time from `tick`); MessageError on any defect."""
    if list(msg.head) != list(HEAD):
        raise MessageError(f"LowState header {list(msg.head)} is not {list(HEAD)}")
    if msg.crc != low_state_crc(msg):
        raise MessageError("LowState CRC mismatch (corrupted or not a unitree_go LowState)")
    present = present_slots(msg)
    if sorted(present) != sorted(motors.slots):
        from wbmpc.hardware.mapping import slot_joint_name

        missing = [slot_joint_name(s) for s in sorted(set(motors.slots) - set(present))]
        extra = [slot_joint_name(s) for s in sorted(set(present) - set(motors.slots))]
        raise MessageError(
            f"the robot reports {len(present)} motors; the model has {motors.n_motors} on this link: "
            f"missing on the robot: {', '.join(missing) or 'none'}; extra on the robot: {', '.join(extra) or 'none'}. "
            "Run the controller with the robot's model (--robot)")
    w, x, y, z = msg.imu_state.quaternion
    quat = np.array([x, y, z, w], dtype=float)
    q = np.array([msg.motor_state[s].q for s in motors.slots], dtype=float)
    dq = np.array([msg.motor_state[s].dq for s in motors.slots], dtype=float)
    gyro = np.array(msg.imu_state.gyroscope, dtype=float)
    accel = np.array(msg.imu_state.accelerometer, dtype=float)
    values = np.concatenate([quat, q, dq, gyro, accel])
    if not np.all(np.isfinite(values)) or abs(np.linalg.norm(quat) - 1.0) > 1e-2:
        raise MessageError("LowState carries non-finite values or a non-unit IMU quaternion")
    # foot_force is a raw, uncalibrated sensor count on Unitree robots, not newtons: stance comes from the
    # gait schedule in the estimator (EstimatorConfig.use_contact_sensors stays off on hardware)
    contact = np.full(4, np.nan)
    return SensorReadings(msg.tick / 1e3, quat, gyro, accel, q, dq, contact)


# ---------------------------------------------------------------------------- LowCmd
def encode_low_cmd(command: MotorCommand, motors: MotorMap, echo_tick: int = 0):
    sdk = load_sdk()
    msg = sdk.new_low_cmd()
    msg.head = list(HEAD)
    msg.level_flag = LOWLEVEL
    for j, slot in enumerate(motors.slots):
        m = msg.motor_cmd[slot]
        m.mode = MODE_SERVO
        m.q, m.dq = float(command.q_rad[j]), float(command.dq_rad_s[j])
        m.kp, m.kd, m.tau = float(command.kp[j]), float(command.kd[j]), float(command.tau_nm[j])
    msg.reserve = int(echo_tick) & 0xFFFFFFFF
    msg.crc = low_cmd_crc(msg)
    return msg


def decode_low_cmd(msg, motors: MotorMap) -> MotorCommand:
    """Checked LowCmd -> `MotorCommand`; MessageError on a bad CRC, header, motor set or value."""
    if list(msg.head) != list(HEAD) or msg.level_flag != LOWLEVEL:
        raise MessageError(f"LowCmd header {list(msg.head)}/level {msg.level_flag} is not a low-level command")
    if msg.crc != low_cmd_crc(msg):
        raise MessageError("LowCmd CRC mismatch: rejected")
    active = [i for i, m in enumerate(msg.motor_cmd) if m.mode != MODE_OFF]
    unknown = sorted(set(active) - set(motors.slots))
    if unknown:
        raise MessageError(f"LowCmd commands motor slots {unknown} this robot does not have ({motors.describe()})")
    rows = np.array([[msg.motor_cmd[s].q, msg.motor_cmd[s].dq, msg.motor_cmd[s].kp, msg.motor_cmd[s].kd,
                      msg.motor_cmd[s].tau] if msg.motor_cmd[s].mode != MODE_OFF else [0, 0, 0, 0, 0]
                     for s in motors.slots], dtype=float)
    if not np.all(np.isfinite(rows)) or np.any(rows[:, 2:4] < 0):
        raise MessageError("LowCmd carries non-finite values or negative gains")
    return MotorCommand(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4])
