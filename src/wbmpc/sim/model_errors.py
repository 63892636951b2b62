"""`ModelErrors`: how the simulated plant differs from the controller's model (sim-to-real gaps).

The paper's sim-to-real findings (section VI: base CoM about 60 % rearward of the URDF's, rotor
inertia, motor friction) are questions of maps over such differences. Every option edits only
the MuJoCo scene (through `MujocoPlantConfig.spec_callback` and the shared `PlantConfig`
fields); the MPC keeps the nominal `RobotModel`.

- `base_com_offset_m`: the base's centre of mass moved by this vector (base frame, m);
- `link_mass_scale`: every link's mass and rotational inertia multiplied by this factor (base
  included; its inertia about the CoM scales with the mass);
- `link_mass_noise_rel` + `seed`: on top, each body gets its own factor 1 + N(0, noise);
- `link_mass_spread_rel` + `seed`: on top, each body gets its own factor uniform in [1 - s, 1 + s] (the reality
  gap's draw, `wbmpc campaign --randomize`); `link_factors` lists every body's factor;
- `base_payload_kg`: a point-like mass rigidly attached at the base origin (what the inertial identification
  estimates as the payload of a robot without an arm);
- `ee_payload_kg`: a point-like mass (sphere of `payload_radius_m`) rigidly attached at the arm
  end-effector frame;
- `joint_armature_kg_m2`, `joint_damping_nm_s_per_rad`, `joint_frictionloss_nm`: rotor inertia,
  viscous and dry (Coulomb) friction in every plant joint (MuJoCo `armature`, `damping`, `frictionloss`);
- `joint_armature_scale`, `joint_damping_scale`, `joint_frictionloss_scale`: the same three as factors on the
  robot's reference drive train (`reference_drive_train`), per joint;
- `floor_friction_mu`: the floor's friction coefficient (the MPC keeps its own assumed value).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from wbmpc.robots import RobotModel
from wbmpc.sim.base import DRIVE_TRAIN_FIELDS, PlantConfig, PlantInputError

# a drive train where the robot's model gives none: Unitree's Go2 MJCF (unitree_mujoco's go2.xml: armature 0.01
# kg m^2, damping 0.1 N m s/rad, frictionloss 0.2 N m on every joint) scaled per joint by its torque limit over
# the Go2's mean leg limit (30.9 N m: 23.7, 23.7, 45.43): B2's file (200-300 N m) has 0.1 and 1 where this gives
# 0.075 and 0.75
GO2_DRIVE_TRAIN = {"joint_armature_kg_m2": 0.01, "joint_damping_nm_s_per_rad": 0.1, "joint_frictionloss_nm": 0.2}
GO2_MEAN_LEG_TORQUE_NM = (23.7 + 23.7 + 45.43) / 3
SCALE_FIELDS = {"joint_armature_scale": "joint_armature_kg_m2", "joint_damping_scale": "joint_damping_nm_s_per_rad",
                "joint_frictionloss_scale": "joint_frictionloss_nm"}
_MODEL_DRIVE_TRAIN = {"joint_armature_kg_m2": "armature_kg_m2", "joint_damping_nm_s_per_rad": "viscous_friction_nm_s",
                      "joint_frictionloss_nm": "coulomb_friction_nm"}


def reference_drive_train(robot: RobotModel) -> dict[str, np.ndarray]:
    """{plant field: per-joint value}: the robot model's rotor inertia, viscous and dry friction where it has
    them, else `GO2_DRIVE_TRAIN` scaled by the joint's torque limit (what the reality-gap draw scales)."""
    size = np.asarray(robot.tau_max, dtype=float) / GO2_MEAN_LEG_TORQUE_NM
    out = {}
    for name, model_name in _MODEL_DRIVE_TRAIN.items():
        own = np.broadcast_to(np.asarray(getattr(robot, model_name), dtype=float), (robot.n_joints,))
        out[name] = np.where(own > 0, own, GO2_DRIVE_TRAIN[name] * size)
    return out


