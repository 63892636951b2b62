"""What keeps a real robot safe around the MPC: watchdogs, clamps, fall detection, posture moves.

- `Watchdog`: time since the last valid message; expired after `timeout_ms`.
- `clamp_command`: joint targets inside the position limits (minus a margin), gains and the
  torque the motor law can produce inside the effort limits.
- `fallen`: base tilted more than `max_tilt_deg` or below `min_height_ratio` of its nominal height.
- `posture_command`: joint PD towards a pose, blended from a start pose over a duration (stand-up
  from lying, lie-down from standing); `Posture` adds what a biped needs to stand on it (see there).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError
from wbmpc.hardware.messages import MotorCommand
from wbmpc.robots import RobotModel


@dataclass(frozen=True)
class SafetyConfig:
    state_timeout_ms: float = 100.0  # controller: no LowState for this long -> stop commanding
    command_timeout_ms: float = 100.0  # robot: no LowCmd for this long -> damping
    damping_kd: float = 5.0  # N m s/rad in damping mode
    joint_limit_margin_rad: float = 0.02
    max_kp: float = 500.0
    max_kd: float = 50.0
    max_tilt_deg: float = 60.0
    min_height_ratio: float = 0.5
    stand_up_s: float = 2.0
    lie_down_s: float = 2.0
    # stand-up / lie-down joint PD, per N m of the joint's effort limit (go2 calf: kp 91, kd 2.3; B1 calf:
    # kp 280, kd 7): fixed high gains made the light go2 oscillate and flip over DDS's tick delay
    posture_kp_per_nm: float = 2.0
    posture_kd_per_nm: float = 0.05

    def __post_init__(self):
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"safety setting {name} must be a finite number >= 0, got {value}")
        if not (self.state_timeout_ms > 0 and self.command_timeout_ms > 0):
            raise ConfigError("watchdog timeouts must be positive (ms)")


class Watchdog:
    """Wall-clock time since the last `feed()`; `expired()` after `timeout_ms` (never fed: expired)."""

    def __init__(self, timeout_ms: float, clock=time.monotonic):
        self.timeout_s = timeout_ms / 1e3
        self._clock = clock
        self._last: float | None = None

    def feed(self) -> None:
        self._last = self._clock()

    def age_s(self) -> float:
        return np.inf if self._last is None else self._clock() - self._last

    def expired(self) -> bool:
        return self.age_s() > self.timeout_s


def clamp_command(robot: RobotModel, command: MotorCommand, q: np.ndarray, dq: np.ndarray,
                  config: SafetyConfig) -> MotorCommand:
    """Targets inside the joint limits, gains bounded, and tau_ff so that the motor law stays in +-tau_max."""
    lower = robot.model.lowerPositionLimit[7:] + config.joint_limit_margin_rad
    upper = robot.model.upperPositionLimit[7:] - config.joint_limit_margin_rad
    q_des = np.clip(command.q_rad, lower, upper)
    kp = np.clip(command.kp, 0.0, config.max_kp)
    kd = np.clip(command.kd, 0.0, config.max_kd)
    feedback = kp * (q_des - q) + kd * (command.dq_rad_s - dq)
    tau_max = robot.tau_max
    tau = np.clip(command.tau_nm + feedback, -tau_max, tau_max) - feedback
    return MotorCommand(q_des, command.dq_rad_s.copy(), kp, kd, tau)


def fallen(robot: RobotModel, q: np.ndarray, config: SafetyConfig, check_height: bool = True) -> bool:
    """Tilted beyond `max_tilt_deg`, or (when standing, `check_height`) below `min_height_ratio` of the nominal height."""
    x, y, z, w = q[3:7] / np.linalg.norm(q[3:7])
    tilted = 1.0 - 2.0 * (x * x + y * y) < np.cos(np.deg2rad(config.max_tilt_deg))  # R[2, 2] of the base
    return bool(tilted or (check_height and q[2] < config.min_height_ratio * robot.q_nominal[2]))


CROUCH_KNEE_RAD = 1.2  # a biped's resting crouch: knees bent this much more than standing


def lying_joint_positions(robot: RobotModel) -> np.ndarray:
    """The resting pose of the lie-down. Quadrupeds: folded legs (calf near its folding limit, thigh raised), a
    Z1 arm folded (its rest pose, z1_controller's "startFlat"), another arm at its nominal pose. Bipeds (two feet):
    a crouch, knees bent `CROUCH_KNEE_RAD` more than standing and hip and ankle pitch each taking half of it back,
    so the soles stay flat and the torso upright over them (G1's and TALOS's pitch joints share one sign
    convention); a humanoid does not lie down by joint PD, it crouches onto its gantry before damping."""
    from wbmpc.hardware.z1_messages import Z1_REST_POSE_RAD

    q = robot.q_nominal[7:].copy()
    lower, upper = robot.model.lowerPositionLimit[7:], robot.model.upperPositionLimit[7:]
    if len(robot.feet) == 2:
        for j, name in enumerate(robot.joint_names):
            bend = CROUCH_KNEE_RAD if "knee" in name else -0.5 * CROUCH_KNEE_RAD if any(
                part in name for part in ("hip_pitch", "ankle_pitch")) else 0.0
            q[j] = np.clip(q[j] + bend, lower[j] + 0.05, upper[j] - 0.05) if bend else q[j]
        return q
    for j, name in enumerate(robot.joint_names):
        if not robot.leg_joint_mask[j]:
            if name in Z1_REST_POSE_RAD:
                q[j] = np.clip(Z1_REST_POSE_RAD[name], lower[j], upper[j])
            continue
        if "calf" in name:
            q[j] = lower[j] + 0.15 if abs(lower[j]) > abs(upper[j]) else upper[j] - 0.15
        elif "thigh" in name:
            q[j] = np.clip(q[j] + 0.45, lower[j], upper[j])
        elif "hip" in name:
            q[j] = 0.0
    return q


def posture_command(start: np.ndarray, target: np.ndarray, elapsed_s: float, duration_s: float,
                    config: SafetyConfig, tau_max: np.ndarray) -> MotorCommand:
    """Joint PD (gains scaled by the effort limits) to a smooth cosine blend from `start` to `target`;
    holds `target` after `duration_s`."""
    s = 1.0 if duration_s <= 0 else float(np.clip(elapsed_s / duration_s, 0.0, 1.0))
    blend = 0.5 - 0.5 * np.cos(np.pi * s)
    rate = 0.0 if duration_s <= 0 or s >= 1 else 0.5 * np.pi * np.sin(np.pi * s) / duration_s
    n = len(target)
    return MotorCommand(start + blend * (target - start), rate * (target - start), config.posture_kp_per_nm * tau_max,
                        config.posture_kd_per_nm * tau_max, np.zeros(n))


class Posture:
    """The posture moves (stand-up, hold, lie-down) of one robot: `posture_command` with its gains, and for a biped
    what standing on joint PD needs. A quadruped stands on four feet whatever its posture gains; a biped's body is
    an inverted pendulum over its ankles: joint PD holds it only if every leg joint is stiffer than its share of
    the toppling stiffness (m g h / feet, `balance_margin` times), and the pose's gravity torques come as
    feedforward (`stance_torques`), so that the PD does not sag under the robot's weight."""

    def __init__(self, robot: RobotModel, config: SafetyConfig, balance_margin: float = 1.5):
        self.robot, self.config = robot, config
        tau_max = robot.tau_max
        self.kp, self.kd = config.posture_kp_per_nm * tau_max, config.posture_kd_per_nm * tau_max
        self.biped = len(robot.feet) == 2
        if self.biped:
            data = robot.model.createData()
            com_height_m = pin.centerOfMass(robot.model, data, robot.q_nominal)[2]
            mass_kg = pin.computeTotalMass(robot.model)
            balance_kp = balance_margin * mass_kg * 9.81 * com_height_m / len(robot.feet)
            legs = robot.leg_joint_mask
            ratio = config.posture_kd_per_nm / config.posture_kp_per_nm
            self.kp[legs] = np.maximum(self.kp[legs], balance_kp)
            self.kd[legs] = np.maximum(self.kd[legs], ratio * balance_kp)
        self._stance: dict[bytes, np.ndarray] = {}

    def command(self, start: np.ndarray, target: np.ndarray, elapsed_s: float, duration_s: float) -> MotorCommand:
        command = posture_command(start, target, elapsed_s, duration_s, self.config, self.robot.tau_max)
        command.kp, command.kd = self.kp.copy(), self.kd.copy()
        if self.biped:
            s = 1.0 if duration_s <= 0 else float(np.clip(elapsed_s / duration_s, 0.0, 1.0))
            blend = 0.5 - 0.5 * np.cos(np.pi * s)
            command.tau_nm = (1 - blend) * self.stance_torques(start) + blend * self.stance_torques(target)
        return command

    def stance_torques(self, q_joints: np.ndarray) -> np.ndarray:
        """Joint torques holding `q_joints` still on the feet, base at its nominal orientation: gravity through the
        joints, the feet's wrenches the least-squares solution of the base's balance (the first six rows of eq. 2)."""
        key = np.asarray(q_joints, dtype=float).tobytes()
        if key not in self._stance:
            robot = self.robot
            model, data = robot.model, robot.model.createData()
            q = robot.q_nominal.copy()
            q[7:] = q_joints
            gravity = pin.computeGeneralizedGravity(model, data, q)
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            jac = np.vstack([pin.getFrameJacobian(model, data, model.getFrameId(foot), pin.LOCAL_WORLD_ALIGNED)
                             for foot in robot.feet])
            wrenches = np.linalg.lstsq(jac[:, :6].T, gravity[:6], rcond=None)[0]
            if len(self._stance) > 8:
                self._stance.clear()
            self._stance[key] = gravity[6:] - jac[:, 6:].T @ wrenches
        return self._stance[key]
