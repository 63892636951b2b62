"""Forward dynamics with rigid contacts held (pinocchio's `constraintDynamics`), in CasADi SX.

The contacts are pinocchio's `RigidConstraintModel`s in the LOCAL frame of each foot's contact frame: a sole
(flat foot) holds its 6D spatial acceleration, a point foot the classical acceleration of its point (3D), each
driven towards zero velocity by a Baumgarte term, `J a + gamma = -Kd v_c`. With M a = tau - b + J^T lambda,

    (J M^-1 J^T + mu I) lambda = -Kd v_c - gamma - J M^-1 (tau - b),

(mu: pinocchio's proximal damping) and M^-1 applied by the tree's sparse L^T D L factorisation
(`dynamics._ltdl_solve`). Which feet are held is an input (one 0/1 per foot): a free foot's rows become
lambda_i = 0, so one function covers every stance set.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from wbmpc.symbolic import spatial as sp
from wbmpc.symbolic.dynamics import Configuration, Motion, SymbolicDynamics, _ltdl_solve


def contact_rows(dyn: SymbolicDynamics, motion: Motion, accelerations: tuple[list, list], frame: str, surface: bool):
    """(constraint acceleration, constraint velocity) of a contact frame in its LOCAL axes, from the joints'
    `accelerations` (`SymbolicDynamics.joint_accelerations`): the spatial acceleration and velocity (6 rows, linear first) of a sole,
    the classical acceleration and linear velocity of a point (3)."""
    f = dyn.model.frames[dyn.robot.frame_id(frame)]
    j, rot_t, t = f.parentJoint, sp.const(np.array(f.placement.rotation).T), sp.const(f.placement.translation)
    lin, ang = accelerations
    acc_lin = ca.mtimes(rot_t, lin[j] + sp.cross(ang[j], t))
    acc_ang = ca.mtimes(rot_t, ang[j])
    vel_lin = ca.mtimes(rot_t, motion.lin[j] + sp.cross(motion.ang[j], t))
    vel_ang = ca.mtimes(rot_t, motion.ang[j])
    if surface:
        return ca.vertcat(acc_lin, acc_ang), ca.vertcat(vel_lin, vel_ang)
    return acc_lin + sp.cross(vel_ang, vel_lin), vel_lin


def held_forward_dynamics(dyn: SymbolicDynamics, cfg: Configuration, motion: Motion, tau_joints: ca.SX,
                          held: ca.SX, baumgarte_kd, mu: float) -> ca.SX:
    """The accelerations with the feet whose `held` entry is 1 held still (module docstring); the joint torques
    `tau_joints`, gravity and the bias forces of the rigid bodies (the drive train's armature in M; no friction:
    pinocchio's algorithms have none)."""
    robot, nv = dyn.robot, dyn.nv
    a_sym = ca.SX.sym("a", nv)
    zero = ca.SX.zeros(nv)
    bias = dyn.rnea(cfg, motion, zero) - dyn.drive_train_torque(motion.v, zero)
    rhs = ca.vertcat(ca.SX.zeros(6), tau_joints) - bias
    rows, drift, mask = [], [], []
    accelerations = dyn.joint_accelerations(cfg, motion, a_sym, gravity=False)
    for k, foot in enumerate(robot.feet):
        surface = foot in (robot.soles or {})
        acc, vel = contact_rows(dyn, motion, accelerations, robot.contact_frame(foot), surface)
        rows.append(ca.jacobian(acc, a_sym))  # J_i: the acceleration is linear in a
        drift.append(-baumgarte_kd * vel - ca.substitute(acc, a_sym, zero))
        mask += [held[k]] * acc.shape[0]
    jac, target, s = ca.vertcat(*rows), ca.vertcat(*drift), ca.vertcat(*mask)
    columns = ca.horzcat(rhs, jac.T)
    solved = _ltdl_solve(dyn.mass_matrix(cfg), dyn.dof_parents, [columns[i, :] for i in range(nv)])
    a_free, minv_jt = solved[:, 0], solved[:, 1:]
    delassus = ca.mtimes(jac, minv_jt) + mu * ca.SX.eye(jac.shape[0])
    masked = delassus * ca.mtimes(s, s.T) + ca.diag(1 - s)  # a free foot's rows: lambda_i = 0
    forces = cholesky_solve(masked, s * (target - ca.mtimes(jac, a_free)))
    return a_free + ca.mtimes(minv_jt, forces)


def cholesky_solve(matrix: ca.SX, rhs: ca.SX) -> ca.SX:
    """x with `matrix` x = `rhs`, `matrix` symmetric positive definite (dense Cholesky, unrolled)."""
    n = matrix.shape[0]
    low = [[None] * n for _ in range(n)]
    for j in range(n):
        diagonal = matrix[j, j] - sum((low[j][k] * low[j][k] for k in range(j)), ca.SX(0))
        low[j][j] = ca.sqrt(diagonal)
        for i in range(j + 1, n):
            low[i][j] = (matrix[i, j] - sum((low[i][k] * low[j][k] for k in range(j)), ca.SX(0))) / low[j][j]
    y = [None] * n
    for i in range(n):
        y[i] = (rhs[i] - sum((low[i][k] * y[k] for k in range(i)), ca.SX(0))) / low[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum((low[k][i] * x[k] for k in range(i + 1, n)), ca.SX(0))) / low[i][i]
    return ca.vertcat(*x)
