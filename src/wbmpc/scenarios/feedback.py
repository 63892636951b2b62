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


class InPlaneIntegral:
    """Integral action on the in-plane end-effector error: a velocity term Ki * int(e dt), clipped to
    MAX_INTEGRAL_SPEED_M_S. On a board the pad's friction is an unmodelled force in the plane (the
    force target only carries it along the motion; standing still, static friction acts in any
    direction), which proportional feedback alone leaves as a steady offset of millimetres."""

    MAX_INTEGRAL_SPEED_M_S = 0.05

    def __init__(self, normal: np.ndarray, gain_1_s2: float):
        self.normal, self.gain = np.asarray(normal, dtype=float), gain_1_s2
        self.value = np.zeros(3)
        self.last_t_s: float | None = None

    def update(self, t_s: float, error_m: np.ndarray) -> np.ndarray:
        """Integrate the in-plane part of `error_m` up to time `t_s`; the velocity term (m/s)."""
        error = error_m - self.normal * (error_m @ self.normal)
        if self.last_t_s is not None and self.gain > 0:
            self.value = self.value + error * max(t_s - self.last_t_s, 0.0)
            speed = self.gain * np.linalg.norm(self.value)
            if speed > self.MAX_INTEGRAL_SPEED_M_S:
                self.value *= self.MAX_INTEGRAL_SPEED_M_S / speed
        self.last_t_s = t_s
        return self.gain * self.value


def yaw_rotation(q: np.ndarray) -> np.ndarray:
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
