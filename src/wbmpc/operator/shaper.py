"""`CommandShaper`: the operator's targets -> the MPC's `Commands`, one MPC step at a time.

A target is never handed to the MPC as a step: the base velocity (planar, as a vector) and the yaw rate
follow it within acceleration limits, the body height and the hand's target within speed limits. Walking
stops only once the velocity reference has ramped to zero (then the gait switches to standing at the next
moment no foot is in the air, `GaitClock.follow`), so a stop is a ramp down, the swings in progress landing,
then standing. The hand's target (an offset from its place in the standing pose, in the base's heading frame)
becomes the end-effector velocity command of eq. (7) by feedback, v = v_ff + k (p_target - p_hand), as the
arm-track scenario does; without a hand target the scenario's own hand command passes through.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands
from wbmpc.errors import check_number
from wbmpc.operator.command import OperatorCommand
from wbmpc.robots import RobotModel


@dataclass(frozen=True)
class RampLimits:
    """How fast the references may follow the operator's targets."""

    linear_accel_m_s2: float = 1.0  # planar base velocity
    yaw_accel_rad_s2: float = 2.0
    height_rate_m_s: float = 0.1
    hand_speed_m_s: float = 0.15  # the hand's target moves at most this fast
    hand_gain_1_s: float = 3.0  # feedback on the hand's position error (arm-track uses 4)
    max_hand_speed_m_s: float = 0.5  # the end-effector velocity command is clipped to this
    # a reference governor: while ramping, the reference leads the measured base by at most this much, so the
    # MPC's position anchor (the integrated reference, `MpcConfig.base_tracking`) does not run ahead of a robot
    # that is still starting to step and then pull it past the command (b1_z1 from standing to 0.4 m/s at
    # 1 m/s^2: 0.49 m/s for 0.8 s without it)
    max_lead_m_s: float = 0.15
    max_yaw_lead_rad_s: float = 0.3

    def __post_init__(self):
        for name in ("linear_accel_m_s2", "yaw_accel_rad_s2", "height_rate_m_s", "hand_speed_m_s", "hand_gain_1_s",
                     "max_hand_speed_m_s", "max_lead_m_s", "max_yaw_lead_rad_s"):
            check_number(name, getattr(self, name), low=0.0, low_open=True)


def _step_towards(current: np.ndarray, target: np.ndarray, max_step: float) -> np.ndarray:
    """`current` moved towards `target` by at most `max_step` (Euclidean)."""
    delta = np.asarray(target, dtype=float) - current
    norm = float(np.linalg.norm(delta))
    return current + (delta if norm <= max_step else delta * (max_step / norm))


