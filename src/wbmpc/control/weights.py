"""`CostWeights`: the diagonal weights Q and R of the MPC's cost (eq. 3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.errors import check_number
from wbmpc.robots import RobotModel


@dataclass
class CostWeights:
    """Diagonal Q and R of eq. (3). Parameters of the NLP: change them between steps freely.

    Posture weights dominate the force pull (otherwise the optimum trades height for equal force
    shares and the robot sinks); the regularisation of a, F and tau keeps Fatrop at ~5 iterations.
    """

    base_position: tuple[float, float, float] = (500.0, 500.0, 1e4)
    base_orientation: tuple[float, float, float] = (1e4, 1e4, 2000.0)  # roll, pitch, yaw
    leg_joint_position: float = 50.0
    arm_joint_position: float = 100.0
    base_linear_velocity: float = 50.0
    base_angular_velocity: float = 50.0
    joint_velocity: float = 1.0
    acceleration: float = 1e-2
    contact_force: float = 1e-3  # pull towards the weight shared over the stance feet
    # flat feet's sole moments, per (N m)^2 (their target is 0: the centre of pressure at the sole's centre). None:
    # contact_force / (the sole's half width)^2, the moment weighted as the force it puts on the centre-of-pressure
    # rows at their shortest lever. Weighted per (N m)^2 like the forces per N^2 (the bipeds' 1e-5) the moments were
    # nearly free: g1's plans swung a sole's pitch moment by 2-3.5 N m between consecutive steps (node to node by up
    # to 50 N m with the accelerations taking it up), each warm start far from the next optimum, the centre-of-pressure
    # rows active at the edge cutting Fatrop's first steps to 1-40 % (walking forward at 0.3 m/s, 11 ms delay, 400
    # recorded steps: 5.26 -> 4.70 iterations per step, solves above 6 iterations 86 -> 33)
    contact_moment: float | None = None
    joint_torque: float = 1e-3
    # L1 weight of the soft rows' slacks (OcpConfig.soft_rows) per unit violation (m/s for the arm's
    # velocity): above the rows' multipliers on nominal trot steps (<= 60 on b1_z1), so those plans
    # stay exact; 1e3 leaves nominal Fatrop steps unconverged after 200 iterations, 50 is not exact
    soft_constraint: float = 100.0
    # quadratic weight of the same slacks per (m/s)^2 (0: the exact L1 penalty alone). With collision avoidance
    # the arm's command meets the collision rows: under L1 alone a command pointing within 45 deg of a surface's
    # normal stops the hand there (moving along the surface costs more than stopping), a quadratic weight makes it
    # slide along (the command's projection); Fatrop's interior point also converges on it where a 1e3 L1 does not
    soft_constraint_quadratic: float = 0.0

    def __post_init__(self):
        for name, value in vars(self).items():
            if value is None:
                continue
            for item in np.atleast_1d(np.asarray(value, dtype=float)):
                check_number(f"weights.{name}", float(item), low=0.0)

    def vectors(self, robot: RobotModel, nf: int) -> dict[str, np.ndarray]:
        """The weights as the NLP's parameter vectors (w_dq, w_v, w_a, w_F, w_tau, w_slack, w_slack_sq)."""
        nj = robot.n_joints
        joints = np.where(robot.leg_joint_mask, self.leg_joint_position, self.arm_joint_position)
        return {
            "w_dq": np.concatenate([self.base_position, self.base_orientation, joints]),
            "w_v": np.concatenate([[self.base_linear_velocity] * 3, [self.base_angular_velocity] * 3, [self.joint_velocity] * nj]),
            "w_a": np.full(robot.nv, self.acceleration),
            "w_F": self._force_weights(robot, nf),
            "w_tau": np.full(nj, self.joint_torque),
            "w_slack": [self.soft_constraint],
            "w_slack_sq": [self.soft_constraint_quadratic],
        }

    def _force_weights(self, robot: RobotModel, nf: int) -> np.ndarray:
        """w_F: contact_force on the forces, `contact_moment` on flat feet's sole moments (the last 3 per sole of F,
        in the feet's order; `SymbolicDynamics.moment_slice`)."""
        weights = np.full(nf, self.contact_force)
        soles = [robot.soles[foot] for foot in robot.feet if foot in robot.soles]
        for i, sole in enumerate(soles):
            moment = self.contact_moment if self.contact_moment is not None else \
                self.contact_force / sole.half_width_m**2
            start = nf - 3 * (len(soles) - i)
            weights[start : start + 3] = moment
        return weights
