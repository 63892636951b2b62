"""Leg joint references consistent with the feet's motion while the base moves (a Raibert-like placement).

The posture rows of eq. (3) pull the leg joints to the nominal pose at every node. On a trot at speed v that
reference contradicts the feet: a stance foot is fixed in the world, so relative to its hip it runs from
v T_st / 2 ahead to v T_st / 2 behind (T_st the stance duration); a swing foot comes back forward. Pulled to
the nominal pose, a swing foot lands under its hip and the whole stance is behind it: the base leads its
support (go2 at 0.24 m/s: by 9 cm), the load moves onto the front foot of each diagonal, whose line then
passes beside the CoM (by the lead times the diagonal's width over its length), and the trunk sways sideways
at the gait frequency (0.17 m/s RMS on go2; 0.01 trotting in place).

`StanceReference` gives per node the foot offset (in the heading frame) that the gait and the commanded base
velocity imply, Raibert's neutral point v T_st / 2 ahead at touch-down,

    stance, fraction u of it done:  d = v_hip T_st (1/2 - u)
    swing, progress s:              d = v_hip T_st (s - 1/2)

with v_hip = v + omega x r_hip, turned into leg joint offsets through the inverse of each leg's Jacobian
(first order: a few cm). They are taken around the centred pose: the nominal pose with its feet moved
horizontally (inverse kinematics, base and foot heights fixed) until the CoM is over the centre of the feet,
where a trot's diagonals cross; a nominal pose with its CoM off that centre (anymal_b_kinova: 8.5 cm ahead,
a1: 3.7 cm behind) puts each diagonal beside the CoM even in place. The legs' posture weight decides how
closely the plan follows these targets (`control/tuning.py`, `LEG_POSTURE`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.gait import Gait
from wbmpc.robots import RobotModel

CENTRING_ITERATIONS = 4  # CoM -> feet -> CoM: the legs' own mass moves with the feet (converged to < 1 mm)
IK_ITERATIONS = 20


class StanceReference:
    """Leg joint offsets from the nominal pose per MPC node (see the module docstring)."""

    def __init__(self, robot: RobotModel):
        model = robot.model
        self._data = data = model.createData()
        self._model, self._robot = model, robot
        q = robot.q_nominal.copy()
        q[3:7] = (0.0, 0.0, 0.0, 1.0)  # the base frame is the heading frame
        # q[7:] coordinate of each one-coordinate joint's velocity column (continuous joints have two)
        q_column = {model.joints[j].idx_v - 6: model.joints[j].idx_q - 7 for j in range(2, model.njoints)
                    if model.joints[j].nq == 1}
        self._frames = [robot.frame_id(foot) for foot in robot.feet]
        pin.computeJointJacobians(model, data, q)
        self._velocity_columns = []  # per foot: its leg's joints (velocity columns after the base's 6)
        for frame in self._frames:
            jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
            columns = np.flatnonzero(np.any(np.abs(jacobian) > 1e-9, axis=0))
            self._velocity_columns.append(np.array([c for c in columns if robot.leg_joint_mask[c] and c in q_column],
                                                   dtype=int))
        self._columns = [np.array([q_column[c] for c in columns], dtype=int) for columns in self._velocity_columns]
        # the pose with the CoM over the centre of the feet (where a trot's diagonals cross), by inverse kinematics
        nominal_feet = self._feet(q)
        centred = q.copy()
        for _ in range(CENTRING_ITERATIONS):
            shift = pin.centerOfMass(model, data, centred)[:2] - nominal_feet[:, :2].mean(axis=0)
            centred = self._inverse_kinematics(centred, nominal_feet + np.r_[shift, 0.0])
        self.centring_m = shift
        self._centred_offset = centred[7:] - q[7:]
        pin.computeJointJacobians(model, data, centred)
        pin.updateFramePlacements(model, data)
        base = data.oMi[1].translation
        self._inverse = []  # per foot: (n_leg, 2) horizontal foot displacement -> joint offsets (centred pose)
        self._hip_m = []  # per foot: horizontal position relative to the base (for the yaw rate)
        for frame, columns in zip(self._frames, self._velocity_columns):
            jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + columns]
            # the foot moves in 3D with its leg's joints; hold its height (z = 0) while it moves horizontally
            self._inverse.append(np.linalg.pinv(jacobian)[:, :2])
            self._hip_m.append(data.oMf[frame].translation[:2] - base[:2])
        self._n_coordinates = model.nq - 7

    def _feet(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self._model, self._data, q)
        return np.array([self._data.oMf[frame].translation.copy() for frame in self._frames])

    def _inverse_kinematics(self, q: np.ndarray, feet_m: np.ndarray) -> np.ndarray:
        """q with each leg's joints moved so that its foot reaches feet_m (base fixed; Gauss-Newton)."""
        q = q.copy()
        for _ in range(IK_ITERATIONS):
            error = feet_m - self._feet(q)
            if np.max(np.abs(error)) < 1e-6:
                break
            pin.computeJointJacobians(self._model, self._data, q)
            for frame, columns, coordinates, e in zip(self._frames, self._velocity_columns, self._columns, error):
                jacobian = pin.getFrameJacobian(self._model, self._data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + columns]
                q[7 + coordinates] += np.linalg.lstsq(jacobian, e, rcond=None)[0]
        return q

    def joint_offsets(self, gait: Gait, times_s: np.ndarray, velocity_m_s: np.ndarray,
                      yaw_rate_rad_s: float) -> np.ndarray:
        """(len(times), nq - 7) leg joint offsets from the nominal pose at these absolute times, for a base
        velocity (x, y in the heading frame) and yaw rate: the centred pose plus the feet's motion."""
        times_s = np.asarray(times_s, dtype=float)
        out = np.tile(self._centred_offset, (len(times_s), 1))
        duty = gait.duty_factor
        if duty >= 1:
            return np.zeros_like(out)
        if not np.any(velocity_m_s[:2]) and yaw_rate_rad_s == 0.0:
            return out
        stance_s = duty * gait.period_s
        phase = gait.phase(times_s)  # (n, feet)
        swing = phase >= duty
        lever = np.where(swing, (phase - duty) / (1 - duty) - 0.5, 0.5 - phase / duty)  # (n, feet)
        for i, (columns, inverse, hip) in enumerate(zip(self._columns, self._inverse, self._hip_m)):
            v_hip = np.asarray(velocity_m_s[:2], dtype=float) + yaw_rate_rad_s * np.array([-hip[1], hip[0]])
            out[:, columns] += np.outer(lever[:, i] * stance_s, v_hip) @ inverse.T
        return out
