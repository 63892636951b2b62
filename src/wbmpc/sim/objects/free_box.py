"""`FreeBox`: a free box on the floor to push along a path. Measured: the end-effector's contact force on it and its
planar state (`planar_state`: x, y, yaw, vx, vy, wz), which `--object-model` feeds to the MPC."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.sim.objects.common import check_box, free_box_mjcf, planar_box_state, replay_box


@dataclass(frozen=True)
class FreeBox:
    """A free box of `mass_kg` on the floor (no wall) for the end-effector to push along a path.

    `near_face_x_m` is the world x of the face the end-effector pushes (the box's -x face at the start);
    its friction `friction_mu` is that of the floor and of the end-effector on it (priority: MuJoCo uses
    the box's coefficient in both contacts). Wide and deep for its height, so that the push at the hand's
    height (~0.87 m on b1_z1) slides it without tipping it (mu h < depth / 2). The object model of the MPC
    (`wbmpc.ocp.objects.SlidingBox.from_scene`) reads these same numbers. Measured: the end-effector's
    contact force on the box and its planar state [x, y, yaw, vx, vy, wz] (`planar_state`).
    """

    near_face_x_m: float = 0.45
    mass_kg: float = 5.0
    friction_mu: float = 0.3
    size_m: tuple[float, float, float] = (0.6, 0.6, 1.0)
    name: str = "box"

    def __post_init__(self):
        check_box(self.mass_kg, self.friction_mu, self.size_m)

    @property
    def centre_xy_m(self) -> np.ndarray:
        return np.array([self.near_face_x_m + self.size_m[0] / 2, 0.0])

    def bodies_mjcf(self, robot):
        return [free_box_mjcf(self.name, self.centre_xy_m, self.size_m, self.mass_kg, self.friction_mu)]

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        return {"force_n": -plant.ee_contact_force([self.name]), **planar_box_state(plant, self.name)}

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        return [replay_box(self.name, "#99734d", np.asarray(self.size_m) / 2, position, rotation, t)]

