"""The measured state's frame velocities that enter a step's bounds: the stance feet's and the end effector's velocity
rows start from them (eq. 6, 7, blended towards their targets over the first nodes), flat feet's sole rotations too.

With the MPC's compiled functions they come from the OCP's own symbolic kinematics compiled with them (one call, also
from C: `control/compiled_step.py`), else from pinocchio's forward kinematics (the same velocities to rounding:
tests/control/test_compiled_step.py).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.symbolic import Motion


def velocities_function(problem, robot) -> ca.Function:
    """(q, v) -> [the feet's linear velocities (3 per foot) | the end effector's (3, with an arm) | the feet's angular
    velocities (3 per foot, flat feet)], world-aligned (pinocchio's LOCAL_WORLD_ALIGNED) at the feet's contact frames."""
    dyn = problem.dyn
    q, v = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv)
    cfg = dyn.configuration(q)
    motion = Motion(cfg, v)
    feet = [dyn.frame_velocity(cfg, motion, robot.contact_frame(foot)) for foot in robot.feet]
    parts = [linear for linear, _ in feet]
    if robot.arm_ee:
        parts.append(dyn.frame_velocity(cfg, motion, robot.arm_ee)[0])
    if robot.soles:
        parts += [angular for _, angular in feet]
    return ca.Function("measured_velocities", [q, v], [ca.vertcat(*parts)], ["q", "v"], ["velocities"])


def split_velocities(robot, values: np.ndarray) -> dict:
    """`velocities_function`'s output vector as `MeasuredVelocities`' fields (views of `values`)."""
    n_feet = len(robot.feet)
    ee = 3 * n_feet + (3 if robot.arm_ee else 0)
    out = {"foot_velocity_m_s": values[: 3 * n_feet].reshape(n_feet, 3),
           "ee_velocity_measured_m_s": values[3 * n_feet : ee] if robot.arm_ee else None}
    if robot.soles:
        out["foot_angular_velocity_rad_s"] = values[ee : ee + 3 * n_feet].reshape(n_feet, 3)
    return out


class MeasuredVelocities:
    """`(q, v)` -> {"foot_velocity_m_s": (n_feet, 3), "ee_velocity_measured_m_s": (3,) or None, and with flat feet
    "foot_angular_velocity_rad_s": (n_feet, 3)} (`StageBounds`' fields), by `function` (a `BufferedFunction` of
    `velocities_function`: the arrays are views of its output, valid until its next call) or by pinocchio."""

    def __init__(self, robot, function=None):
        self.robot, self.function = robot, function
        self._data = robot.model.createData()
        self._foot_ids = [robot.frame_id(robot.contact_frame(foot)) for foot in robot.feet]  # soles of flat feet
        self._ee_id = robot.frame_id(robot.arm_ee) if robot.arm_ee else None

    def __call__(self, q: np.ndarray, v: np.ndarray) -> dict:
        robot = self.robot
        if self.function is not None:
            return split_velocities(robot, self.function(q, v)[0])
        model, data = robot.model, self._data
        pin.forwardKinematics(model, data, q, v)

        def velocity(frame_id):
            return pin.getFrameVelocity(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)

        values = {"foot_velocity_m_s": np.array([velocity(i).linear for i in self._foot_ids]),
                  "ee_velocity_measured_m_s": velocity(self._ee_id).linear if self._ee_id is not None else None}
        if robot.soles:
            values["foot_angular_velocity_rad_s"] = np.array([velocity(i).angular for i in self._foot_ids])
        return values
