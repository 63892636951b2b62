"""Time-series tools of the scenarios' metrics: ramps, holds, a force sensor's low-pass, force tracking."""

from __future__ import annotations

import numpy as np

from wbmpc.control.run_log import RunLog
from wbmpc.robots import RobotModel

FORCE_SENSOR_BANDWIDTH_HZ = 30.0


def ramp(t_s: float, start_s: float, end_s: float) -> float:
    """0 before start, 1 after end, linear in between."""
    return float(np.clip((t_s - start_s) / (end_s - start_s), 0.0, 1.0))


def hold(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Zero-order hold of per-MPC-step values at other times."""
    index = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 1)
    return values[index]


def force_tracking(t_s: np.ndarray, measured_n: np.ndarray, direction: np.ndarray, target_n: np.ndarray,
                   window: np.ndarray) -> dict:
    """`ee_force_err_rel` and friends: measured force along `direction` against `target_n` (> 0) in `window`."""
    along = np.einsum("ij,ij->i", measured_n, direction)
    use = window & (target_n > 1e-6)
    if not use.any():
        return {"ee_force_err_rel": None}
    rel = np.abs(along[use] - target_n[use]) / target_n[use]
    return {
        "ee_force_err_rel": float(np.mean(rel)),
        "ee_force_err_rel_p95": float(np.percentile(rel, 95)),
        "ee_force_measured_mean_n": float(np.mean(along[use])),
        "ee_force_target_mean_n": float(np.mean(target_n[use])),
        "ee_force_bias_rel": float(np.mean(along[use] - target_n[use]) / np.mean(target_n[use])),
    }


def low_pass(t_s: np.ndarray, values: np.ndarray, bandwidth_hz: float) -> np.ndarray:
    """First-order low-pass (a force sensor's filter) of samples `values` (n, ...) at times `t`."""
    out = np.array(values, dtype=float, copy=True)
    tau = 1.0 / (2 * np.pi * bandwidth_hz)
    for k in range(1, len(t_s)):
        alpha = (t_s[k] - t_s[k - 1]) / (t_s[k] - t_s[k - 1] + tau)
        out[k] = out[k - 1] + alpha * (values[k] - out[k - 1])
    return out


def commanded_forces(log: RunLog, at: np.ndarray) -> np.ndarray:
    forces = log.command_array()[:, 7:10]  # ee_force_n (see wbmpc.control.loop.command_row)
    return hold(np.array(log.mpc_t), forces, at)


def arm_torque_metrics(robot: RobotModel, log: RunLog) -> dict:
    """Torque ratio of each arm joint (joint3 is what limited the paper's pull on hardware)."""
    tau = np.abs(log.arrays(("tau",))["tau"]) / robot.tau_max
    return {f"torque_ratio_{name}": float(tau[:, k].max())
            for k, name in enumerate(robot.joint_names) if not robot.leg_joint_mask[k]}
