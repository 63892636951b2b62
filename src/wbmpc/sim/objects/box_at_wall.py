"""`BoxAtWall`: a free box on the floor standing against a fixed wall. Measured: the contact force of the
end-effector sphere on the box."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.sim.objects.common import check_box, free_box_mjcf, mjcf_vector, replay_box


@dataclass(frozen=True)
class BoxAtWall:
    """A free box of `mass_kg` on the floor whose far face (+x) touches a fixed wall.

    `near_face_x_m` is the world x of the face the end-effector pushes; the box spans
    `size_m` (depth x, width y, height z) behind it, then comes the wall.
    """

    near_face_x_m: float = 0.5
    mass_kg: float = 5.0
    friction_mu: float = 0.5
    size_m: tuple[float, float, float] = (0.3, 0.5, 1.0)
    wall_thickness_m: float = 0.1
    name: str = "box"

    def __post_init__(self):
        check_box(self.mass_kg, self.friction_mu, self.size_m)

    def bodies_mjcf(self, robot):
        sx = self.size_m[0]
        cx = self.near_face_x_m + sx / 2
        wall_x = self.near_face_x_m + sx + self.wall_thickness_m / 2 + 1e-3
        return [
            free_box_mjcf(self.name, (cx, 0.0), self.size_m, self.mass_kg, self.friction_mu),
            f'<body name="{self.name}_wall" pos="{mjcf_vector([wall_x, 0.0, 1.0])}">'
            f'<geom name="{self.name}_wall" type="box" size="{mjcf_vector([self.wall_thickness_m / 2, 1.5, 1.0])}" '
            'rgba=".75 .75 .7 1"/></body>',
        ]

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        body = plant.data.body(self.name)
        return {"force_n": -plant.ee_contact_force([self.name]), "object_position_m": body.xpos.copy(),
                "object_rotation": body.xmat.reshape(3, 3).copy()}

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        sx, sy, sz = self.size_m
        wall_x = self.near_face_x_m + sx + self.wall_thickness_m / 2 + 1e-3
        return [replay_box(self.name, "#99734d", np.asarray(self.size_m) / 2, position, rotation, t),
                replay_box(f"{self.name} wall", "#bfbfb3", [self.wall_thickness_m / 2, 1.5, 1.0], [wall_x, 0.0, 1.0])]
