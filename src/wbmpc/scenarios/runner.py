"""Run a named scenario end to end: MPC + plant + closed loop -> metrics (+ plots and replay)."""

from __future__ import annotations

import dataclasses
import functools
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from wbmpc.control.config import MpcConfig
from wbmpc.control.delay import delay_from_text, delay_text
from wbmpc.control.interpolator import PdGains
from wbmpc.control.joint_loop import hold_s, unstable_gains
from wbmpc.control.loop import MOTOR_LAWS, ClosedLoop, LoopConfig, Progress, RunLog
from wbmpc.control.mpc import MPC
from wbmpc.control.policy import IDENTIFY_MASS_NEEDS, MpcChoices, mpc_config
from wbmpc.control.tuning import DEFAULT_HOLD_S, tuning_for
from wbmpc.errors import ConfigError
from wbmpc.interrupt import stop_flag
from wbmpc.operator.config import OperatorConfig
from wbmpc.operator.run import prepare
from wbmpc.options import check_fields, declared, declared_field, option
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.library import SCENARIOS, make_scenario
from wbmpc.scenarios.metrics import common_metrics
from wbmpc.scenarios.outputs import write_output_files
from wbmpc.scenarios.terrain import check_terrain, contact_monitor
from wbmpc.sim import PLANTS, PlantConfig, make_plant, robot_plant_config
from wbmpc.sim.base import DRIVE_TRAIN_FIELDS, specialised_config
from wbmpc.sim.model_errors import ModelErrors
from wbmpc.strict_json import to_json

OBJECT_MODEL_SCENARIOS = next(opt.scenarios for f, opt in declared(ScenarioOptions) if f.name == "object_model")
MAX_DURATION_S = 3600.0  # one simulated hour; longer runs are split by the caller
REPLAY_FULL_RATE_TICKS = 30_000  # up to 60 s at 500 Hz the replay gets every control tick
REPLAY_MAX_EVERY = 10  # beyond, every k-th tick, k <= 10 (>= 50 Hz at 500 Hz)


def _mpc(name: str):
    """`MpcChoices`' option `name`, carried flat by `RunConfig` (declared once, in wbmpc.control.policy)."""
    return declared_field(MpcChoices, name)


