"""The inputs of an MPC step checked before any work: the measured state and the commands (`MPC.solve`)."""

from __future__ import annotations

import math

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.control.config import CommandLimits
from wbmpc.errors import ConfigError
from wbmpc.robots import GRAVITY_M_S2, RobotModel


def checked_state(robot: RobotModel, limits: CommandLimits, q, v, commands: Commands, t: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The measured state (q with a unit quaternion, v) as float arrays, after checking it and the commands: sizes,
    finite values, the quaternion's norm, the commands within `MpcConfig.limits` and what the robot can do."""
    q = np.asarray(q, dtype=float).ravel()
    v = np.asarray(v, dtype=float).ravel()
    if q.size != robot.nq:
        raise ConfigError(f"state q has {q.size} entries; {robot.name} needs nq = {robot.nq}")
    if v.size != robot.nv:
        raise ConfigError(f"state v has {v.size} entries; {robot.name} needs nv = {robot.nv}")
    # one finite sum instead of two element-wise checks (every step); a NaN or inf anywhere makes it non-finite
    if not (math.isfinite(q.dot(q) + v.dot(v)) and math.isfinite(t)):
        raise ConfigError("state or time contains NaN/inf (or values beyond 1e150); pass a finite measured state")
    quaternion = q[3:7]
    norm = math.sqrt(quaternion.dot(quaternion))  # (np.linalg.norm: ~5x the time on 4 numbers)
    if abs(norm - 1) > 1e-3:
        raise ConfigError(f"base quaternion q[3:7] must be unit (norm {norm:.4f}); normalise the estimate")
    q = q.copy()
    q[3:7] /= norm
    _check_commands(robot, limits, commands)
    return q, v


def _command_vector(commands: Commands, name: str) -> list[float] | None:
    """A command's 3 numbers as Python floats (None if not given; scalar arithmetic: every step)."""
    value = getattr(commands, name)
    if value is None:
        return None
    value = np.asarray(value, dtype=float)
    if value.shape != (3,):
        raise ConfigError(f"command {name} must be 3 finite numbers, got {value}")
    return value.tolist()


def _check_commands(robot: RobotModel, limits: CommandLimits, commands: Commands) -> None:
    """The commands within `limits` and what the robot can do, finite, of 3 numbers each."""
    vectors = {name: _command_vector(commands, name) for name in ("base_velocity_m_s", "ee_velocity_m_s", "ee_force_n")}
    base, ee_velocity, force = vectors["base_velocity_m_s"], vectors["ee_velocity_m_s"], vectors["ee_force_n"]
    speed = math.hypot(base[0], base[1])
    if speed > limits.base_speed_m_s:
        raise ConfigError(f"base velocity command {speed:.2f} m/s exceeds limits.base_speed_m_s = {limits.base_speed_m_s}")
    if abs(commands.base_yaw_rate_rad_s) > limits.yaw_rate_rad_s:
        raise ConfigError(f"yaw rate command exceeds limits.yaw_rate_rad_s = {limits.yaw_rate_rad_s}")
    if robot.arm_ee and ee_velocity is not None and math.hypot(*ee_velocity) > limits.ee_speed_m_s:
        raise ConfigError(f"end-effector velocity command exceeds limits.ee_speed_m_s = {limits.ee_speed_m_s}")
    for name, value in vectors.items():
        if value is not None and not math.isfinite(value[0] * value[0] + value[1] * value[1] + value[2] * value[2]):
            raise ConfigError(f"command {name} must be 3 finite numbers, got {np.asarray(value)}")
    if not math.isfinite(commands.base_yaw_rate_rad_s):
        raise ConfigError(f"command base_yaw_rate_rad_s must be finite, got {commands.base_yaw_rate_rad_s}")
    force_n = math.hypot(*force)
    limit = limits.ee_force_n or robot.mass_kg * GRAVITY_M_S2
    if force_n > limit:
        raise ConfigError(f"end-effector force command {force_n:.4g} N exceeds {limit:.0f} N (the robot's weight unless "
                          "MpcConfig.limits.ee_force_n says otherwise): the robot cannot apply it; lower the force")
    if commands.base_height_m is not None:
        nominal = robot.q_nominal[2]
        if not 0.4 * nominal <= commands.base_height_m <= 1.3 * nominal:
            raise ConfigError(f"base height command {commands.base_height_m:g} m is outside "
                              f"{0.4 * nominal:.2f}-{1.3 * nominal:.2f} m (40-130 % of the nominal "
                              f"{nominal:.2f} m of {robot.name})")
