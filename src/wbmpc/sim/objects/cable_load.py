"""`CableLoad`: a box on the floor tied to the end-effector by a massless cable (a MuJoCo spatial tendon with a
length limit: it pulls, never pushes). Measured: the cable tension and the force along the cable."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from wbmpc.sim.objects.common import (
    EE_SITE,
    add_ee_site,
    check_positive,
    mjcf_friction,
    mjcf_vector,
    planar_box_state,
    replay_box,
)


@dataclass(frozen=True)
class CableLoad:
    """A load of `mass_kg` on the floor, its hook `cable_length_m` of cable away from the end-effector.

    `position_m` is the load centre on the floor (world x, y); the hook is on the load's face
    towards -x (the robot) at `hook_height_m`. The cable is a tendon with a length limit, soft
    like a stiff rope (`cable_timeconst_s`); its tension is the force of that limit constraint.
    """

    mass_kg: float = 10.0
    friction_mu: float = 0.3
    position_m: tuple[float, float] = (2.0, 0.0)
    size_m: tuple[float, float, float] = (0.3, 0.3, 0.2)
    hook_height_m: float = 0.1
    cable_length_m: float = 1.6
    cable_timeconst_s: float = 0.02
    name: str = "load"

    def __post_init__(self):
        check_positive("load mass (kg)", self.mass_kg)
        check_positive("load friction coefficient", self.friction_mu, allow_zero=True)
        check_positive("cable length (m)", self.cable_length_m)
        for s in self.size_m:
            check_positive("load size (m)", s)

    @property
    def hook_m(self) -> np.ndarray:
        """World position of the hook when the load rests at `position_m`."""
        return np.array([self.position_m[0] - self.size_m[0] / 2, self.position_m[1], self.hook_height_m])

    def bodies_mjcf(self, robot):
        sx, sy, sz = self.size_m
        x, y = self.position_m
        return [
            f'<body name="{self.name}" pos="{mjcf_vector([x, y, sz / 2])}"><freejoint name="{self.name}_joint"/>'
            f'<geom name="{self.name}" type="box" size="{mjcf_vector([sx / 2, sy / 2, sz / 2])}" mass="{self.mass_kg!r}" '
            f'friction="{mjcf_friction(self.friction_mu)}" priority="2" rgba=".8 .5 .2 1"/>'
            f'<site name="{self.name}_hook" pos="{mjcf_vector([-sx / 2, 0.0, self.hook_height_m - sz / 2])}" size="0.015"/>'
            "</body>"
        ]

    def edit_spec(self, spec, robot):
        add_ee_site(spec, robot)
        tendon = spec.add_tendon(name=f"{self.name}_cable")
        tendon.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        tendon.range = [0.0, self.cable_length_m]
        tendon.solref_limit = [self.cable_timeconst_s, 1.0]
        tendon.width = 0.005
        tendon.rgba = [0.1, 0.1, 0.1, 1.0]
        tendon.wrap_site(EE_SITE)
        tendon.wrap_site(f"{self.name}_hook")

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        m, d = plant.model, plant.data
        tid = m.tendon(f"{self.name}_cable").id
        n = d.nefc
        rows = (d.efc_type[:n] == mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON) & (d.efc_id[:n] == tid)
        tension = float(np.sum(d.efc_force[:n][rows]))
        ee, hook = d.site(EE_SITE).xpos, d.site(f"{self.name}_hook").xpos
        towards_ee = (ee - hook) / max(np.linalg.norm(ee - hook), 1e-9)
        return {
            "tension_n": tension,
            "force_n": tension * towards_ee,  # the end-effector pulls the cable towards itself
            **planar_box_state(plant, self.name),
            "cable_m": np.array([ee, hook]),
        }

    def replay_shapes(self, recording):
        t, position = recording.series(self.name, "object_position_m")
        _, rotation = recording.series(self.name, "object_rotation")
        _, cable = recording.series(self.name, "cable_m")
        return [replay_box(self.name, "#cc8033", np.asarray(self.size_m) / 2, position, rotation, t),
                {"name": f"{self.name} cable", "kind": "line", "color": "#1a1a1a", "t": t, "points_m": cable}]