@dataclass
class RunConfig:
    """One closed-loop run. Every field with a flag is declared once (`wbmpc.options`): `wbmpc run`'s
    flag, help, default and range come from here, the MPC's options from `MpcChoices` (`mpc_choices`)."""

    scenario: str = "trot-in-place"
    duration_s: float | None = option(None, flag="--duration", metavar="S", help="simulated seconds", low=0.0,
                                      high=MAX_DURATION_S, low_open=True, unit="s",
                                      default_text="the scenario's, listed below")
    delay_mode: str = _mpc("delay_mode")
    delay_ms: float | None = _mpc("delay_ms")
    mpc_rate_hz: float = _mpc("mpc_rate_hz")
    plant: str = option("mujoco", flag="--plant", choices=PLANTS,
                        help="simulator: mujoco or pinocchio (rigid contacts, no scene objects)")
    nodes: int = _mpc("nodes")
    uniform_dt_ms: float | None = _mpc("uniform_dt_ms")
    gains: PdGains | None = None  # None: the robot's tuning (wbmpc.control.tuning); --kp/--kd are PdGains'
    options: ScenarioOptions = field(default_factory=ScenarioOptions)
    operator: OperatorConfig = field(default_factory=OperatorConfig)  # live commands, the viewer (wbmpc.operator)
    # None (the Python API's default): `default_solver(..., api=True)`, fatrop unless the OCP carries the object or
    # collision avoidance is asked for
    solver: str | None = _mpc("solver")
    formulation: str = _mpc("formulation")
    compiled: bool = _mpc("compiled")  # generated C, compiled once and cached (solvers/codegen.py)
    base_tracking: str = _mpc("base_tracking")
    seed: int = option(0, flag="--seed", help="seed of the measurement noise", integer=True, low=0)
    collision_avoidance: bool | None = _mpc("collision_avoidance")  # capsule distance rows (robots/collision_model.py)
    collision_margin_m: float = _mpc("collision_margin_m")
    friction_mu: float | None = _mpc("friction_mu")  # the ground friction the MPC plans with (eq. 6's cones)
    touchdown_events: bool = _mpc("touchdown_events")  # the schedule follows measured touch-down (control/touchdown.py)
    floor_friction_mu: float | None = option(None, flag="--floor-friction", metavar="MU", low=0.0, high=5.0,
                                             help="the simulated floor's friction coefficient (the plant's, not the "
                                             "MPC's --friction)", default_text="0.8, MuJoCo's scene")
    # the plant's timing (issue 37): properties of the robot link and the simulator, not of the controller
    joint_loop_hz: float = option(500.0, flag="--joint-loop-hz", metavar="HZ", low=20.0, high=10_000.0, unit="Hz",
                                  help="the joint loop: commands (eq. 9's references) reach the motors and the motor "
                                  "law (eq. 10) is evaluated with that moment's joint readings at this rate, its torque "
                                  "held until the next (unitree_mujoco: 200 Hz at its default 5 ms step; a Go2's "
                                  "LowCmd: 500 Hz)", default_text="500 = the paper's")
    joint_loop_jitter_ms: float = option(0.0, flag="--joint-loop-jitter", metavar="MS", low=0.0, high=50.0, unit="ms",
                                         help="each command arrives late by a uniform draw in [0, MS] (a LowCmd over "
                                         "DDS); at most one joint-loop period")
    motor_law: str = option("held", flag="--motor-law", choices=MOTOR_LAWS,
                            help="held: eq. (10) evaluated once per command and its torque held (unitree_mujoco, the "
                            "paper's PD); continuous: re-evaluated at every physics step with the last command's "
                            "references (a real motor driver)")
    physics_dt_ms: float | None = option(None, flag="--physics-dt", metavar="MS", low=0.0, high=20.0, low_open=True,
                                         unit="ms", help="the simulator's step (unitree_mujoco: 5 ms by default)",
                                         default_text="the plant's, 1 ms")
    # the plant's drive train etc.: None, the robot's own (`sim.robot_plant_config`, g1's rotors); given, as it is
    # (start from `robot_plant_config(robot)` to keep those, as the CLI's --plant-* flags do)
    plant_config: PlantConfig | None = None
    plant_model: str | None = option(None, flag="--plant-model", metavar="FILE",
                                     help="MuJoCo simulates this file of the robot (MJCF or URDF; its own inertias, "
                                     "geoms, friction, damping, armature, contact settings; its actuators replaced by "
                                     "torque motors with its force limits) instead of the controller's model; joints "
                                     "matched by name (wbmpc.sim.plant_model)", default_text="the controller's model")
    state: str = option("true", flag="--state", choices=("true", "estimated"), help="state fed to the MPC: the "
                        "simulator's (true) or estimated from simulated IMU + encoders (noise on; section V-B filter; "
                        "adds estimation RMSE metrics and estimation.png)")
    sensors: object | None = None  # wbmpc.estimation.SensorConfig (defaults when None)
    model_errors: ModelErrors | None = None  # the MuJoCo plant differs from the MPC's model
    joint_position_noise_rad: float = 0.0  # std of the measurement noise (LoopConfig)
    joint_velocity_noise_rad_s: float = 0.0
    push_gait_period_scale: float | None = _mpc("push_gait_period_scale")
    solver_options: dict = _mpc("solver_options")  # SolverConfig.extra_options of rti/sqp
    delay_compensation: bool | None = _mpc("delay_compensation")
    step_budget_ms: float | None = _mpc("step_budget_ms")
    # set by __post_init__ where `solver` was "auto": `for_robot` chooses again once collision avoidance is decided
    auto_solver: bool = field(default=False, repr=False)
    identify_mass: bool = _mpc("identify_mass")  # the base CoM offset and a hand payload identified online

    def __post_init__(self):
        """Every range is checked here, before anything is built (errors name the field; the CLI its flag)."""
        check_fields(self)
        choices = self.mpc_choices()  # the MPC options' own checks; an automatic solver chosen
        self.solver, self.auto_solver, self.delay_mode = choices.solver, choices.auto_solver, choices.delay_mode
        if self.plant_model is not None and self.plant != "mujoco":
            raise ConfigError("--plant-model is simulated by MuJoCo: use --plant mujoco")
        if self.plant_model is not None and not Path(self.plant_model).is_file():
            raise ConfigError.for_field("plant_model", f"file not found: {self.plant_model}")
        if self.state == "estimated" and self.plant != "mujoco":
            raise ConfigError("--state estimated reads IMU and encoders simulated in MuJoCo; use --plant mujoco")
        if self.options.object_model and self.scenario not in OBJECT_MODEL_SCENARIOS:
            raise ConfigError(f"--object-model plans with the manipulated object inside the MPC; scenario "
                              f"'{self.scenario}' has no object the MPC can model: use {' or '.join(OBJECT_MODEL_SCENARIOS)}")
        if self.identify_mass and self.plant != "mujoco":
            raise ConfigError(IDENTIFY_MASS_NEEDS)
        if self.operator.viewer and self.plant != "mujoco":
            raise ConfigError("--viewer shows MuJoCo's own viewer: use --plant mujoco (or leave --viewer out and open "
                              "the replay afterwards)")
        if self.joint_loop_jitter_ms > 1e3 / self.joint_loop_hz:
            raise ConfigError.for_field("joint_loop_jitter_ms", f"must be at most one joint-loop period "
                                        f"({1e3 / self.joint_loop_hz:g} ms at {self.joint_loop_hz:g} Hz), got "
                                        f"{self.joint_loop_jitter_ms:g}")
        if self.touchdown_events and (self.plant != "mujoco" or self.delay_mode == "realtime"):
            raise ConfigError("--touchdown-events reads MuJoCo's foot forces in this process: use --plant mujoco and "
                              "no --delay-mode realtime")

    def mpc_choices(self) -> MpcChoices:
        """The MPC options of this run (`wbmpc.control.policy.mpc_config` turns them into the MPC's settings)."""
        names = [f.name for f in dataclasses.fields(MpcChoices) if hasattr(self, f.name)]
        return MpcChoices(**{name: getattr(self, name) for name in names}, estimated_state=self.state == "estimated",
                          object_model=self.options.object_model)

    def for_robot(self, robot: RobotModel) -> RunConfig:
        """This run on `robot`: collision avoidance decided where left open (`collision_avoidance_default`) and
        an automatic solver chosen again with it."""
        if self.collision_avoidance is not None:
            return self
        scenario = SCENARIOS.get(self.scenario)
        choices = self.mpc_choices().for_robot(robot, scenario is not None and scenario.sweeps_ee)
        return dataclasses.replace(self, collision_avoidance=choices.collision_avoidance, solver=choices.solver)


