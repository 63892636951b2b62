"""End-effector feedback laws: a position reference turned into the velocity command of eq. (7)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.robots import RobotModel

FEEDBACK_GAIN_1_S = 4.0
MAX_EE_SPEED_M_S = 0.5


class EeState:
    """End-effector position from a measured configuration (pinocchio FK)."""

    def __init__(self, robot: RobotModel):
        self.robot = robot
        self.data = robot.model.createData()
        self.fid = robot.frame_id(robot.arm_ee)

    def position(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self.robot.model, self.data, q)
        return self.data.oMf[self.fid].translation.copy()


def ee_velocity_feedback(v_ref: np.ndarray, p_ref: np.ndarray, p: np.ndarray, free_normal: np.ndarray | None = None) -> np.ndarray:
    """v = v_ref + K (p_ref - p), without the component along `free_normal` (force-controlled), clipped."""
    velocity = v_ref + FEEDBACK_GAIN_1_S * (p_ref - p)
    if free_normal is not None:
        velocity = velocity - free_normal * (velocity @ free_normal)
    speed = np.linalg.norm(velocity)
    return velocity * (MAX_EE_SPEED_M_S / speed) if speed > MAX_EE_SPEED_M_S else velocity


class EeIntegral:
    """Integral action on the end-effector position error: a velocity term Ki * int(e dt) added to the command,
    clipped to `max_speed_m_s` (anti-windup). The MPC plans with its model: a hand or an arm heavier than the model
    (or unmodelled friction) leaves a steady offset under proportional feedback alone (b1_z1 with 10 % more mass
    on every link: the hand 10 mm low), which the integral removes. `normal`: only the error across it (in a
    plane) is integrated; `within_m`: samples with a larger error are not integrated (an unreachable reference, a
    collision margin: proportional feedback alone, the integral cleared, until the hand is back near its path; a
    term kept at its clip there pushed b1_z1's hand into the post of arm-track's around-obstacle path and walked the
    base off after it)."""

    def __init__(self, gain_1_s2: float, normal: np.ndarray | None = None, max_speed_m_s: float = 0.05,
                 within_m: float | None = None):
        self.normal = None if normal is None else np.asarray(normal, dtype=float)
        self.gain, self.max_speed_m_s, self.within_m = gain_1_s2, max_speed_m_s, within_m
        self.value = np.zeros(3)
        self.last_t_s: float | None = None

    def update(self, t_s: float, error_m: np.ndarray) -> np.ndarray:
        """Integrate `error_m` (its in-plane part with a normal) up to time `t_s`; the velocity term (m/s)."""
        error = np.asarray(error_m, dtype=float)
        if self.normal is not None:
            error = error - self.normal * (error @ self.normal)
        if self.within_m is not None and np.linalg.norm(error) > self.within_m:
            self.value = np.zeros(3)
        elif self.last_t_s is not None and self.gain > 0:
            self.value = self.value + error * max(t_s - self.last_t_s, 0.0)
            speed = self.gain * np.linalg.norm(self.value)
            if speed > self.max_speed_m_s:
                self.value *= self.max_speed_m_s / speed
        self.last_t_s = t_s
        return self.gain * self.value


class InPlaneIntegral(EeIntegral):
    """Integral action on the in-plane end-effector error, clipped to MAX_INTEGRAL_SPEED_M_S. On a board the pad's
    friction is an unmodelled force in the plane (the force target only carries it along the motion; standing
    still, static friction acts in any direction), which proportional feedback alone leaves as a steady offset
    of millimetres."""

    MAX_INTEGRAL_SPEED_M_S = 0.05

    def __init__(self, normal: np.ndarray, gain_1_s2: float):
        super().__init__(gain_1_s2, normal=normal, max_speed_m_s=self.MAX_INTEGRAL_SPEED_M_S)


def yaw_rotation(q: np.ndarray) -> np.ndarray:
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
