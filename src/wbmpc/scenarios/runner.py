"""Run a named scenario end to end: MPC + plant + closed loop -> metrics (+ plots and replay)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import ClosedLoop, LoopConfig, RunLog
from wbmpc.control.mpc import MPC, MpcConfig
from wbmpc.control.tuning import RobotTuning, tuning_for
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.library import make_scenario
from wbmpc.scenarios.metrics import common_metrics
from wbmpc.sim import PlantConfig, make_plant
from wbmpc.sim.base import DRIVE_TRAIN_FIELDS, specialised_config
from wbmpc.solvers.nlp import SolverConfig


@dataclass
class RunConfig:
    scenario: str = "trot-in-place"
    duration_s: float | None = None  # scenario default when None
    delay: str = "none"
    plant: str = "mujoco"
    nodes: int = 15
    uniform_dt_ms: float | None = None  # uniform steps instead of the geometric grid
    gains: PdGains | None = None  # None: the robot's tuning (wbmpc.control.tuning)
    options: ScenarioOptions = field(default_factory=ScenarioOptions)
    solver: str = "fatrop"
    formulation: str = "wb_inverse"
    compiled: bool = False  # generated C, compiled once and cached (solvers/codegen.py)
    seed: int = 0
    plant_config: PlantConfig | None = None  # the plant's drive train etc. (None: defaults)

    def __post_init__(self):
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError(f"duration must be positive, got {self.duration_s} s")
        if self.nodes < 2:
            raise ConfigError(f"the horizon needs at least 2 nodes, got {self.nodes}")


@dataclass
class ScenarioResult:
    scenario: Scenario
    metrics: dict
    log: RunLog


def mpc_config_for(scenario: Scenario, config: RunConfig, robot: RobotModel | None = None) -> MpcConfig:
    """The MPC settings of a run: grid and solver from `config`, weights/swing/period from the robot's tuning."""
    n = config.nodes - 1
    grid = TimeGrid.uniform_steps(n, config.uniform_dt_ms / 1e3) if config.uniform_dt_ms else TimeGrid(n_intervals=n)
    tuning = tuning_for(robot) if robot is not None else RobotTuning()
    return MpcConfig(ocp=OcpConfig(formulation=config.formulation, grid=grid), gait=scenario.gait,
                     solver=SolverConfig(name=config.solver, compiled=config.compiled), weights=tuning.weights,
                     swing=tuning.swing, gait_period_s=tuning.gait_period_s)


def run_scenario(robot: RobotModel, config: RunConfig, progress: Callable[[float], None] | None = None,
                 mpc: MPC | None = None) -> ScenarioResult:
    scenario = make_scenario(config.scenario, robot, config.options)
    duration = config.duration_s or scenario.default_duration_s
    scene = scenario.scene(robot)
    if scene is not None and config.plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' has scene objects and needs --plant mujoco")
    mpc = mpc or MPC(robot, mpc_config_for(scenario, config, robot))
    if mpc.config.gait != scenario.gait:
        raise ConfigError(f"the MPC passed in runs the {mpc.config.gait} gait; scenario '{scenario.name}' needs {scenario.gait}")
    mpc.reset()
    plant_config = config.plant_config
    if scene is not None:
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = scene.plant_config(specialised_config(plant_config, MujocoPlantConfig))
    plant = make_plant(config.plant, robot, plant_config)
    if scene is not None:
        scene.attach(plant)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    gains = scenario.pd_gains(config.gains if config.gains is not None else tuning_for(robot).gains)
    loop = ClosedLoop(mpc, plant, LoopConfig(delay=config.delay, gains=gains, seed=config.seed))
    log = loop.run(duration, scenario.commands(robot), scenario.events(robot), progress)
    metrics = common_metrics(robot, log, scenario.name)
    metrics.update(scenario.extra_metrics(robot, log))
    metrics.update({"delay": config.delay, "plant": config.plant, "nodes": config.nodes,
                    "time_steps": "uniform" if config.uniform_dt_ms else "geometric",
                    "drive_train": _drive_train_summary(robot, plant.config)})
    result = ScenarioResult(scenario, metrics, log)
    result.plant = plant  # type: ignore[attr-defined]
    return result


def _drive_train_summary(robot: RobotModel, plant_config: PlantConfig) -> dict:
    """Armature and friction of the controller's model and of the plant (they may differ, section VI-D)."""
    summary = robot.summary()
    model = {key: summary[key] for key in ("armature_kg_m2", "viscous_friction_nm_s", "coulomb_friction_nm")}
    plant = {key: _plain(getattr(plant_config, key)) for key in DRIVE_TRAIN_FIELDS}
    return {"model": model, "plant": plant}


def _plain(value):
    return {k: float(v) for k, v in value.items()} if isinstance(value, dict) else float(value)


def prepare_output_dir(out_dir: Path) -> Path:
    """Create the output directory and check it is writable (before a long run, not after)."""
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe = out_dir / ".write_test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"cannot write to output directory {out_dir}: {exc.strerror}; choose another --out") from None
    return out_dir


def write_outputs(robot: RobotModel, result: ScenarioResult, out_dir: Path) -> list[Path]:
    """metrics.json, PNG plots and a self-contained HTML replay."""
    out_dir = prepare_output_dir(out_dir)
    paths = [out_dir / "metrics.json"]
    paths[0].write_text(json.dumps(result.metrics, indent=2))
    from wbmpc.viz import save_plots, save_replay

    reference = result.scenario.ee_reference(robot)
    paths += save_plots(robot, result.log, out_dir, ee_reference=reference)
    arrays = result.log.arrays()
    paths += result.scenario.extra_plots(robot, result.log, out_dir)
    paths.append(save_replay(robot, arrays["t"], arrays["q"], out_dir / "replay.html"))
    return paths
