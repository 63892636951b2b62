"""`Scene`: objects added to a MuJoCo plant, turned into a `MujocoPlantConfig`, every measurement recorded."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import mujoco
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.robots import RobotModel
from wbmpc.sim.mujoco_scene import MujocoPlantConfig
from wbmpc.sim.objects.common import add_ee_site


@dataclass
class SceneRecording:
    """Measurements of every object after each physics step: `series(obj, key)` -> (t, values)."""

    t: list = field(default_factory=list)
    values: dict = field(default_factory=dict)

    def series(self, obj: str, key: str) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.t), np.array(self.values[obj][key])


class Scene:
    """Objects added to a MuJoCo plant; `attach(plant)` measures them at every physics step."""

    def __init__(self, robot: RobotModel, objects: list):
        if robot.arm_ee is None:
            raise ConfigError(f"scene objects act on the arm end-effector; {robot.name} has no arm")
        names = [o.name for o in objects]
        if len(set(names)) != len(names):
            raise ConfigError(f"scene object names must be unique, got {names}")
        self.robot = robot
        self.objects = list(objects)
        self.recording = SceneRecording()

    def plant_config(self, base: MujocoPlantConfig | None = None) -> MujocoPlantConfig:
        base = base or MujocoPlantConfig()
        bodies = tuple(b for o in self.objects for b in o.bodies_mjcf(self.robot))
        previous = base.spec_callback

        def edit(spec: mujoco.MjSpec) -> None:
            if previous is not None:
                previous(spec)
            add_ee_site(spec, self.robot)
            for o in self.objects:
                o.edit_spec(spec, self.robot)

        return replace(base, extra_bodies_mjcf=base.extra_bodies_mjcf + bodies, spec_callback=edit)

    def attach(self, plant) -> None:
        """Run the objects' scripts before and record their measurements after every step of `plant`."""
        if not hasattr(plant, "add_step_hook"):
            raise ConfigError("scene objects need the MuJoCo plant (--plant mujoco)")
        self.recording = SceneRecording()
        plant.add_step_hook(self)

    def before_step(self, plant) -> None:
        for o in self.objects:
            o.before_step(plant)

    def after_step(self, plant) -> None:
        rec = self.recording
        rec.t.append(plant.time_s)
        for o in self.objects:
            for key, value in o.measure(plant).items():
                rec.values.setdefault(o.name, {}).setdefault(key, []).append(value)

    def replay_objects(self) -> list[dict]:
        """Boxes and lines of every object over the recorded run (for `wbmpc.viz.replay`)."""
        if not self.recording.t:
            return []
        return [shape for o in self.objects for shape in o.replay_shapes(self.recording)]

    def object(self, name: str):
        for o in self.objects:
            if o.name == name:
                return o
        raise ConfigError(f"no scene object named '{name}'")