class CommandShaper:
    """Call once per MPC step with the step's time, the measured state, the operator's command and the
    scenario's own commands (`Commands`); returns the MPC's commands."""

    def __init__(self, robot: RobotModel, initial: OperatorCommand, limits: RampLimits = RampLimits()):
        self.robot, self.limits = robot, limits
        self.velocity = np.array([initial.forward_m_s, initial.lateral_m_s])  # heading frame, m/s
        self.yaw_rate = float(initial.yaw_rate_rad_s)
        self.height_offset = float(initial.height_offset_m)
        self.hand_offset = np.array(initial.hand_offset_m if initial.hand_offset_m is not None else (0.0, 0.0, 0.0))
        self.walking = bool(initial.walking)
        self._last_t: float | None = None
        self._ee_id = robot.frame_id(robot.arm_ee) if robot.arm_ee else None
        self._data = robot.model.createData()
        self.hand_home_m = self._hand_home() if self._ee_id is not None else None

    def _hand_home(self) -> np.ndarray:
        """The hand's place in the standing pose, relative to the base in its heading frame."""
        q = self.robot.q_nominal.copy()
        q[3:7] = (0.0, 0.0, 0.0, 1.0)
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        return self._data.oMf[self._ee_id].translation - q[:3]

    def hand_target_world(self, q: np.ndarray) -> np.ndarray | None:
        """Where the hand is asked to be now (world), None without an arm."""
        if self.hand_home_m is None:
            return None
        return q[:3] + heading_rotation(q) @ (self.hand_home_m + self.hand_offset)

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray, command: OperatorCommand, base: Commands) -> Commands:
        lim = self.limits
        dt = 0.0 if self._last_t is None else max(0.0, t - self._last_t)
        self._last_t = t
        target = np.array([command.forward_m_s, command.lateral_m_s]) if command.walking else np.zeros(2)
        heading = heading_rotation(q)
        rot = pin.Quaternion(np.asarray(q[3:7], dtype=float)).toRotationMatrix()
        measured = (heading.T @ rot @ np.asarray(v[:3], dtype=float))[:2]
        measured_yaw = float((rot @ np.asarray(v[3:6], dtype=float))[2])
        self.velocity = _governed_step(self.velocity, target, lim.linear_accel_m_s2 * dt, measured, lim.max_lead_m_s)
        yaw_target = command.yaw_rate_rad_s if command.walking else 0.0
        self.yaw_rate = float(_governed_step(np.array([self.yaw_rate]), np.array([yaw_target]), lim.yaw_accel_rad_s2 * dt,
                                             np.array([measured_yaw]), lim.max_yaw_lead_rad_s)[0])
        self.height_offset = float(_step_towards(np.array([self.height_offset]), np.array([command.height_offset_m]),
                                                 lim.height_rate_m_s * dt)[0])
        # stand only once the references are still: the feet then land where the base stops
        moving = bool(np.any(self.velocity) or self.yaw_rate)
        self.walking = bool(command.walking or moving)
        height = base.base_height_m
        if self.height_offset or command.height_offset_m:
            height = float(self.robot.q_nominal[2]) + self.height_offset
        ee_velocity = base.ee_velocity_m_s
        if command.hand_offset_m is not None and self._ee_id is not None:
            ee_velocity = self._hand_velocity(q, np.asarray(command.hand_offset_m, dtype=float), dt)
        return replace(base, base_velocity_m_s=np.array([self.velocity[0], self.velocity[1], 0.0]),
                       base_yaw_rate_rad_s=self.yaw_rate, base_height_m=height, ee_velocity_m_s=ee_velocity,
                       walking=self.walking)

    def _hand_velocity(self, q: np.ndarray, target_offset: np.ndarray, dt: float) -> np.ndarray:
        """World velocity command of the hand: the target's own motion (base velocity and turn, the offset
        moving at most `hand_speed_m_s`) plus feedback on where the hand is."""
        lim = self.limits
        previous = self.hand_offset.copy()
        self.hand_offset = _step_towards(self.hand_offset, target_offset, lim.hand_speed_m_s * dt)
        heading = heading_rotation(q)
        lever = heading @ (self.hand_home_m + self.hand_offset)
        feedforward = heading @ np.array([self.velocity[0], self.velocity[1], 0.0])
        feedforward += np.cross([0.0, 0.0, self.yaw_rate], lever)
        if dt > 0:
            feedforward += heading @ (self.hand_offset - previous) / dt
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        hand = self._data.oMf[self._ee_id].translation
        velocity = feedforward + lim.hand_gain_1_s * (q[:3] + lever - hand)
        speed = float(np.linalg.norm(velocity))
        if speed > lim.max_hand_speed_m_s:
            velocity *= lim.max_hand_speed_m_s / speed
        return velocity


def _governed_step(current: np.ndarray, target: np.ndarray, max_step: float, measured: np.ndarray,
                   max_lead: float) -> np.ndarray:
    """`_step_towards` that, ramping up in speed, stops where the reference would lead the measurement by more than
    `max_lead` along the ramp's direction (it never holds back a slow-down, nor a reference already at its target)."""
    delta = np.asarray(target, dtype=float) - current
    norm = float(np.linalg.norm(delta))
    if norm < 1e-12:
        return np.array(target, dtype=float)
    direction = delta / norm
    speeding_up = float(np.linalg.norm(target)) > float(np.linalg.norm(current)) - 1e-12
    step = min(norm, max_step)
    if speeding_up:
        room = float(direction @ (measured - current)) + max_lead  # how far ahead of the robot the reference may go
        step = min(step, max(room, 0.0))
    return current + step * direction


def heading_rotation(q: np.ndarray) -> np.ndarray:
    """The base's heading frame (yaw only) in world coordinates."""
    rot = pin.Quaternion(np.asarray(q[3:7], dtype=float)).toRotationMatrix()
    yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