def _accepting_one_string_delay(init):
    """RunConfig(delay="6") (the one-string delay of before, deprecated for one release) as RunConfig(delay_mode=
    "fixed", delay_ms=6.0); "none", "measured", "measured-wall", "realtime" as the mode."""

    @functools.wraps(init)
    def __init__(self, *args, delay: str | None = None, **kwargs):
        if delay is not None:
            warnings.warn("RunConfig(delay=...) is deprecated; use delay_mode (none, measured, measured-wall, fixed, "
                          "realtime) and delay_ms", DeprecationWarning, stacklevel=2)
            kwargs["delay_mode"], kwargs["delay_ms"] = delay_from_text(delay)
        init(self, *args, **kwargs)

    return __init__


RunConfig.__init__ = _accepting_one_string_delay(RunConfig.__init__)


@dataclass
class ScenarioResult:
    scenario: Scenario
    metrics: dict
    log: RunLog
    scene: object | None = None  # wbmpc.sim.objects.Scene with the objects' recordings, if any
    plant: object | None = None  # the simulator the run used (wbmpc.sim), for its final state and config
    estimation: object | None = None  # the estimator's log with --state estimated (wbmpc.estimation), else None


def mpc_config_for(scenario: Scenario, config: RunConfig, robot: RobotModel | None = None) -> MpcConfig:
    """The MPC settings of a run: the scenario's needs and the run's choices through the MPC's policy
    (`wbmpc.control.policy.mpc_config`)."""
    return mpc_config(robot, scenario.needs(robot), config.mpc_choices())


