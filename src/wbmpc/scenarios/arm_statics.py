"""What an end-effector force does to a standing robot's statics: the arm's joint torques (eq. 2 without motion),
the feet's centre of pressure, and the check that a force target is feasible before a run."""

from __future__ import annotations

import warnings

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError
from wbmpc.robots import GRAVITY_M_S2, RobotModel

EE_SPHERE_RADIUS_M = 0.03  # MujocoPlantConfig.ee_sphere_radius_m default: contact offset of the EE frame
TORQUE_WARNING_RATIO = 0.8


def nominal_ee_position(robot: RobotModel) -> np.ndarray:
    return robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]


def static_arm_torques(robot: RobotModel, force_applied_n: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
    """Arm joint torques holding the pose `q` (nominal by default) while the end-effector applies
    `force_applied_n` (world) on the environment: tau = g(q) + J^T F (static eq. 2 with F_arm = -F)."""
    q = robot.q_nominal if q is None else q
    model, data = robot.model, robot.model.createData()
    gravity = pin.computeGeneralizedGravity(model, data, q)
    jac = pin.computeFrameJacobian(model, data, q, robot.frame_id(robot.arm_ee), pin.LOCAL_WORLD_ALIGNED)[:3]
    tau = gravity[6:] + jac[:, 6:].T @ np.asarray(force_applied_n, dtype=float)
    return tau[~robot.leg_joint_mask]


def support_centre_of_pressure(robot: RobotModel, force_applied_n: np.ndarray) -> np.ndarray:
    """Ground centre of pressure (x, y) holding the nominal pose statically against gravity and the
    end-effector applying `force_applied_n` (moment balance of eq. 2 without motion)."""
    q = robot.q_nominal
    weight = robot.mass_kg * GRAVITY_M_S2
    com = pin.centerOfMass(robot.model, robot.model.createData(), q)
    p_ee = nominal_ee_position(robot)
    on_robot = -np.asarray(force_applied_n, dtype=float)
    reaction_z = weight - on_robot[2]
    if reaction_z <= 0:
        return np.array([np.inf, np.inf])
    moment = np.cross(com, [0.0, 0.0, -weight]) + np.cross(p_ee, on_robot)
    return np.array([moment[1], -moment[0]]) / reaction_z


def support_points(robot: RobotModel) -> np.ndarray:
    """(n, 2) ground points of the feet at the nominal pose: point feet, and the corners of flat feet's soles
    (two point feet side by side support no fore-aft moment; two soles do)."""
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, robot.q_nominal)
    points = []
    for foot in robot.feet:
        placement = data.oMf[robot.frame_id(robot.contact_frame(foot))]
        local = robot.soles[foot].corners_m() if foot in robot.soles else np.zeros((1, 3))
        points.extend(placement.rotation @ corner + placement.translation for corner in local)
    return np.array(points)[:, :2]


def check_arm_force(robot: RobotModel, force_applied_n: np.ndarray, what: str) -> np.ndarray:
    """Raise `ConfigError` when the arm cannot hold the force target at its nominal pose, or the
    force would tip the standing robot over its feet; warn near the arm's torque limits.

    Returns the ratio |tau| / tau_max per arm joint."""
    tau = static_arm_torques(robot, force_applied_n)
    limits = robot.tau_max[~robot.leg_joint_mask]
    ratio = np.abs(tau) / limits
    names = [n for n, leg in zip(robot.joint_names, robot.leg_joint_mask) if not leg]
    worst = int(np.argmax(ratio))
    magnitude = float(np.linalg.norm(force_applied_n))
    detail = (f"{what} of {magnitude:.1f} N needs {abs(tau[worst]):.1f} Nm on {names[worst]} at the nominal arm "
              f"pose (limit {limits[worst]:.1f} Nm)")
    if ratio[worst] > 1.0:
        raise ConfigError(f"{detail}: beyond the arm's torque limits; lower the force (--force-n) or the load (--load-kg)")
    xy = support_points(robot)
    cop = support_centre_of_pressure(robot, force_applied_n)
    if not (np.all(cop >= xy.min(axis=0)) and np.all(cop <= xy.max(axis=0))):
        raise ConfigError(f"{what} of {magnitude:.1f} N would tip the robot over: the centre of pressure it needs "
                          f"({cop[0]:.2f}, {cop[1]:.2f}) m lies outside the feet; lower the force (--force-n)")
    if ratio[worst] > TORQUE_WARNING_RATIO:
        warnings.warn(f"{detail}: {100 * ratio[worst]:.0f} % of the limit, little margin left for motion", stacklevel=2)
    return ratio
