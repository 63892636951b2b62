"""A humanoid's safety gantry in `robot-sim` (`--gantry`): a strap from above the robot's start to a point above its
base, slack while the robot stands and walks, carrying it once the base sinks `slack_m` below its standing height.

Humanoids are run on hardware under such a gantry: their safe stop (damping) lets them sink into the strap, as
unitree_mujoco's elastic band does in Unitree's simulator. The strap pulls only when taut: a spring of
`stiffness_n_m` (the robot's weight stretches it `stretch_m`) with critical damping along the strap, applied
at the attachment point on the base. `taut_since_s` and `max_force_n` tell whether it ever carried the robot.
"""

from __future__ import annotations

import mujoco
import numpy as np

STRAP_LENGTH_M = 1.0  # anchor height above the attachment point at the standing height
ATTACHMENT_ABOVE_BASE_M = 0.3  # the strap holds the base at this height above its origin (base frame z)


class Gantry:
    """A MuJoCo step hook (`plant.add_step_hook`) pulling the base of `robot` up on a strap."""

    def __init__(self, plant, robot, slack_m: float | None = None, stretch_m: float = 0.05):
        model = plant.model
        self.body = model.body(plant.body_name(1)).id
        q, _ = plant.state()
        mass_kg = float(np.sum(model.body_mass))
        self.slack_m = 0.3 * robot.q_nominal[2] if slack_m is None else slack_m
        self.stiffness_n_m = mass_kg * 9.81 / stretch_m
        self.damping_n_s_m = 2.0 * np.sqrt(self.stiffness_n_m * mass_kg)
        standing = np.array([q[0], q[1], robot.q_nominal[2] + ATTACHMENT_ABOVE_BASE_M])
        self.anchor = standing + np.array([0.0, 0.0, STRAP_LENGTH_M])
        self.rest_length_m = STRAP_LENGTH_M + self.slack_m
        self.taut_since_s: float | None = None
        self.max_force_n = 0.0

    def _attachment(self, data) -> np.ndarray:
        return data.xpos[self.body] + data.xmat[self.body].reshape(3, 3) @ np.array([0.0, 0.0, ATTACHMENT_ABOVE_BASE_M])

    def before_step(self, plant) -> None:
        model, data = plant.model, plant.data
        point = self._attachment(data)
        strap = self.anchor - point
        length = float(np.linalg.norm(strap))
        data.xfrc_applied[self.body] = 0.0
        if length <= self.rest_length_m:
            return
        direction = strap / length
        velocity = np.zeros(6)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, self.body, velocity, 0)  # [angular, linear] world
        point_velocity = velocity[3:] + np.cross(velocity[:3], point - data.xpos[self.body])
        tension = self.stiffness_n_m * (length - self.rest_length_m) - self.damping_n_s_m * float(point_velocity @ direction)
        if tension <= 0.0:
            return
        force = tension * direction
        data.xfrc_applied[self.body, :3] = force
        data.xfrc_applied[self.body, 3:] = np.cross(point - data.xipos[self.body], force)
        self.max_force_n = max(self.max_force_n, tension)
        if self.taut_since_s is None:
            self.taut_since_s = plant.time_s

    def after_step(self, plant) -> None:
        pass

    def summary(self, t0_s: float) -> dict:
        """When the strap first carried the robot (seconds after `t0_s`, None: never) and its largest pull."""
        return {"slack_m": self.slack_m, "taut_since_s": None if self.taut_since_s is None else self.taut_since_s - t0_s,
                "max_force_n": self.max_force_n}