def run_scenario(robot: RobotModel, config: RunConfig, progress: Progress | None = None,
                 mpc: MPC | None = None, stop: Callable[[], bool] | None = None) -> ScenarioResult:
    """Build, run and measure a scenario. Ctrl-C stops the run early (see `wbmpc.interrupt`) and the
    result keeps what was measured, with `metrics["interrupted"]`; `stop` replaces that flag."""
    config = config.for_robot(robot)
    scenario = make_scenario(config.scenario, robot, config.options)
    operator = prepare(robot, config.operator, scenario)  # script, terminal, gamepad, display: checked first
    duration = config.duration_s or operator.duration_s or scenario.default_duration_s
    scene = scenario.scene(robot)
    if scene is not None and config.plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' has scene objects and needs --plant mujoco")
    check_terrain(robot, scenario, config.plant)
    mpc = mpc or MPC(robot, mpc_config_for(scenario, config, robot))
    # the plant does not wait: recovery solvers must not be built mid-run (in real time the solver process
    # builds its own MPC and prepares it; this one only solves the first step, before the clock runs)
    if config.delay_mode not in ("none", "realtime"):
        mpc.prepare_fallback()
    if mpc.config.gait != scenario.gait:
        raise ConfigError(f"the MPC passed in runs the {mpc.config.gait} gait; scenario '{scenario.name}' needs {scenario.gait}")
    with stop_flag(stop) as stop:
        if stop():  # Ctrl-C while building (CasADi's C++ build does not raise): stop before running
            raise KeyboardInterrupt
        return _run(robot, config, scenario, scene, mpc, duration, progress, stop, operator)


def _run(robot, config, scenario, scene, mpc, duration, progress, stop, operator) -> ScenarioResult:
    mpc.reset()
    terrain = scenario.terrain(robot)
    plant = _plant(robot, config, scene, operator, terrain, scenario.start_pose(robot))
    terrain_monitor = contact_monitor(robot, plant, terrain)
    sole_monitor = None
    if robot.soles and hasattr(plant, "sole_pressure"):  # flat feet in MuJoCo: the measured CoP on every tick
        from wbmpc.sim.sole_pressure import SolePressureMonitor

        sole_monitor = SolePressureMonitor.for_robot(robot)
        plant.add_step_hook(sole_monitor)
    identification = _mass_identification(robot, config, mpc, plant) if config.identify_mass else None
    hold = joint_loop_hold_s(config, plant.dt_s)
    gains = _joint_loop_gains(robot, config, scenario, hold)
    state_source = _estimated_state(plant, mpc, config) if config.state == "estimated" else None
    if identification is not None and state_source is not None:  # the estimate is what the robot would know
        state_source.listeners.append(identification.on_estimate)
    loop_config = LoopConfig(mpc_rate_hz=config.mpc_rate_hz, delay_mode=config.delay_mode, delay_ms=config.delay_ms,
                             gains=gains, seed=config.seed, terrain=terrain, control_rate_hz=config.joint_loop_hz,
                             joint_loop_jitter_ms=config.joint_loop_jitter_ms, motor_law=config.motor_law,
                             touchdown_events=config.touchdown_events,
                             joint_position_noise_rad=config.joint_position_noise_rad,
                             joint_velocity_noise_rad_s=config.joint_velocity_noise_rad_s)
    loop = ClosedLoop(mpc, plant, loop_config, state_source)
    with operator:  # the scenario's commands, or the operator's sources on them
        commands, until = operator.attach(mpc, plant, loop, stop)
        operator.start()
        log = loop.run(duration, commands, scenario.events(robot), progress, until)
    if not log.n_ticks:  # interrupted before the first control tick: nothing was measured
        raise KeyboardInterrupt
    metrics = common_metrics(robot, log, scenario.name)
    metrics.update(scenario.extra_metrics(robot, log))
    metrics.update(operator.finish(log, mpc))
    metrics["state"] = config.state
    metrics["mass_kg"] = robot.mass_kg
    metrics["plant_mass_kg"] = plant_mass_kg(plant)
    metrics["model_errors"] = (config.model_errors.summary(robot) if config.model_errors is not None
                               and not config.model_errors.is_nominal else None)
    if sole_monitor is not None:
        metrics.update(sole_monitor.metrics())
    metrics.update(self_collision_metrics(plant, mpc, log))
    if terrain_monitor is not None:
        metrics.update(terrain_monitor.metrics())
    metrics["settings"] = _settings_report(robot, mpc, loop_config.gains, scenario.needs_arm, hold)
    if identification is not None:
        metrics.update(identification.metrics(config.model_errors))
    if state_source is not None:
        from wbmpc.estimation.metrics import estimation_metrics

        metrics.update(estimation_metrics(state_source.log))
    metrics.update(_run_summary(robot, config, mpc, plant, duration, log))
    return ScenarioResult(scenario, metrics, log, scene, plant=plant,
                          estimation=state_source.log if state_source is not None else None)


