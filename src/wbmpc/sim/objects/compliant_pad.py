"""`CompliantPad`: a sprung wiping pad on the end-effector (keeps a sliding contact closed)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from wbmpc.sim.mujoco_scene import ROBOT_CONAFFINITY, ROBOT_CONTYPE
from wbmpc.sim.objects.common import check_positive, ee_body


@dataclass(frozen=True)
class CompliantPad:
    """A sprung wiping pad on the end-effector: a light sphere (the pad) on three orthogonal slide
    joints with springs and dampers, replacing the rigid end-effector sphere at the same place.

    A real wiping tool is compliant (a sponge, a spring-loaded holder). Between the arm's inertia
    and a rigid sliding contact, MuJoCo's contact makes and breaks at ~200 Hz (the contact chatters);
    the spring keeps the pad pressed on while the arm moves, so the force on the board follows the
    arm's force. The spring is isotropic, `stiffness_n_m` per axis, damped at `damping_ratio` of
    critical for the pad's `mass_kg`; at 10 N and 2000 N/m it compresses 5 mm. The MPC does not
    model the pad (its mass is a few grams against the arm's kilograms).
    """

    stiffness_n_m: float = 2000.0
    damping_ratio: float = 1.0
    mass_kg: float = 0.05
    radius_m: float = 0.03
    name: str = "pad"

    def __post_init__(self):
        check_positive("pad stiffness (N/m)", self.stiffness_n_m)
        check_positive("pad damping ratio", self.damping_ratio, allow_zero=True)
        check_positive("pad mass (kg)", self.mass_kg)
        check_positive("pad radius (m)", self.radius_m)

    @property
    def damping_n_s_m(self) -> float:
        return 2.0 * self.damping_ratio * float(np.sqrt(self.stiffness_n_m * self.mass_kg))

    def bodies_mjcf(self, robot):
        return []

    def edit_spec(self, spec, robot):
        body, position = ee_body(spec, robot)
        for geom in list(body.geoms):  # the rigid end-effector sphere gives way to the pad
            if geom.name == robot.arm_ee:
                spec.delete(geom)
        inertia = 0.4 * self.mass_kg * self.radius_m**2
        pad = body.add_body(name=self.name, pos=position.tolist(), mass=self.mass_kg,
                            inertia=[inertia] * 3, explicitinertial=True)
        for axis, label in zip(np.eye(3), "xyz"):
            pad.add_joint(name=f"{self.name}_{label}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=axis.tolist(),
                          stiffness=self.stiffness_n_m, damping=self.damping_n_s_m, range=[-0.03, 0.03], limited=True)
        pad.add_geom(name=self.name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[self.radius_m, 0, 0],
                     contype=ROBOT_CONTYPE, conaffinity=ROBOT_CONAFFINITY, rgba=[0.95, 0.75, 0.2, 1.0])

    def before_step(self, plant) -> None:
        pass

    def measure(self, plant):
        d = plant.data
        return {"deflection_m": np.array([d.joint(f"{self.name}_{a}").qpos[0] for a in "xyz"])}

    def replay_shapes(self, recording):
        return []  # the replay draws the end-effector itself
