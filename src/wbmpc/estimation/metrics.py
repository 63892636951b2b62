"""Estimation errors against the simulator's truth (keys of `metrics.json` under --state estimated)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.estimation.source import EstimationLog


def orientation_errors_rad(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """(n, 3) rotation vector of R_true^T R_est per row (roll, pitch, yaw-ish components in the base frame)."""
    out = np.empty((len(q_est), 3))
    for i in range(len(q_est)):
        r_est = pin.Quaternion(q_est[i, 3:7]).toRotationMatrix()
        r_true = pin.Quaternion(q_true[i, 3:7]).toRotationMatrix()
        out[i] = pin.log3(r_true.T @ r_est)
    return out


def estimation_metrics(log: EstimationLog, skip_s: float = 0.0) -> dict:
    """RMSE of base position (m, xyz), base velocity (m/s, base frame), orientation (rad), joint velocity.

    Velocity error is compared in the base frame (what the MPC receives); `skip_s` drops the start.
    """
    a = log.arrays()
    if len(a["t"]) == 0:
        return {}
    keep = a["t"] - a["t"][0] >= skip_s
    qe, qt, ve, vt = a["q_est"][keep], a["q_true"][keep], a["v_est"][keep], a["v_true"][keep]
    pos = qe[:, :3] - qt[:, :3]
    vel = ve[:, :3] - vt[:, :3]
    rot = orientation_errors_rad(qe, qt)
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, axis=1))))  # noqa: E731
    return {
        "est_base_pos_rmse_m": rms(pos),
        "est_base_pos_rmse_xyz_m": np.sqrt(np.mean(pos**2, axis=0)).tolist(),
        "est_base_pos_final_err_m": float(np.linalg.norm(pos[-1])),
        "est_base_vel_rmse_m_s": rms(vel),
        "est_base_vel_rmse_xyz_m_s": np.sqrt(np.mean(vel**2, axis=0)).tolist(),
        "est_orientation_rmse_rad": rms(rot),
        "est_roll_pitch_rmse_rad": float(np.sqrt(np.mean(np.sum(rot[:, :2] ** 2, axis=1)))),
        "est_base_angvel_rmse_rad_s": rms(ve[:, 3:6] - vt[:, 3:6]),
        "est_joint_vel_rmse_rad_s": float(np.sqrt(np.mean((ve[:, 6:] - vt[:, 6:]) ** 2))),
    }