def _plant(robot: RobotModel, config: RunConfig, scene, operator=None, terrain=None,
           start_q: np.ndarray | None = None):
    """The run's simulator: its drive train (a preset's rotors too), the scene's objects, the terrain, the model
    errors, the viewer's hand target (`operator`, a `wbmpc.operator.run.OperatorRun`); reset to the start pose
    (the nominal one, on the terrain under it)."""
    plant_config = config.plant_config
    if plant_config is None and config.plant_model is None:  # a preset's rotors (g1) are the plant's too
        plant_config = robot_plant_config(robot)
    if config.plant_model is not None:  # another file of the robot: its own drive train, the config's added
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = dataclasses.replace(specialised_config(plant_config, MujocoPlantConfig), plant_model=config.plant_model)
    if scene is not None:
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = scene.plant_config(specialised_config(plant_config, MujocoPlantConfig))
    if terrain is not None:  # MuJoCo builds the terrain the MPC plans on
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = dataclasses.replace(specialised_config(plant_config, MujocoPlantConfig), terrain=terrain)
    if config.model_errors is not None and not config.model_errors.is_nominal:
        if config.plant != "mujoco":
            raise ConfigError("model errors (CoM offset, masses, payload, armature, floor friction) need --plant mujoco")
        plant_config = config.model_errors.plant_config(robot, plant_config)
    # the log has the configurations at 500 Hz; the plant's own per-step recording is read by nothing
    # here and would grow by ~0.3 MB per simulated second
    plant_config = dataclasses.replace(plant_config or PlantConfig(), record_every_n_steps=0)
    if config.floor_friction_mu is not None:
        plant_config = dataclasses.replace(plant_config, friction_mu=config.floor_friction_mu)
    if config.physics_dt_ms is not None:
        plant_config = dataclasses.replace(plant_config, dt_s=config.physics_dt_ms / 1e3)
    if operator is not None:
        plant_config = operator.plant_config(plant_config)
    plant = make_plant(config.plant, robot, plant_config)
    if scene is not None:
        scene.attach(plant)
    plant.reset(robot.q_nominal if start_q is None else start_q, np.zeros(robot.nv))
    return plant


def joint_loop_hold_s(config: RunConfig, physics_dt_s: float | None = None) -> float:
    """The longest time the run's plant holds a motor torque (`wbmpc.control.joint_loop.hold_s`)."""
    if physics_dt_s is None:
        physics_dt_s = (config.physics_dt_ms / 1e3 if config.physics_dt_ms is not None else
                        (config.plant_config or PlantConfig()).dt_s)
    return hold_s(config.joint_loop_hz, config.joint_loop_jitter_ms, config.motor_law, physics_dt_s)


def _joint_loop_gains(robot: RobotModel, config: RunConfig, scenario: Scenario, hold: float) -> PdGains:
    """Eq. (10)'s gains of the run: the robot's tuned ones capped for the hold its plant applies
    (`RobotTuning.gains_at`), or the ones given (warned about when their held damper is unstable)."""
    tuning = tuning_for(robot)
    gains = scenario.pd_gains(config.gains if config.gains is not None else tuning.gains_at(hold))
    for problem in unstable_gains(gains, tuning.leg_joint_inertia_kg_m2, tuning.arm_joint_inertia_kg_m2, hold):
        warnings.warn(f"the motor law's damper is unstable at this joint loop: {problem}; lower the gain or leave it "
                      "to the robot's tuning", stacklevel=3)
    return gains