@dataclass(frozen=True)
class ModelErrors:
    base_com_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    link_mass_scale: float = 1.0
    link_mass_noise_rel: float = 0.0
    ee_payload_kg: float = 0.0
    base_payload_kg: float = 0.0
    payload_radius_m: float = 0.03
    joint_armature_kg_m2: float | None = None  # None: the plant's default
    joint_damping_nm_s_per_rad: float | None = None
    joint_frictionloss_nm: float | None = None
    floor_friction_mu: float | None = None
    link_mass_spread_rel: float = 0.0
    joint_armature_scale: float | None = None  # None: not applied; a factor on `reference_drive_train`
    joint_damping_scale: float | None = None
    joint_frictionloss_scale: float | None = None
    seed: int = 0

    def __post_init__(self):
        offset = np.asarray(self.base_com_offset_m, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)) or np.linalg.norm(offset) > 0.5:
            raise PlantInputError(f"base_com_offset_m must be 3 finite numbers within 0.5 m, got {self.base_com_offset_m}")
        if not (np.isfinite(self.link_mass_scale) and 0.2 <= self.link_mass_scale <= 5.0):
            raise PlantInputError(f"link_mass_scale must be in [0.2, 5] (a factor on every link mass), got {self.link_mass_scale}")
        if not (np.isfinite(self.link_mass_noise_rel) and 0 <= self.link_mass_noise_rel <= 0.5):
            raise PlantInputError(f"link_mass_noise_rel must be in [0, 0.5], got {self.link_mass_noise_rel}")
        if not (np.isfinite(self.link_mass_spread_rel) and 0 <= self.link_mass_spread_rel <= 0.5):
            raise PlantInputError(f"link_mass_spread_rel must be in [0, 0.5], got {self.link_mass_spread_rel}")
        for name in ("ee_payload_kg", "base_payload_kg"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise PlantInputError(f"{name} must be a mass >= 0 kg, got {getattr(self, name)}")
        if not self.payload_radius_m > 0:
            raise PlantInputError(f"payload_radius_m must be positive, got {self.payload_radius_m}")
        for name in ("joint_armature_kg_m2", "joint_damping_nm_s_per_rad", "joint_frictionloss_nm", "floor_friction_mu",
                     *SCALE_FIELDS):
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
        reference = reference_drive_train(robot)
        for scale_name, name in SCALE_FIELDS.items():
            scale = getattr(self, scale_name)
            if scale is not None:
                shared[name] = dict(zip(robot.joint_names, (float(x) for x in scale * reference[name])))
        if self.floor_friction_mu is not None:
            shared["friction_mu"] = self.floor_friction_mu
        previous = config.spec_callback

        def callback(spec) -> None:
            if previous is not None:
                previous(spec)
            self.edit_spec(robot, spec)

        return replace(config, spec_callback=callback, **shared)

    def link_factors(self, robot: RobotModel, names: list[str] | None = None) -> dict[str, float]:
        """{MuJoCo body: factor on its mass and rotational inertia}, the same for the same seed; `names`: the
        scene's robot bodies (default wbmpc's own scene of `robot`; a plant model's differ)."""
        from wbmpc.sim.mujoco_scene import body_names

        names = body_names(robot) if names is None else names
        rng = np.random.default_rng(self.seed)
        spread = np.random.default_rng([self.seed, 2])  # its own stream: the noise's draws stay as they were
        factors = {}
        for name in names:
            factor = self.link_mass_scale
            if self.link_mass_noise_rel:
                factor *= max(0.1, 1.0 + rng.normal(0.0, self.link_mass_noise_rel))
            if self.link_mass_spread_rel:
                factor *= spread.uniform(1.0 - self.link_mass_spread_rel, 1.0 + self.link_mass_spread_rel)
            factors[name] = float(factor)
        return factors

    def summary(self, robot: RobotModel) -> dict:
        """What the plant was given, for a run's metrics: the fields that differ from nominal, every link's
        factor and the drive train applied per joint."""
        out = {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) != f.default}
        if self.link_mass_noise_rel or self.link_mass_spread_rel or self.link_mass_scale != 1.0:
            out["link_factors"] = self.link_factors(robot)
        reference = reference_drive_train(robot)
        for scale_name, name in SCALE_FIELDS.items():
            scale = getattr(self, scale_name)
            if scale is not None:
                out[name] = dict(zip(robot.joint_names, (float(x) for x in scale * reference[name])))
        return out

    def edit_spec(self, robot: RobotModel, spec) -> None:
        """Apply the inertial errors to a `mujoco.MjSpec` of `robot` built by `wbmpc.sim.mujoco_scene`."""
        from wbmpc.sim.mujoco_scene import scene_bodies

        bodies = scene_bodies(spec, robot)
        names = list(dict.fromkeys(bodies.names))  # a plant model's body may carry several merged links
        for name, factor in self.link_factors(robot, names).items():
            body = spec.body(name)
            if factor != 1.0:
                body.mass = body.mass * factor
                if np.all(np.isfinite(body.fullinertia)):
                    body.fullinertia = np.asarray(body.fullinertia) * factor
                else:  # a plant model's file gives principal moments (diaginertia)
                    body.inertia = np.asarray(body.inertia) * factor
        base = spec.body(names[0])
        base.ipos = np.asarray(base.ipos) + np.asarray(self.base_com_offset_m, dtype=float)
        if self.base_payload_kg > 0:
            inertia = 0.4 * self.base_payload_kg * self.payload_radius_m**2
            base.add_body(name="base_payload", pos=[0.0, 0.0, 0.0], ipos=[0.0, 0.0, 0.0], mass=self.base_payload_kg,
                          inertia=[inertia] * 3, explicitinertial=True)
        if self.ee_payload_kg > 0:
            if robot.arm_ee is None:
                raise PlantInputError(f"ee_payload_kg needs a robot with an arm end-effector; {robot.name} has none")
            body, placement = bodies.frame(robot, robot.arm_ee)
            parent = spec.body(body)
            inertia = 0.4 * self.ee_payload_kg * self.payload_radius_m**2
            parent.add_body(name="ee_payload", pos=np.asarray(placement.translation, dtype=float),
                            ipos=[0.0, 0.0, 0.0], mass=self.ee_payload_kg, inertia=[inertia] * 3,
                            explicitinertial=True)
