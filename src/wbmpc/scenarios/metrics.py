"""Scenario metrics from a closed-loop `RunLog` (the keys of `metrics.json`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.loop import RunLog
from wbmpc.robots import RobotModel


SETTLE_S = 2.0


def heading_rotation(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def base_world_velocity(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 3) base linear velocity in world coordinates from pinocchio-layout states."""
    out = np.empty((len(q), 3))
    for i in range(len(q)):
        out[i] = pin.Quaternion(q[i, 3:7]).toRotationMatrix() @ v[i, :3]
    return out


def common_metrics(robot: RobotModel, log: RunLog, scenario: str) -> dict:
    a = log.arrays()
    t, q, v = a["t"], a["q"], a["v"]
    duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    # commanded base velocity (heading frame of the start) integrated over the run
    yaw0 = _yaw(q[0])
    cmd_t = np.array(log.mpc_t)
    cmd_v = np.array([c.base_velocity_m_s for c in log.commands])
    cmd_world = cmd_v @ heading_rotation(yaw0).T
    cmd_at_t = np.stack([np.interp(t, cmd_t, cmd_world[:, k]) for k in range(3)], axis=1)
    commanded_path = np.concatenate([[0.0], np.cumsum(cmd_at_t[:-1, 0] * np.diff(t))]), \
        np.concatenate([[0.0], np.cumsum(cmd_at_t[:-1, 1] * np.diff(t))])
    displacement = q[-1, :2] - q[0, :2] - np.array([commanded_path[0][-1], commanded_path[1][-1]])
    # the same after the start transient (the first SETTLE_S, at most half the run): with velocity-only
    # base tracking an initial shift is never pulled back and would dominate the whole-run figure
    settle = np.searchsorted(t, t[0] + min(SETTLE_S, 0.5 * duration)) if duration > 0 else 0
    settled_s = float(t[-1] - t[settle]) if duration > 0 else 0.0
    settled_displacement = displacement - (q[settle, :2] - q[0, :2]) + np.array(
        [commanded_path[0][settle], commanded_path[1][settle]])
    vel_world = base_world_velocity(q, v)
    solve = a["solve_ms"]
    n_solves = len(solve)
    return {
        "scenario": scenario,
        "robot": robot.name,
        "fell": bool(log.fell),
        "fell_at_s": log.fell_at_s,
        "duration_s": duration,
        "base_drift_cm_s": float(100 * np.linalg.norm(displacement) / duration) if duration > 0 else None,
        "base_drift_settled_cm_s": float(100 * np.linalg.norm(settled_displacement) / settled_s) if settled_s > 0 else None,
        "base_drift_settled_from_s": float(t[settle] - t[0]) if duration > 0 else None,
        "base_vel_rmse": float(np.sqrt(np.mean(np.sum((vel_world[:, :2] - cmd_at_t[:, :2]) ** 2, axis=1)))),
        "ee_pos_rmse_m": None,
        "ee_force_err_rel": None,
        "max_torque_ratio": float(np.max(np.abs(a["tau"]) / robot.tau_max)),
        "max_feedforward_torque_ratio": float(np.max(np.abs(a["tau_ff"]) / robot.tau_max)),
        "torque_margin_per_joint": {name: float(1.0 - r) for name, r in
                                    zip(robot.joint_names, np.max(np.abs(a["tau"]) / robot.tau_max, axis=0))},
        "solve_ms": {"mean": float(np.mean(solve)), "std": float(np.std(solve)), "max": float(np.max(solve))},
        "iterations_mean": float(np.mean(a["iterations"])),
        "mpc_failures": int(log.mpc_failures),
        "mpc_recoveries": int(log.mpc_recoveries),  # failed first, solved by a recovery re-solve
        "mpc_solves": n_solves,
        "mpc_rate_hz": float(n_solves / duration) if duration > 0 else None,
        "late_solution_share": float(log.late_solutions / max(n_solves, 1)),
        "delay_ms_mean": float(np.mean(log.delay_ms)) if log.delay_ms else 0.0,
        "wall_time_s": log.wall_time_s,
        "sim_cpu_share": log.sim_cpu_share,  # real time: simulation process CPU / wall (must not starve the MPC)
        "mpc_cpu_share": log.mpc_cpu_share,
        "realtime_priority": log.realtime_priority,  # real time: "nice -10" where permitted, else "default"
    }


def _yaw(q: np.ndarray) -> float:
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    return float(np.arctan2(rot[1, 0], rot[0, 0]))
