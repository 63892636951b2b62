"""`Board`: a fixed board (vertical like a whiteboard, or horizontal like a table) with its own friction.
Measured: the contact force of the end-effector sphere on the board."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.sim.objects.common import check_positive, mjcf_friction, mjcf_vector, replay_box


@dataclass(frozen=True)
class Board:
    """A fixed board to wipe: `normal` is the direction from the board face towards the robot side.

    `vertical` boards face -x (a whiteboard in front of the robot; `face_m` is a point of the
    face); `horizontal` boards face +z (a table top at `face_m[2]`).
    """

    orientation: str = "vertical"
    face_m: tuple[float, float, float] = (0.5, 0.0, 0.8)
    size_m: tuple[float, float] = (1.0, 0.8)  # in-plane extent
    centre_offset_m: tuple[float, float] = (0.0, 0.0)  # board centre from `face_m`, along `plane_axes`
    thickness_m: float = 0.04
    friction_mu: float = 0.3
    contact_timeconst_s: float = 0.02  # a wiping pad is soft
    # contacts act from this distance on, and the geom sits this much behind `face_m` so the
    # effective surface is at `face_m`: without it, sliding with friction chatters (contact lost
    # and re-made every few steps)
    contact_margin_m: float = 0.003
    name: str = "board"

    def __post_init__(self):
        if self.orientation not in ("vertical", "horizontal"):
            raise ConfigError(f"board orientation must be 'vertical' or 'horizontal', got {self.orientation!r}")
        check_positive("board friction coefficient", self.friction_mu, allow_zero=True)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the face, pointing out of the board (towards the end-effector)."""
        return np.array([-1.0, 0.0, 0.0]) if self.orientation == "vertical" else np.array([0.0, 0.0, 1.0])

    @property
    def plane_axes(self) -> np.ndarray:
        """(2, 3) in-plane unit axes (horizontal first)."""
        if self.orientation == "vertical":
            return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

    def boxes(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(name, centre, half sizes) in world of the board and, for a table, the block under it."""
        face = np.asarray(self.face_m, dtype=float) - self.normal * self.contact_margin_m
        face = face + self.plane_axes.T @ np.asarray(self.centre_offset_m, dtype=float)
        centre = face - self.normal * self.thickness_m / 2
        half = np.abs(self.plane_axes.T @ (np.asarray(self.size_m) / 2)) + np.abs(self.normal) * self.thickness_m / 2
        out = [(self.name, centre, half)]
        if self.orientation == "horizontal":  # a table: the top rests on a block under its far edge
            height = centre[2] - self.thickness_m / 2
            leg = min(0.1, half[0])
            out.append((f"{self.name}_stand", np.array([centre[0] + half[0] - leg, centre[1], height / 2]),
                        np.array([leg, half[1] * 0.8, height / 2])))
        return out

    def replay_shapes(self, recording):
        return [replay_box(name.replace("_", " "), "#f2f2f2" if k == 0 else "#806633", half, centre)
                for k, (name, centre, half) in enumerate(self.boxes())]

    def bodies_mjcf(self, robot):
        (_, centre, half), *stand = self.boxes()
        bodies = [
            f'<body name="{self.name}" pos="{mjcf_vector(centre)}"><geom name="{self.name}" type="box" size="{mjcf_vector(half)}" '
            f'friction="{mjcf_friction(self.friction_mu)}" priority="2" solref="{mjcf_vector([self.contact_timeconst_s, 1.0])}" '
            f'margin="{self.contact_margin_m!r}" '
            'rgba=".95 .95 .95 1"/></body>'
        ]
        for name, stand_centre, stand_half in stand:
            bodies.append(f'<body name="{name}" pos="{mjcf_vector(stand_centre)}"><geom name="{name}" type="box" '
                          f'size="{mjcf_vector(stand_half)}" rgba=".5 .4 .3 1"/></body>')
        return bodies

    def edit_spec(self, spec, robot):
        pass

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        return {"force_n": -plant.ee_contact_force([self.name])}
