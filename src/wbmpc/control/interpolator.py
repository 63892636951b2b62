"""Linear interpolation of an MPC solution at the low-level rate (eq. 9) and joint PD (eq. 10)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.control.solution import Solution
from wbmpc.options import check_fields, option


@dataclass(frozen=True)
class JointReference:
    tau_ff: np.ndarray
    q_des: np.ndarray
    v_des: np.ndarray
    segment: int  # 0: between t0 and t1; 1: the last solution is late, between t1 and t2


def interpolate(solution: Solution, t_s: float) -> JointReference:
    """Eq. (9): tau from tau_k to tau_{k+1}, q_des = q_k + v_k (t - t_k), v_des = v_k + a_k (t - t_k).

    Segment k = 0 while t < t_1; if t_1 has passed without a new solution the same rule runs
    between t_1 and t_2 (k = 1). Beyond t_2 the references are held at t_2.
    """
    times = solution.t_s + solution.node_times_s
    k = 0 if t_s < times[1] else 1
    n_tau = solution.tau.shape[0]
    t_local = float(np.clip(t_s - times[k], 0.0, times[k + 1] - times[k]))
    dt_k = times[k + 1] - times[k]
    tau_k = solution.tau[min(k, n_tau - 1)]
    tau_next = solution.tau[min(k + 1, n_tau - 1)]
    tau_ff = tau_k + (tau_next - tau_k) * (t_local / dt_k)
    q_des = solution.q_joints[k] + solution.v[k, 6:] * t_local
    v_des = solution.v[k, 6:] + solution.a[k, 6:] * t_local
    return JointReference(tau_ff, q_des, v_des, k)


@dataclass(frozen=True)
class PdGains:
    """Joint PD of eq. (10); the paper needs Kd ~ 5 in simulation with delay, Kp = 0 on the legs."""

    kp_leg: float = option(0.0, flag="--kp", help="leg joint Kp of eq. (10)", low=0.0, high=1e4, unit="Nm/rad",
                           cli_default=None, default_text="the robot's tuning, 0 on B1")
    kd_leg: float = option(5.0, flag="--kd", help="leg joint Kd of eq. (10)", low=0.0, high=1e4, unit="Nm s/rad",
                           cli_default=None, default_text="the robot's tuning, 5 on B1")
    kp_arm: float = option(20.0, help="arm joint Kp of eq. (10)", low=0.0, high=1e4, unit="Nm/rad")
    kd_arm: float = option(1.0, help="arm joint Kd of eq. (10)", low=0.0, high=1e4, unit="Nm s/rad")

    def __post_init__(self):
        check_fields(self)

    def vectors(self, is_arm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kp = np.where(is_arm, self.kp_arm, self.kp_leg)
        kd = np.where(is_arm, self.kd_arm, self.kd_leg)
        return kp, kd


def pd_torque(reference: JointReference, q_j: np.ndarray, v_j: np.ndarray, kp: np.ndarray, kd: np.ndarray,
              tau_max: np.ndarray) -> np.ndarray:
    """Eq. (10): tau_motor = tau_ff + Kp (q_des - q) + Kd (v_des - v), clamped to the effort limits."""
    tau = reference.tau_ff + kp * (reference.q_des - q_j) + kd * (reference.v_des - v_j)
    return np.clip(tau, -tau_max, tau_max)
