"""Leg joint references consistent with the feet's motion while the base moves (a Raibert-like placement).

The posture rows of eq. (3) pull the leg joints to the nominal pose at every node. On a trot at speed v that
reference contradicts the feet: a stance foot is fixed in the world, so relative to its hip it runs from
v T_st / 2 ahead to v T_st / 2 behind (T_st the stance duration); a swing foot comes back forward. Pulled to
the nominal pose, a swing foot lands under its hip and the whole stance is behind it: the base leads its
support by v T_st / 2 on average (go2 at 0.24 m/s: 9 cm), the load moves onto the front foot of each
diagonal, whose line then passes beside the CoM (by the lead times the diagonal's width over its length)
and the trunk sways sideways at the gait frequency (0.17 m/s RMS on go2, 0.03 lead-free in place).

`StanceReference` gives per node the foot offset (in the base's heading frame) that the gait and the
commanded base velocity imply, Raibert's neutral point v T_st / 2 at touch-down,

    stance, fraction u of it done:  d = v_hip T_st (1/2 - u)
    swing, progress s:              d = v_hip T_st (s - 1/2)

with v_hip = v + omega x r_hip, and turns it into leg joint offsets through the inverse of each leg's
Jacobian at the nominal pose (first order: offsets of a few cm). The offsets are zero at zero velocity, so
trotting in place is unchanged.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.gait import Gait
from wbmpc.robots import RobotModel


class StanceReference:
    """Leg joint offsets from the nominal pose per MPC node (see the module docstring)."""

    def __init__(self, robot: RobotModel):
        model = robot.model
        data = model.createData()
        q = robot.q_nominal.copy()
        q[3:7] = (0.0, 0.0, 0.0, 1.0)  # the base frame is the heading frame
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        base = data.oMi[1].translation
        feet_xy = np.array([data.oMf[robot.frame_id(foot)].translation[:2] for foot in robot.feet])
        # the nominal pose's CoM over the centre of its feet (where a trot's diagonals cross)
        self.centring_m = pin.centerOfMass(model, data, q)[:2] - feet_xy.mean(axis=0)
        # q[7:] coordinate of each one-coordinate joint's velocity column (continuous joints have two)
        q_column = {model.joints[j].idx_v - 6: model.joints[j].idx_q - 7 for j in range(2, model.njoints)
                    if model.joints[j].nq == 1}
        self._columns = []  # per foot: the joint coordinates (in q[7:]) of its leg
        self._inverse = []  # per foot: (n_leg, 2) horizontal foot displacement -> joint offsets
        self._hip_m = []  # per foot: horizontal position relative to the base (for the yaw rate)
        for foot in robot.feet:
            frame = robot.frame_id(foot)
            jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
            columns = np.flatnonzero(np.any(np.abs(jacobian) > 1e-9, axis=0))
            columns = np.array([c for c in columns if robot.leg_joint_mask[c] and c in q_column], dtype=int)
            # the foot moves in 3D with its leg's joints; hold its height (z = 0) while it moves horizontally
            inverse = np.linalg.pinv(jacobian[:, columns])[:, :2]
            self._columns.append(np.array([q_column[c] for c in columns], dtype=int))
            self._inverse.append(inverse)
            self._hip_m.append(data.oMf[frame].translation[:2] - base[:2])
        self._n_coordinates = model.nq - 7

    def joint_offsets(self, gait: Gait, times_s: np.ndarray, velocity_m_s: np.ndarray,
                      yaw_rate_rad_s: float) -> np.ndarray:
        """(len(times), nq - 7) leg joint offsets at these absolute times, for a base velocity (x, y in the
        heading frame) and yaw rate."""
        times_s = np.asarray(times_s, dtype=float)
        out = np.zeros((len(times_s), self._n_coordinates))
        duty = gait.duty_factor
        if duty >= 1:
            return out
        stance_s = duty * gait.period_s
        phase = gait.phase(times_s)  # (n, feet)
        swing = phase >= duty
        lever = np.where(swing, (phase - duty) / (1 - duty) - 0.5, 0.5 - phase / duty)  # (n, feet)
        for i, (columns, inverse, hip) in enumerate(zip(self._columns, self._inverse, self._hip_m)):
            v_hip = np.asarray(velocity_m_s[:2], dtype=float) + yaw_rate_rad_s * np.array([-hip[1], hip[0]])
            displacement = np.outer(lever[:, i] * stance_s, v_hip) + self.centring_m  # (n, 2)
            out[:, columns] += displacement @ inverse.T
        return out