def plant_mass_kg(plant) -> float | None:
    """The simulated robot's mass (its base's subtree in MuJoCo: payloads included, scene objects not)."""
    model = getattr(plant, "model", None)
    if model is None or not hasattr(model, "body_subtreemass"):
        return None
    return float(model.body_subtreemass[model.body(plant.body_name(1)).id])


def _mass_identification(robot: RobotModel, config: RunConfig, mpc: MPC, plant):
    """--identify-mass: the inertial estimator on the plant's steps, feeding the MPC's inertial parameters."""
    from wbmpc.estimation.inertial import ESTIMATED_STATE_CONFIG, InertialEstimator, InertialIdentification

    from_estimate = config.state == "estimated"
    estimator = InertialEstimator(robot, ESTIMATED_STATE_CONFIG) if from_estimate else InertialEstimator(robot)
    identification = InertialIdentification(estimator, mpc, from_estimate=from_estimate)
    plant.add_step_hook(identification)
    return identification


def _run_summary(robot: RobotModel, config: RunConfig, mpc: MPC, plant, duration: float, log: RunLog) -> dict:
    """The run's settings in its metrics: delay, plant, grid, base tracking, push cadence, solver, drive train."""
    return {"delay_mode": config.delay_mode, "delay_ms": config.delay_ms, "mpc_rate_target_hz": config.mpc_rate_hz,
            "delay": delay_text(config.delay_mode, config.delay_ms),  # the one-string form of before (one release)
            "plant": config.plant, "nodes": config.nodes, "joint_loop_hz": config.joint_loop_hz,
            "joint_loop_jitter_ms": config.joint_loop_jitter_ms, "motor_law": config.motor_law,
            "physics_dt_ms": 1e3 * plant.dt_s, "friction_coefficient": mpc.config.friction_coefficient,
            "time_steps": "geometric" if config.uniform_dt_ms is None else "uniform",
            "uniform_dt_ms": config.uniform_dt_ms, "base_tracking": mpc.config.references.base_tracking,
            "push_gait_period_scale": mpc.config.push.gait_period_scale,
            **solver_summary(mpc, config),
            "requested_duration_s": float(duration), "interrupted": bool(log.interrupted),
            "drive_train": _drive_train_summary(robot, plant.config),
            "plant_model": plant.plant_model_report() if hasattr(plant, "plant_model_report") else None}


def self_collision_metrics(plant, mpc: MPC, log: RunLog) -> dict:
    """Robot-robot contacts counted in MuJoCo over the run (null on a plant that does not simulate them) and,
    with collision avoidance, its pairs and the smallest capsule distance of the run (500 Hz ticks)."""
    counter = getattr(plant, "self_contacts", None)
    if counter is not None and getattr(plant.config, "self_collision", False):
        out = counter.metrics(plant.dt_s)
    else:
        out = {"self_collision_contacts": None, "self_collision_time_s": None, "self_collision_pairs": None}
    model = mpc.problem.collision
    out["collision_avoidance"] = None
    if model is not None:
        q = log.arrays(("q",))["q"]
        distances = np.array([model.distances(qk) for qk in q]) if len(q) else np.zeros((0, len(model.pairs)))
        worst = int(np.argmin(distances.min(axis=0))) if distances.size else None
        out["collision_avoidance"] = {
            "margin_m": model.config.margin_m, "pairs": len(model.pairs), "rows_per_node": len(model.groups),
            "skipped_links": list(model.skipped_links),
            "min_distance_m": float(distances.min()) if distances.size else None,
            "closest_pair": model.pairs[worst].name if worst is not None else None}
    return out


def _settings_report(robot: RobotModel, mpc: MPC, gains: PdGains, commands_ee: bool = False,
                     hold: float = DEFAULT_HOLD_S) -> dict:
    """{"values": {setting: value}, "sources": {setting: source}} of the run: derived / table as `wbmpc info`
    says, "option" where the run used another value (a command-line option, the scenario's own gains)."""
    tuning = tuning_for(robot).for_task(commands_ee)
    used = dataclasses.replace(tuning.as_used_in(mpc.config), gains=gains)
    report = tuning.report(hold_s=hold)
    used_report = used.report(hold_s=hold)
    out = {"values": {}, "sources": {}}
    for name, entry in used_report.items():
        out["values"][name] = entry["value"]
        out["sources"][name] = report[name]["source"] if entry["value"] == report[name]["value"] else "option"
    return out


