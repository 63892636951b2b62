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
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.library import make_scenario
from wbmpc.scenarios.metrics import common_metrics
from wbmpc.sim import make_plant
from wbmpc.sim.model_errors import ModelErrors
from wbmpc.solvers.nlp import SolverConfig


@dataclass
class RunConfig:
    scenario: str = "trot-in-place"
    duration_s: float | None = None  # scenario default when None
    delay: str = "none"
    plant: str = "mujoco"
    nodes: int = 15
    uniform_dt_ms: float | None = None  # uniform steps instead of the geometric grid
    gains: PdGains = field(default_factory=PdGains)
    options: ScenarioOptions = field(default_factory=ScenarioOptions)
    solver: str = "fatrop"
    formulation: str = "wb_inverse"
    compiled: bool = False  # generated C, compiled once and cached (solvers/codegen.py)
    seed: int = 0
    model_errors: ModelErrors | None = None  # the MuJoCo plant differs from the MPC's model
    joint_position_noise_rad: float = 0.0  # std of the measurement noise (LoopConfig)
    joint_velocity_noise_rad_s: float = 0.0

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


def mpc_config_for(scenario: Scenario, config: RunConfig) -> MpcConfig:
    n = config.nodes - 1
    grid = TimeGrid.uniform_steps(n, config.uniform_dt_ms / 1e3) if config.uniform_dt_ms else TimeGrid(n_intervals=n)
    return MpcConfig(ocp=OcpConfig(formulation=config.formulation, grid=grid), gait=scenario.gait,
                     # a warm-started step converges in ~5 iterations; one still unsolved after 30 has
                     # stalled (pushes) and goes to the bounded recovery instead of burning 100
                     solver=SolverConfig(name=config.solver, compiled=config.compiled, max_iterations=30))


def run_scenario(robot: RobotModel, config: RunConfig, progress: Callable[[float], None] | None = None,
                 mpc: MPC | None = None) -> ScenarioResult:
    scenario = make_scenario(config.scenario, robot, config.options)
    duration = config.duration_s or scenario.default_duration_s
    scene = scenario.scene(robot)
    if scene is not None and config.plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' has scene objects and needs --plant mujoco")
    mpc = mpc or MPC(robot, mpc_config_for(scenario, config))
    if mpc.config.gait != scenario.gait:
        raise ConfigError(f"the MPC passed in runs the {mpc.config.gait} gait; scenario '{scenario.name}' needs {scenario.gait}")
    mpc.reset()
    plant_config = scene.plant_config() if scene is not None else None
    if config.model_errors is not None and not config.model_errors.is_nominal:
        if config.plant != "mujoco":
            raise ConfigError("model errors (CoM offset, masses, payload, armature, floor friction) need --plant mujoco")
        plant_config = config.model_errors.plant_config(robot, plant_config)
    plant = make_plant(config.plant, robot, plant_config)
    if scene is not None:
        scene.attach(plant)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    gains = scenario.pd_gains(config.gains)
    loop = ClosedLoop(mpc, plant, LoopConfig(delay=config.delay, gains=gains, seed=config.seed,
                                             joint_position_noise_rad=config.joint_position_noise_rad,
                                             joint_velocity_noise_rad_s=config.joint_velocity_noise_rad_s))
    log = loop.run(duration, scenario.commands(robot), scenario.events(robot), progress)
    metrics = common_metrics(robot, log, scenario.name)
    metrics.update(scenario.extra_metrics(robot, log))
    metrics.update({"delay": config.delay, "plant": config.plant, "nodes": config.nodes,
                    "time_steps": "uniform" if config.uniform_dt_ms else "geometric"})
    result = ScenarioResult(scenario, metrics, log)
    result.plant = plant  # type: ignore[attr-defined]
    return result


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
