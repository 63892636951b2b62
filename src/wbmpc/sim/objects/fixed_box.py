"""`FixedBox`: a box fixed in the world (a post to reach around). Measured: whether the robot touches it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.sim.objects.common import check_positive, mjcf_vector, replay_box


@dataclass(frozen=True)
class FixedBox:
    """A box fixed in the world (a post, a shelf) that the robot must not touch: `centre_m` and
    `half_size_m` along the world axes. Measured: whether any robot geom touches it (`touching`, 0/1)
    and the force of the end-effector sphere on it. Collision avoidance sees the same box as
    `wbmpc.robots.collision_model.Obstacle` (`obstacle()`)."""

    centre_m: tuple[float, float, float] = (0.8, 0.0, 0.5)
    half_size_m: tuple[float, float, float] = (0.05, 0.05, 0.5)
    name: str = "post"

    def __post_init__(self):
        for s in self.half_size_m:
            check_positive("box half size (m)", s)

    def obstacle(self, keep_off: tuple[str, ...] = ("arm", "feet")):
        from wbmpc.robots.collision_model import Obstacle

        return Obstacle(self.name, tuple(self.centre_m), tuple(self.half_size_m), keep_off)

    def bodies_mjcf(self, robot):
        return [f'<body name="{self.name}" pos="{mjcf_vector(self.centre_m)}"><geom name="{self.name}" type="box" '
                f'size="{mjcf_vector(self.half_size_m)}" rgba=".85 .3 .25 1"/></body>']

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        d, m = plant.data, plant.model
        n = d.ncon
        touching = 0.0
        if n:
            box = m.geom(self.name).id
            geoms = d.contact.geom[:n]
            other = np.where(geoms[:, 0] == box, geoms[:, 1], np.where(geoms[:, 1] == box, geoms[:, 0], -1))
            other = other[other >= 0]
            touching = float(bool(np.any(plant.layout.robot_geoms[other])))
        return {"touching": touching, "force_n": -plant.ee_contact_force([self.name])}

    def replay_shapes(self, recording):
        return [replay_box(self.name, "#d94d40", self.half_size_m, self.centre_m)]


def contact_count(t: np.ndarray, touching: np.ndarray) -> dict:
    """Touches (a step touching after one that did not) and time in contact of a 0/1 series at physics steps."""
    touching = np.asarray(touching, dtype=bool)
    starts = int(touching[0]) + int(np.sum(touching[1:] & ~touching[:-1])) if len(touching) else 0
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return {"contacts": starts, "time_s": float(touching.sum() * dt)}
