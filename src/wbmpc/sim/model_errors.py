"""`ModelErrors`: how the simulated plant differs from the controller's model (sim-to-real gaps).

The paper's sim-to-real findings (section VI: base CoM about 60 % rearward of the URDF's, rotor
inertia, motor friction) are questions of maps over such differences. Every option edits only
the MuJoCo scene (through `MujocoPlantConfig.spec_callback` and the shared `PlantConfig`
fields); the MPC keeps the nominal `RobotModel`.

- `base_com_offset_m`: the base's centre of mass moved by this vector (base frame, m);
- `link_mass_scale`: every link's mass and rotational inertia multiplied by this factor (base
  included; its inertia about the CoM scales with the mass);
- `link_mass_noise_rel` + `seed`: on top, each body gets its own factor 1 + N(0, noise);
- `ee_payload_kg`: a point-like mass (sphere of `payload_radius_m`) rigidly attached at the arm
  end-effector frame;
- `joint_armature_kg_m2`, `joint_damping_nm_s_per_rad`, `joint_frictionloss_nm`: rotor inertia,
  viscous and dry (Coulomb) friction in every plant joint (MuJoCo `armature`, `damping`, `frictionloss`);
- `floor_friction_mu`: the floor's friction coefficient (the MPC keeps its own assumed value).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wbmpc.robots import RobotModel
from wbmpc.sim.base import DRIVE_TRAIN_FIELDS, PlantConfig, PlantInputError


@dataclass(frozen=True)
class ModelErrors:
    base_com_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    link_mass_scale: float = 1.0
    link_mass_noise_rel: float = 0.0
    ee_payload_kg: float = 0.0
    payload_radius_m: float = 0.03
    joint_armature_kg_m2: float | None = None  # None: the plant's default
    joint_damping_nm_s_per_rad: float | None = None
    joint_frictionloss_nm: float | None = None
    floor_friction_mu: float | None = None
    seed: int = 0

    def __post_init__(self):
        offset = np.asarray(self.base_com_offset_m, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)) or np.linalg.norm(offset) > 0.5:
            raise PlantInputError(f"base_com_offset_m must be 3 finite numbers within 0.5 m, got {self.base_com_offset_m}")
        if not (np.isfinite(self.link_mass_scale) and 0.2 <= self.link_mass_scale <= 5.0):
            raise PlantInputError(f"link_mass_scale must be in [0.2, 5] (a factor on every link mass), got {self.link_mass_scale}")
        if not (np.isfinite(self.link_mass_noise_rel) and 0 <= self.link_mass_noise_rel <= 0.5):
            raise PlantInputError(f"link_mass_noise_rel must be in [0, 0.5], got {self.link_mass_noise_rel}")
        if not (np.isfinite(self.ee_payload_kg) and self.ee_payload_kg >= 0):
            raise PlantInputError(f"ee_payload_kg must be a mass >= 0 kg, got {self.ee_payload_kg}")
        if not self.payload_radius_m > 0:
            raise PlantInputError(f"payload_radius_m must be positive, got {self.payload_radius_m}")
        for name in ("joint_armature_kg_m2", "joint_damping_nm_s_per_rad", "joint_frictionloss_nm", "floor_friction_mu"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value >= 0):
                raise PlantInputError(f"{name} must be a finite number >= 0 (or None for the plant default), got {value}")

    @property
    def is_nominal(self) -> bool:
        return self == ModelErrors(seed=self.seed)

    def plant_config(self, robot: RobotModel, config: PlantConfig | None = None):
        """`config` (default: the MuJoCo defaults) with these errors applied; scene callbacks are kept."""
        from wbmpc.sim.base import specialised_config
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        if config is not None and not isinstance(config, (PlantConfig,)):
            raise PlantInputError(f"model errors apply to a PlantConfig, got {type(config).__name__}")
        config = specialised_config(config, MujocoPlantConfig)
        shared = {name: getattr(self, name) for name in DRIVE_TRAIN_FIELDS if getattr(self, name) is not None}
        if self.floor_friction_mu is not None:
            shared["friction_mu"] = self.floor_friction_mu
        previous = config.spec_callback

        def callback(spec) -> None:
            if previous is not None:
                previous(spec)
            self.edit_spec(robot, spec)

        return replace(config, spec_callback=callback, **shared)

    def edit_spec(self, robot: RobotModel, spec) -> None:
        """Apply the inertial errors to a `mujoco.MjSpec` of `robot` built by `wbmpc.sim.mujoco_scene`."""
        from wbmpc.sim.mujoco_scene import scene_bodies

        bodies = scene_bodies(spec, robot)
        names = list(dict.fromkeys(bodies.names))  # a plant model's body may carry several merged links
        rng = np.random.default_rng(self.seed)
        for name in names:
            body = spec.body(name)
            factor = self.link_mass_scale
            if self.link_mass_noise_rel:
                factor *= max(0.1, 1.0 + rng.normal(0.0, self.link_mass_noise_rel))
            if factor != 1.0:
                body.mass = body.mass * factor
                if np.all(np.isfinite(body.fullinertia)):
                    body.fullinertia = np.asarray(body.fullinertia) * factor
                else:  # a plant model's file gives principal moments (diaginertia)
                    body.inertia = np.asarray(body.inertia) * factor
        base = spec.body(names[0])
        base.ipos = np.asarray(base.ipos) + np.asarray(self.base_com_offset_m, dtype=float)
        if self.ee_payload_kg > 0:
            if robot.arm_ee is None:
                raise PlantInputError(f"ee_payload_kg needs a robot with an arm end-effector; {robot.name} has none")
            body, placement = bodies.frame(robot, robot.arm_ee)
            parent = spec.body(body)
            inertia = 0.4 * self.ee_payload_kg * self.payload_radius_m**2
            parent.add_body(name="ee_payload", pos=np.asarray(placement.translation, dtype=float),
                            ipos=[0.0, 0.0, 0.0], mass=self.ee_payload_kg, inertia=[inertia] * 3,
                            explicitinertial=True)
