"""Plants: MuJoCo simulation (default) and a pinocchio contact-dynamics plant (benchmarks).

Every plant implements `Plant`: `reset(q, v)`, `step(tau_joints)`, `state() -> (q, v)`,
`time_s`, `apply_base_velocity_kick(dv_world_m_s)`, `contact_forces()` and `recording`, with
states in pinocchio layout (see `wbmpc.sim.base`).
"""

import numpy as np

from wbmpc.sim.base import (
    Plant,
    PlantConfig,
    PlantDivergedError,
    PlantInputError,
    Recording,
)

PLANTS = ("mujoco", "pinocchio")

__all__ = [
    "PLANTS",
    "MujocoPlant",
    "MujocoPlantConfig",
    "PinocchioPlant",
    "PinocchioPlantConfig",
    "Plant",
    "PlantConfig",
    "PlantDivergedError",
    "PlantInputError",
    "Recording",
    "make_plant",
    "robot_plant_config",
]


def __getattr__(name: str):
    # plants are imported lazily: `import wbmpc.sim` must not pay for MuJoCo when only pinocchio is used
    if name in ("MujocoPlant",):
        from wbmpc.sim.mujoco_plant import MujocoPlant

        return MujocoPlant
    if name == "MujocoPlantConfig":
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        return MujocoPlantConfig
    if name in ("PinocchioPlant", "PinocchioPlantConfig"):
        from wbmpc.sim import pinocchio_plant

        return getattr(pinocchio_plant, name)
    raise AttributeError(f"module 'wbmpc.sim' has no attribute '{name}'")


def robot_plant_config(robot) -> PlantConfig | None:
    """The plant settings a robot brings itself: its rotor inertias on the plant's joints (`RobotSpec.armature_kg_m2`,
    g1's), and an MJCF robot's file its joints' armature, damping and frictionloss (the physical robot the file
    describes, whatever the controller's model assumes); None where it has none (the plant's defaults)."""
    armature = dict(zip(robot.joint_names, map(float, robot.armature_kg_m2)))
    if getattr(robot, "mjcf", None) is not None:
        from wbmpc.robots.mjcf import drive_train, mjcf_joints

        own = drive_train(robot.mjcf, [n for n in robot.joint_names if n in mjcf_joints(robot.mjcf)])
        return PlantConfig(joint_armature_kg_m2={**armature, **own["armature_kg_m2"]},
                           joint_damping_nm_s_per_rad=own["viscous_friction_nm_s"],
                           joint_frictionloss_nm=own["coulomb_friction_nm"])
    if not np.any(robot.armature_kg_m2):
        return None
    return PlantConfig(joint_armature_kg_m2=armature)


def make_plant(kind: str, robot, config: PlantConfig | None = None) -> Plant:
    """A plant by name: 'mujoco' (default simulator) or 'pinocchio' (contact dynamics without MuJoCo).

    Without a config, the plant's joints get the robot's own rotor inertias (`robot_plant_config`), as the scenario
    runner gives them: without them `bench mpc`'s pinocchio plant drove g1's lifted ankle roll to
    110 rad/s (an explicit damper unstable at the 1 ms tick) and half of its walk's QPs failed."""
    config = config if config is not None else robot_plant_config(robot)
    if kind == "mujoco":
        from wbmpc.sim.mujoco_plant import MujocoPlant

        return MujocoPlant(robot, config)
    if kind == "pinocchio":
        from wbmpc.sim.pinocchio_plant import PinocchioPlant

        return PinocchioPlant(robot, config)
    raise PlantInputError(f"unknown plant '{kind}'; available plants: mujoco, pinocchio")
