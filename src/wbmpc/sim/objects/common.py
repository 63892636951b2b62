"""What every scene object shares: the end-effector site, MJCF text helpers, replay boxes, the `SceneObject`
protocol (see `wbmpc.sim.objects`)."""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.robots import RobotModel
from wbmpc.sim.mujoco_scene import scene_bodies

EE_SITE = "ee_attach"


def ee_body(spec: mujoco.MjSpec, robot: RobotModel):
    """(MuJoCo body carrying the arm end-effector frame, the frame's position in that body) in the scene `spec` builds."""
    name, placement = scene_bodies(spec, robot).frame(robot, robot.arm_ee)
    return spec.body(name), placement.translation.copy()


def check_positive(name: str, value: float, allow_zero: bool = False) -> None:
    ok = value >= 0 if allow_zero else value > 0
    if not (np.isfinite(value) and ok):
        raise ConfigError(f"{name} must be {'>= 0' if allow_zero else 'positive'}, got {value}")


def mjcf_vector(values) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(values, dtype=float).ravel())


def replay_box(name: str, color: str, half_size_m, position_m, rotation=None, t=None) -> dict:
    """A box for the replay: static (one pose) or moving (`t` and one pose per time)."""
    shape = {"name": name, "kind": "box", "color": color, "half_size_m": np.asarray(half_size_m, dtype=float),
             "position_m": np.asarray(position_m, dtype=float),
             "rotation": np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)}
    if t is not None:
        shape["t"] = np.asarray(t, dtype=float)
    return shape


def mjcf_friction(mu: float) -> str:
    return mjcf_vector([mu, 0.005, 0.0001])


class SceneObject(Protocol):
    name: str

    def bodies_mjcf(self, robot: RobotModel) -> list[str]: ...

    def edit_spec(self, spec: mujoco.MjSpec, robot: RobotModel) -> None: ...

    def before_step(self, plant) -> None: ...

    def measure(self, plant) -> dict[str, np.ndarray | float]: ...

    def replay_shapes(self, recording) -> list[dict]: ...  # recording: a `SceneRecording`


def check_box(mass_kg: float, friction_mu: float, size_m) -> None:
    check_positive("box mass (kg)", mass_kg)
    check_positive("box friction coefficient", friction_mu, allow_zero=True)
    for s in size_m:
        check_positive("box size (m)", s)


def free_box_mjcf(name: str, centre_xy_m, size_m, mass_kg: float, friction_mu: float) -> str:
    """A box on the floor with a free joint (priority 2: its friction is the contact's, with floor and hand)."""
    sx, sy, sz = size_m
    return (f'<body name="{name}" pos="{mjcf_vector([centre_xy_m[0], centre_xy_m[1], sz / 2 + 1e-3])}">'
            f'<freejoint name="{name}_joint"/>'
            f'<geom name="{name}" type="box" size="{mjcf_vector([sx / 2, sy / 2, sz / 2])}" mass="{mass_kg!r}" '
            f'friction="{mjcf_friction(friction_mu)}" priority="2" rgba=".6 .45 .3 1"/></body>')


def add_ee_site(spec: mujoco.MjSpec, robot: RobotModel) -> None:
    """A site at the end-effector frame origin (cable attachment, hand contact point), added once."""
    body, position = ee_body(spec, robot)
    if any(s.name == EE_SITE for s in body.sites):
        return
    body.add_site(name=EE_SITE, pos=position.tolist(), size=[0.01, 0.01, 0.01])

def planar_box_state(plant, name: str) -> dict:
    """Position, rotation and the planar state [x, y, yaw, vx, vy, wz] (world) of a free body."""
    body = plant.data.body(name)
    rotation = body.xmat.reshape(3, 3).copy()
    qvel = plant.data.joint(f"{name}_joint").qvel  # free joint: world linear, local angular velocity
    yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
    angular = rotation @ qvel[3:6]
    return {"object_position_m": body.xpos.copy(), "object_rotation": rotation,
            "planar_state": np.array([body.xpos[0], body.xpos[1], yaw, qvel[0], qvel[1], angular[2]])}