def solver_summary(mpc: MPC, config: RunConfig) -> dict:
    """Which solver ran and how: compiled or not (and why not, when asked to be), the step budget and the
    delay compensation. A solver asked to be compiled that could not be runs in CasADi's VM, several
    times slower: the summary and metrics say so instead of a warning alone."""
    solver = mpc.solver
    compiled = bool(getattr(solver, "is_compiled", False))
    error = getattr(solver, "compile_error", None)
    return {"solver": solver.config.name, "solver_compiled": compiled, "compiled_requested": bool(config.compiled),
            "compile_error": error if config.compiled and not compiled else None,
            # why a direct binding (fatrop-direct's Fatrop, the SQP solvers' HPIPM) was not used; None: it was or has none
            "direct_fallback": getattr(solver, "direct_error", None),
            "delay_compensation": bool(mpc.config.delay_compensation),
            "step_budget_ms": None if mpc.config.step_budget_s is None else 1e3 * mpc.config.step_budget_s}


def _drive_train_summary(robot: RobotModel, plant_config: PlantConfig) -> dict:
    """Armature and friction of the controller's model and of the plant (they may differ, section VI-D)."""
    summary = robot.summary()
    model = {key: summary[key] for key in ("armature_kg_m2", "viscous_friction_nm_s", "coulomb_friction_nm")}
    plant = {key: _plain(getattr(plant_config, key)) for key in DRIVE_TRAIN_FIELDS}
    return {"model": model, "plant": plant}


def _plain(value):
    return {k: float(v) for k, v in value.items()} if isinstance(value, dict) else float(value)


def _estimated_state(plant, mpc: MPC, config: RunConfig):
    """IMU + encoder models on the plant and the paper's estimator, contacts from the MPC's gait."""
    from wbmpc.estimation import SensorConfig
    from wbmpc.estimation.source import EstimatedState

    sensors = config.sensors or SensorConfig(seed=config.seed)
    return EstimatedState(plant, mpc.gait, sensors, terrain=mpc.config.references.terrain)



def write_outputs(robot: RobotModel, result: ScenarioResult, out_dir: Path) -> list[Path]:
    """metrics.json, PNG plots and a self-contained HTML replay, published together (`outputs.py`)."""

    def write(folder: Path) -> list[Path]:
        from wbmpc.viz import save_plots, save_replay

        paths = [folder / "metrics.json"]
        paths[0].write_text(to_json(result.metrics, indent=2) + "\n")
        scenario = result.scenario
        reference = scenario.ee_reference(robot)
        paths += save_plots(robot, result.log, folder, ee_reference=reference,
                            ee_error=lambda t_s, ee: scenario.ee_tracking_error(robot, t_s, ee),
                            ee_error_label=scenario.ee_error_label)
        # the replay shows 30 frames per second: 50 Hz of the log is plenty for long runs
        every = min(REPLAY_MAX_EVERY, max(1, round(result.log.n_ticks / REPLAY_FULL_RATE_TICKS)))
        arrays = result.log.arrays(("t", "q"), every=every)
        paths += scenario.extra_plots(robot, result.log, folder)
        objects = result.scene.replay_objects() if result.scene is not None else None
        terrain = scenario.terrain(robot)
        if terrain is not None:  # the steps, ramps and heightmaps the robot walked on, drawn and as a file
            from wbmpc.sim.terrain_geoms import replay_shapes
            from wbmpc.terrain import save_terrain

            objects = (objects or []) + replay_shapes(terrain)
            paths.append(save_terrain(terrain, folder / "terrain.yaml"))
        paths.append(save_replay(robot, arrays["t"], arrays["q"], folder / "replay.html", objects=objects,
                                 scenario=scenario.name))
        if result.estimation is not None:
            from wbmpc.viz.estimation import save_estimation_plot

            paths.append(save_estimation_plot(result.estimation, folder))
        return paths

    return write_output_files(out_dir, write)
