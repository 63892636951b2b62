"""Run a named scenario end to end: MPC + plant + closed loop -> metrics (+ plots and replay)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import ClosedLoop, LoopConfig, Progress, RunLog, fixed_delay_s
from wbmpc.control.mpc import BASE_TRACKING_MODES, MPC, MpcConfig
from wbmpc.control.tuning import RobotTuning, tuning_for
from wbmpc.errors import ConfigError, unknown_name
from wbmpc.interrupt import stop_flag
from wbmpc.ocp.formulations import FORMULATIONS
from wbmpc.ocp.grid import MAX_INTERVALS, MAX_STEP_S, TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.options import check_fields, declared, option
from wbmpc.robots import RobotModel
from wbmpc.robots.collision_model import CollisionConfig
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.library import make_scenario
from wbmpc.scenarios.metrics import common_metrics
from wbmpc.scenarios.outputs import write_output_files
from wbmpc.sim import PLANTS, PlantConfig, make_plant, robot_plant_config
from wbmpc.sim.base import DRIVE_TRAIN_FIELDS, specialised_config
from wbmpc.sim.model_errors import ModelErrors
from wbmpc.solvers.nlp import SOLVERS, SolverConfig
from wbmpc.strict_json import to_json

OBJECT_MODEL_SCENARIOS = next(opt.scenarios for f, opt in declared(ScenarioOptions) if f.name == "object_model")
DELAYED_RECOVERY_LIMIT_S = 0.05  # four MPC periods at 80 Hz
RECOVERY_ITERATIONS_DELAYED = 10  # the RTI's Fatrop re-solve of a failed QP, when the plant does not wait (~50 ms)
MAX_DURATION_S = 3600.0  # one simulated hour; longer runs are split by the caller
REPLAY_FULL_RATE_TICKS = 30_000  # up to 60 s at 500 Hz the replay gets every control tick
REPLAY_MAX_EVERY = 10  # beyond, every k-th tick, k <= 10 (>= 50 Hz at 500 Hz)


@dataclass
class RunConfig:
    """One closed-loop run. Every field with a flag is declared once (`wbmpc.options`): `wbmpc run`'s
    flag, help, default and range come from here."""

    scenario: str = "trot-in-place"
    duration_s: float | None = option(None, flag="--duration", metavar="S", help="simulated seconds", low=0.0,
                                      high=MAX_DURATION_S, low_open=True, unit="s",
                                      default_text="the scenario's, listed below")
    delay: str = option("none", flag="--delay", help="none (the simulation waits for the solver) | measured (the "
                        "step's CPU time elapses: its time on a core of its own) | measured-wall (its wall time) | "
                        "realtime (solver in its own process, wall-clock paced) | a fixed delay of 0-1000 ms")
    plant: str = option("mujoco", flag="--plant", choices=PLANTS,
                        help="simulator: mujoco or pinocchio (rigid contacts, no scene objects)")
    nodes: int = option(15, flag="--nodes", help="horizon nodes", integer=True, low=2, high=MAX_INTERVALS + 1,
                        default_text="15 = the paper's")
    uniform_dt_ms: float | None = option(None, flag="--uniform-dt", metavar="MS", help="uniform time steps of MS ms "
                                         "instead of the geometric 10-100 ms grid", low=0.0, high=1e3 * MAX_STEP_S,
                                         low_open=True, unit="ms")
    gains: PdGains | None = None  # None: the robot's tuning (wbmpc.control.tuning); --kp/--kd are PdGains'
    options: ScenarioOptions = field(default_factory=ScenarioOptions)
    # None (the Python API's default): `default_solver(..., api=True)`, fatrop unless the OCP carries the object or
    # collision avoidance is asked for
    solver: str | None = option(None, flag="--solver", cli_default="auto", help="auto (fatrop-direct for --compiled "
                                "runs without --delay, else sqp), fatrop (converged), fatrop-direct (the same Fatrop "
                                "through its C interface, always compiled), ipopt, rti (one SQP iteration per step on "
                                "HPIPM's QP) or sqp (anytime SQP: iterations with a line search until converged or the "
                                "step's deadline)")
    formulation: str = option("wb_inverse", flag="--formulation", help="OCP formulation of Table I (see bench table1)")
    # generated C, compiled once and cached (solvers/codegen.py)
    compiled: bool = option(False, flag="--compiled", help="generate C for the NLP, compile it once (cached in "
                            "~/.cache/wbmpc) and use it")
    base_tracking: str = option("position", flag="--base-tracking", choices=BASE_TRACKING_MODES,
                                help="position: base x/y/yaw anchored to the integrated command, corrects drift; "
                                "velocity: the paper's velocity-only base tracking, drift uncorrected")
    seed: int = option(0, flag="--seed", help="seed of the measurement noise", integer=True, low=0)
    # collision avoidance (issue 22, beyond the paper): capsule distance rows in the OCP (robots/collision_model.py)
    collision_avoidance: bool | None = option(
        None, flag="--collision-avoidance", choices=("on", "off"), const="on", parse=lambda text: text == "on",
        help="hard rows keeping the arm off the base and the legs and the legs apart (capsules from the URDF's "
        "collision geometry) and the scene's boxes (arm-track --target-path around-obstacle) off the arm; the arm's "
        "velocity command becomes soft, so the hand stops at or slides along the margin instead of the OCP turning "
        "infeasible; solver auto: the anytime SQP",
        default_text="on for arm-track on a legged base carrying an arm, off otherwise")
    collision_margin_m: float = option(0.03, flag="--collision-margin", help="with --collision-avoidance: smallest "
                                       "distance kept between two capsules", low=0.0, high=0.3, unit="m")
    plant_config: PlantConfig | None = None  # the plant's drive train etc. (None: defaults)
    state: str = option("true", flag="--state", choices=("true", "estimated"), help="state fed to the MPC: the "
                        "simulator's (true) or estimated from simulated IMU + encoders (noise on; section V-B filter; "
                        "adds estimation RMSE metrics and estimation.png)")
    sensors: object | None = None  # wbmpc.estimation.SensorConfig (defaults when None)
    model_errors: ModelErrors | None = None  # the MuJoCo plant differs from the MPC's model
    joint_position_noise_rad: float = 0.0  # std of the measurement noise (LoopConfig)
    joint_velocity_noise_rad_s: float = 0.0
    # MpcConfig.push_gait_period_scale: the gait period's factor after a push (1: the paper's fixed schedule).
    # None: the solver's default (`_push_cadence`: faster steps with Fatrop and IPOPT, fixed with RTI)
    push_gait_period_scale: float | None = option(
        None, flag="--push-cadence", metavar="SCALE", low=0.0, high=1.0, low_open=True,
        help="after a push (any scenario) the gait period is scaled by this while in push recovery mode and 1 s "
        "after; 1: the paper's fixed schedule",
        default_text="0.5625: the 0.8 s trot steps every 0.45 s; with --solver rti 1")
    # SolverConfig.extra_options of rti/sqp
    solver_options: dict = option(default_factory=dict, flag="--solver-option", metavar="KEY=VALUE", repeat=True,
                                  parse=lambda items: parse_solver_options(items),
                                  help="a setting of the rti/sqp solvers (RtiConfig/AnytimeConfig), repeatable: e.g. "
                                  "sqp_iterations=2, budget_ms=5, clock=cpu")
    # MpcConfig.delay_compensation; None: on whenever the plan applies late (any --delay but none) on point feet,
    # off on flat feet (`_delay_compensation_default`)
    delay_compensation: bool | None = option(
        None, flag="--delay-compensation", choices=("on", "off"), parse=lambda text: text == "on",
        help="plan from the state predicted for when the plan applies (the measurement rolled forward over the "
        "expected delay with the last plan)", default_text="on with any --delay but none; off on flat feet")
    # MpcConfig.step_budget_s of the anytime solver; None: see _step_budget_s
    step_budget_ms: float | None = option(
        None, flag="--step-budget", metavar="MS", low=0.0, high=1e4, low_open=True, unit="ms",
        help="sqp: the MPC step's time budget", default_text="the 12.5 ms period less 2.5 ms of transport with a "
        "delay, on CPU time unless --delay realtime; none without delay")

    # set by __post_init__ where `solver` was "auto": `for_robot` chooses again once collision avoidance is decided
    auto_solver: bool = field(default=False, repr=False)
    # issue 22: the base CoM offset and a hand payload identified online and fed to the NLP (estimation/inertial.py)
    identify_mass: bool = option(False, flag="--identify-mass", help="estimate the base CoM offset and a payload at "
                                 "the hand online from the measured motion and torques and plan with them (NLP "
                                 "parameters); reports base_com_offset_estimate_m and payload_estimate_kg")

    def __post_init__(self):
        """Every range is checked here, before anything is built (errors name the field; the CLI its flag)."""
        check_fields(self)
        fixed_delay_s(self.delay)
        if self.solver in ("auto", None):
            self.auto_solver = self.solver == "auto"
            self.solver = default_solver(self.compiled, self.delay, bool(self.collision_avoidance),
                                         self.options.object_model, api=self.solver is None)
        if self.formulation not in FORMULATIONS:
            raise ConfigError(unknown_name("formulation", self.formulation, FORMULATIONS))
        if self.solver not in SOLVERS:
            raise ConfigError(unknown_name("solver", self.solver, SOLVERS))
        if self.push_gait_period_scale not in (None, 1.0) and self.state == "estimated" and self.delay == "realtime":
            raise ConfigError("a faster step cadence after a push (--push-cadence) changes the MPC's gait clock in the "
                              "solver process, which the estimator of --state estimated --delay realtime cannot "
                              "see: leave --push-cadence out (that run keeps the fixed schedule) or set it to 1")
        if self.solver_options and self.solver not in ("rti", "sqp"):
            raise ConfigError(f"--solver-option sets the rti/sqp solvers' settings; the {self.solver} solver has none "
                              "(use --solver rti or --solver sqp)")
        if self.solver_options:  # unknown names and bad values refused before anything is built
            from wbmpc.solvers.anytime import AnytimeConfig
            from wbmpc.solvers.rti import RtiConfig

            (AnytimeConfig if self.solver == "sqp" else RtiConfig).from_options(self.solver_options)
        if self.state == "estimated" and self.plant != "mujoco":
            raise ConfigError("--state estimated reads IMU and encoders simulated in MuJoCo; use --plant mujoco")
        if self.options.object_model and self.scenario not in OBJECT_MODEL_SCENARIOS:
            raise ConfigError(f"--object-model plans with the manipulated object inside the MPC; scenario "
                              f"'{self.scenario}' has no object the MPC can model: use {' or '.join(OBJECT_MODEL_SCENARIOS)}")
        if self.identify_mass and (self.plant != "mujoco" or self.delay == "realtime" or not self.formulation.startswith("wb_")):
            raise ConfigError("--identify-mass observes the MuJoCo plant's steps and updates the whole-body model of "
                              "the MPC in this process: use --plant mujoco, a wb_* --formulation and no --delay realtime")

    def for_robot(self, robot: RobotModel) -> RunConfig:
        """This run on `robot`: collision avoidance decided where left open (`collision_avoidance_default`) and
        an automatic solver chosen again with it."""
        if self.collision_avoidance is not None:
            return self
        on = collision_avoidance_default(self.scenario, robot)
        return dataclasses.replace(self, collision_avoidance=on, solver="auto" if self.auto_solver else self.solver)


def parse_solver_options(items: list[str] | None) -> dict:
    """--solver-option KEY=VALUE (repeatable) as {key: number, bool, None or text}."""
    options = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--solver-option needs KEY=VALUE (e.g. sqp_iterations=2), got {item!r}")
        lowered = text.strip().lower()
        if lowered in ("none", "null"):
            value = None
        elif lowered in ("true", "false"):
            value = lowered == "true"
        else:
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError:
                    value = text
        options[key.strip()] = value
    return options


@dataclass
class ScenarioResult:
    scenario: Scenario
    metrics: dict
    log: RunLog
    scene: object | None = None  # wbmpc.sim.objects.Scene with the objects' recordings, if any
    plant: object | None = None  # the simulator the run used (wbmpc.sim), for its final state and config
    estimation: object | None = None  # the estimator's log with --state estimated (wbmpc.estimation), else None


# scenarios whose hand sweeps the workspace: the paper's arm-track path brings the Z1's wrist (link04) onto its
# shoulder housing (link01) in MuJoCo (b1_z1, 10 s, compiled Fatrop: 116 robot-robot contacts, EE RMSE 1.11 cm
# against 3.3 mm and 0 contacts with the rows)
COLLISION_AVOIDANCE_SCENARIOS = ("arm-track",)


def collision_avoidance_default(scenario: str, robot: RobotModel) -> bool:
    """Collision avoidance where the user left it open: on for the scenarios that sweep the hand through the
    workspace (COLLISION_AVOIDANCE_SCENARIOS) on a legged base carrying an arm; a humanoid's hand (flat feet)
    keeps it off (its arm-track measured without contacts)."""
    return scenario in COLLISION_AVOIDANCE_SCENARIOS and robot.arm_ee is not None and not robot.soles


def mpc_config_for(scenario: Scenario, config: RunConfig, robot: RobotModel | None = None) -> MpcConfig:
    """The MPC settings of a run: grid and solver from `config`; weights, swing, gait period and push detection
    derived from the robot (`wbmpc.control.tuning`)."""
    if robot is not None:
        config = config.for_robot(robot)
    n = config.nodes - 1
    grid = TimeGrid.uniform_steps(n, config.uniform_dt_ms / 1e3) if config.uniform_dt_ms is not None else TimeGrid(n_intervals=n)
    tuning = (tuning_for(robot) if robot is not None else RobotTuning()).for_task(scenario.needs_arm)  # no robot: B1 + Z1's
    collision = (CollisionConfig(margin_m=config.collision_margin_m,
                                 obstacles=tuple(scenario.obstacles(robot)) if robot is not None else ())
                 if config.collision_avoidance else None)
    soft_arm = collision is not None and (robot is None or robot.arm_ee is not None)
    flat_feet = robot is not None and bool(robot.soles)
    return MpcConfig(terrain=scenario.terrain(robot) if robot is not None else None,
                     ocp=OcpConfig(formulation=config.formulation, grid=grid, collision=collision,
                                   soft_rows=("ee_vel",) if soft_arm else (),
                                   inertial_parameters=config.identify_mass,
                                   object_model=(scenario.object_model(robot) if config.options.object_model and robot is not None
                                                 else None)),
                     soft_rows_always=soft_arm, gait=scenario.gait,
                     # a warm-started step converges in ~4 iterations; one still unsolved after 30 has
                     # stalled (pushes) and goes to the bounded recovery instead of burning 100
                     solver=SolverConfig(name=config.solver, compiled=config.compiled, max_iterations=30,
                                         extra_options=_solver_options(config, flat_feet)),
                     delay_compensation=(_delay_compensation_default(config, flat_feet)
                                         if config.delay_compensation is None else config.delay_compensation),
                     step_budget_s=_step_budget_s(config),
                     **{**tuning.mpc_fields(), "weights": _collision_weights(scenario.cost_weights(tuning.weights),
                                                                         soft_arm)},
                     base_tracking=config.base_tracking,
                     # with a delay the plant does not wait: a long recovery leaves the robot on a stale
                     # plan, so it is cut shorter than MpcConfig's default budget and the last good plan,
                     # shifted in time, is held instead
                     # the anytime SQP continues from its own best iterate: no converged solver first after a rescue
                     # (an uncompiled IPOPT step takes 100+ ms: real-time push cases fell to 5 Hz with it)
                     fallback_first_s=0.0 if config.solver == "sqp" else MpcConfig.fallback_first_s,
                     fallback_solver=None if _hold_on_failure(config, flat_feet) else MpcConfig.fallback_solver,
                     recovery_time_limit_s=MpcConfig.recovery_time_limit_s if config.delay == "none"
                     else DELAYED_RECOVERY_LIMIT_S,
                     # the estimator reads the MPC's gait clock for its stance feet; in real time the clock
                     # that changes after a push lives in the solver process: keep the fixed schedule there
                     push_gait_period_scale=_push_cadence(config),
                     push_relaxed_rows=_push_relaxed_rows(config))


# rows dropped in push recovery mode by a solver with a deadline (MpcConfig.push_relaxed_rows): the arm's velocity
# rows of eq. (7) pin the hand in the world while the base flies off and make the post-push QPs infeasible (HPIPM runs
# into its iteration cap, duals diverging). b1_z1, anytime SQP with a 10 ms CPU budget (--delay measured), 6 s push
# runs at 0.8 m/s in 8 directions and 1.0 m/s at 90/270 deg: 45 deg 0.8 m/s fell without it (9 of 10 up), 10 of 10 with it
DEADLINE_PUSH_RELAXED_ROWS = ("ee_vel",)


def _push_relaxed_rows(config: RunConfig) -> tuple[str, ...]:
    return DEADLINE_PUSH_RELAXED_ROWS if _step_budget_s(config) is not None else MpcConfig.push_relaxed_rows


COLLISION_SOFT_WEIGHT_SQ = 1e4  # quadratic weight of the arm's soft velocity rows with collision avoidance, (m/s)^-2


def _collision_weights(weights, soft_arm: bool):
    """With collision avoidance the arm's velocity rows are soft on every step, their slacks weighed
    quadratically too (COLLISION_SOFT_WEIGHT_SQ): the hand follows its command wherever the collision rows
    allow and slides along a surface the command points into. With the L1 weight alone, at the default 100 the
    plan traded hand velocity for posture (the hand lagged the behind-base path by 30-50 cm), at 1000 a hand
    sent through a post stopped at it and Fatrop's interior point needed ~38 iterations per step."""
    return dataclasses.replace(weights, soft_constraint_quadratic=max(weights.soft_constraint_quadratic,
                                                                     COLLISION_SOFT_WEIGHT_SQ)) if soft_arm else weights


def default_solver(compiled: bool, delay: str, collision_avoidance: bool = False, object_model: bool = False,
                   api: bool = False) -> str:
    """The one place that picks a run's solver where none was named. `api`: `RunConfig`'s own default (the Python
    API, `solver=None`): casadi's Fatrop as always, but the anytime SQP with an object model or collision avoidance
    asked for, as for `--solver auto` (below).

    `--solver auto`: converged Fatrop for a compiled run whose plant waits for it (the paper's closed
    loop), through our direct binding (`fatrop-direct`: the same iterates as casadi's Fatrop without its
    nlpsol copies and per-solve initialisation, ~35 % less time per b1_z1 step; it falls back to casadi's
    Fatrop with a warning where the shim cannot be built); otherwise the anytime SQP, which keeps the MPC
    period: with a delay the plan must come in time, and uncompiled Fatrop takes ~25 ms per step on b1_z1
    (twice the period: "240/240 over budget" on the main job) where one uncompiled SQP iteration takes ~5 ms.
    With collision avoidance the anytime SQP always: Fatrop's interior point needs 11-16 iterations per step
    on the arm's soft velocity rows (3-5 with them hard; ~38 with an L1 weight of 1000). With the object inside the
    MPC (--object-model) too: Fatrop's line search failed on most push-box steps (hand-box contact rows with the
    box's smoothed friction), IPOPT rescued them in 10-50 iterations (0.1-0.7 s); the SQP's QPs take them."""
    if object_model or collision_avoidance:
        return "sqp"
    if api:
        return "fatrop"
    return "fatrop-direct" if compiled and delay == "none" else "sqp"


def _delay_compensation_default(config: RunConfig, flat_feet: bool) -> bool:
    """Delay compensation where the user left it open: with any --delay but none, on point feet only.

    On g1 (flat feet, free hands) the plan started from the state rolled forward with the last plan's accelerations
    set the arms oscillating at the MPC's own period (elbows and shoulders 10-30 rad/s, every other step the other
    way) once the plans came 12 ms or more after their measurement; the QPs then failed and the robot fell. RTI
    walking in place, 10 s, no recovery re-solves, fixed delays of 12 / 14 / 16 ms: with compensation it fell at
    7.8 / 5.4 / 2.3 s (58 / 66 / 22 failed steps); without it up at 12, 13, 16 and 20 ms (50 Hz) with 0 failed
    steps, and with each step's CPU time as delay (--delay measured) 0 failed either way, base velocity RMSE
    0.073 m/s against 0.085 with it. Raising the arms' Kd (3.2 -> 6) only moved the cliff (12 ms up, 13 fell).
    Quadrupeds keep it (their resolved real-time figures)."""
    return config.delay != "none" and not flat_feet


def _hold_on_failure(config: RunConfig, flat_feet: bool) -> bool:
    """A failed QP step holds the last good plan at once (no Fatrop re-solve, no IPOPT fallback): the SQP solvers
    on flat feet with a plant that does not wait. g1 walking in place with RTI in real time: a failed QP's capped
    Fatrop re-solve took ~200 ms (1555 variables, ~8 ms an iteration) and the MPC's IPOPT fallback after it up to
    the delayed recovery budget, while the plan went stale: it fell at 1.24 s, 47 Hz (i19g). Its QPs failed where
    the state had left the plan (the arms oscillating, see `_delay_compensation_default`; infeasible from there:
    hard swing-foot velocity rows on node 1 against the torque limits of nodes 0-2), not on a degenerate QP that a
    converged solver from a larger barrier would get through."""
    return flat_feet and config.solver in ("rti", "sqp") and config.delay != "none"


def _solver_options(config: RunConfig, flat_feet: bool = False) -> dict:
    """SolverConfig.extra_options of a run: --solver-option, and for rti/sqp with a delay a capped Fatrop
    re-solve of a failed QP (none on flat feet: `_hold_on_failure`); the anytime SQP measures its budget on CPU
    time where the plant waits for it."""
    options = {}
    if config.solver in ("rti", "sqp") and config.delay != "none":
        options["recovery_max_iterations"] = RECOVERY_ITERATIONS_DELAYED
    if _hold_on_failure(config, flat_feet):
        # nor a re-solve in HPIPM's balance mode: g1 at --delay 16 (RTI, 10 s), 27 QPs failed in speed_abs, 26 of
        # them failed in balance too (both at the iteration cap: 60 ms a failed step); without it the same run
        # (same 27 failed steps, up) at 30 ms a failed step
        options.update(recovery_barrier_init=None, fallback_qp_mode=None)
    if config.solver == "sqp" and config.delay not in ("realtime", "none", "measured-wall"):
        options["clock"] = "cpu"  # what the step would take on a core of its own, whatever else the machine runs
    return {**options, **config.solver_options}


# the anytime SQP's step budget without --step-budget: the MPC period less the transport and the loop's
# own work in real time (REALTIME_OVERHEAD_S), the same budget on CPU time with a simulated delay (the plant
# waits, the plan still applies --delay ms late), on wall time without delay (the solve times the main job plots)
REALTIME_OVERHEAD_S = 2.5e-3


def _step_budget_s(config: RunConfig) -> float | None:
    if config.step_budget_ms is not None:
        return config.step_budget_ms / 1e3
    if config.solver != "sqp":
        return None
    return 1.0 / LoopConfig.mpc_rate_hz - REALTIME_OVERHEAD_S


def _push_cadence(config: RunConfig) -> float | None:
    """MpcConfig.push_gait_period_scale of a run: the one asked for, else faster steps after a push with
    the converged solvers and the fixed schedule with RTI, and the fixed schedule where the estimator
    cannot see the MPC's clock (a solver process in real time).

    RTI (one SQP step per MPC step) after b1_z1's default 0.8 m/s push, 8 s runs: without delay it stays
    up on the fixed schedule and falls 2.9 s after the kick with the faster steps (scales 0.65 and 0.75
    fall too), running off sideways; in real time it falls either way (0.3 s after the kick on the
    fixed schedule, ~2.8 s with the faster steps). The anytime SQP (~2.5 iterations per step, 6 ms delay,
    compensated) takes the faster steps: the 0.8 m/s push at 0 deg falls 0.37 s after the kick on the
    fixed schedule and stays up with them (no failed step)."""
    if config.state == "estimated" and config.delay == "realtime":
        return None
    scale = config.push_gait_period_scale
    if scale is None:
        scale = 1.0 if config.solver == "rti" else MpcConfig.push_gait_period_scale
    return None if scale == 1 else scale


def run_scenario(robot: RobotModel, config: RunConfig, progress: Progress | None = None,
                 mpc: MPC | None = None, stop: Callable[[], bool] | None = None) -> ScenarioResult:
    """Build, run and measure a scenario. Ctrl-C stops the run early (see `wbmpc.interrupt`) and the
    result keeps what was measured, with `metrics["interrupted"]`; `stop` replaces that flag."""
    config = config.for_robot(robot)
    scenario = make_scenario(config.scenario, robot, config.options)
    duration = config.duration_s or scenario.default_duration_s
    scene = scenario.scene(robot)
    if scene is not None and config.plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' has scene objects and needs --plant mujoco")
    _check_terrain(robot, scenario, config)
    mpc = mpc or MPC(robot, mpc_config_for(scenario, config, robot))
    # the plant does not wait: recovery solvers must not be built mid-run (in real time the solver process
    # builds its own MPC and prepares it; this one only solves the first step, before the clock runs)
    if config.delay not in ("none", "realtime"):
        mpc.prepare_fallback()
    if mpc.config.gait != scenario.gait:
        raise ConfigError(f"the MPC passed in runs the {mpc.config.gait} gait; scenario '{scenario.name}' needs {scenario.gait}")
    with stop_flag(stop) as stop:
        if stop():  # Ctrl-C while building (CasADi's C++ build does not raise): stop before running
            raise KeyboardInterrupt
        return _run(robot, config, scenario, scene, mpc, duration, progress, stop)


def _run(robot, config, scenario, scene, mpc, duration, progress, stop) -> ScenarioResult:
    mpc.reset()
    plant_config = config.plant_config
    if plant_config is None:  # a preset's rotors (g1) are the plant's too
        plant_config = robot_plant_config(robot)
    if scene is not None:
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = scene.plant_config(specialised_config(plant_config, MujocoPlantConfig))
    if config.model_errors is not None and not config.model_errors.is_nominal:
        if config.plant != "mujoco":
            raise ConfigError("model errors (CoM offset, masses, payload, armature, floor friction) need --plant mujoco")
        plant_config = config.model_errors.plant_config(robot, plant_config)
    # the log has the configurations at 500 Hz; the plant's own per-step recording is read by nothing
    # here and would grow by ~0.3 MB per simulated second
    plant_config = dataclasses.replace(plant_config or PlantConfig(), record_every_n_steps=0)
    terrain = scenario.terrain(robot)
    if terrain is not None:  # MuJoCo builds the terrain the MPC plans on
        from wbmpc.sim.mujoco_scene import MujocoPlantConfig

        plant_config = dataclasses.replace(specialised_config(plant_config, MujocoPlantConfig), terrain=terrain)
    plant = make_plant(config.plant, robot, plant_config)
    if scene is not None:
        scene.attach(plant)
    terrain_monitor = None
    if terrain is not None:
        from wbmpc.sim.terrain_contacts import TerrainContactMonitor

        terrain_monitor = TerrainContactMonitor(plant.model, robot, terrain)
        plant.add_step_hook(terrain_monitor)
    plant.reset(scenario.start_pose(robot), np.zeros(robot.nv))
    sole_monitor = None
    if robot.soles and hasattr(plant, "sole_pressure"):  # flat feet in MuJoCo: the measured CoP on every tick
        from wbmpc.sim.sole_pressure import SolePressureMonitor

        sole_monitor = SolePressureMonitor.for_robot(robot)
        plant.add_step_hook(sole_monitor)
    identification = None
    if config.identify_mass:
        from wbmpc.estimation.inertial import ESTIMATED_STATE_CONFIG, InertialEstimator, InertialIdentification

        from_estimate = config.state == "estimated"
        estimator = InertialEstimator(robot, ESTIMATED_STATE_CONFIG) if from_estimate else InertialEstimator(robot)
        identification = InertialIdentification(estimator, mpc, from_estimate=from_estimate)
        plant.add_step_hook(identification)
    gains = scenario.pd_gains(config.gains if config.gains is not None else tuning_for(robot).gains)
    state_source = _estimated_state(plant, mpc, config) if config.state == "estimated" else None
    if identification is not None and state_source is not None:  # the estimate is what the robot would know
        state_source.listeners.append(identification.on_estimate)
    loop_config = LoopConfig(delay=config.delay, gains=gains, seed=config.seed, terrain=terrain,
                             joint_position_noise_rad=config.joint_position_noise_rad,
                             joint_velocity_noise_rad_s=config.joint_velocity_noise_rad_s)
    loop = ClosedLoop(mpc, plant, loop_config, state_source)
    log = loop.run(duration, scenario.commands(robot), scenario.events(robot), progress, stop)
    if not log.n_ticks:  # interrupted before the first control tick: nothing was measured
        raise KeyboardInterrupt
    metrics = common_metrics(robot, log, scenario.name)
    metrics.update(scenario.extra_metrics(robot, log))
    metrics["state"] = config.state
    if sole_monitor is not None:
        metrics.update(sole_monitor.metrics())
    metrics.update(self_collision_metrics(plant, mpc, log))
    if terrain_monitor is not None:
        metrics.update(terrain_monitor.metrics())
    metrics["settings"] = _settings_report(robot, mpc, loop_config.gains, scenario.needs_arm)
    if identification is not None:
        metrics.update(identification.metrics(config.model_errors))
    if state_source is not None:
        from wbmpc.estimation.metrics import estimation_metrics

        metrics.update(estimation_metrics(state_source.log))
    metrics.update({"delay": config.delay, "plant": config.plant, "nodes": config.nodes,
                    "time_steps": "geometric" if config.uniform_dt_ms is None else "uniform",
                    "uniform_dt_ms": config.uniform_dt_ms, "base_tracking": mpc.config.base_tracking,
                    "push_gait_period_scale": mpc.config.push_gait_period_scale,
                    **solver_summary(mpc, config),
                    "requested_duration_s": float(duration), "interrupted": bool(log.interrupted),
                    "drive_train": _drive_train_summary(robot, plant.config)})
    return ScenarioResult(scenario, metrics, log, scene, plant=plant,
                          estimation=state_source.log if state_source is not None else None)


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


def _settings_report(robot: RobotModel, mpc: MPC, gains: PdGains, holds_hand: bool = False) -> dict:
    """{"values": {setting: value}, "sources": {setting: source}} of the run: derived / table as `wbmpc info`
    says, "option" where the run used another value (a command-line option, the scenario's own gains)."""
    tuning = tuning_for(robot).for_task(holds_hand)
    used = dataclasses.replace(tuning, gains=gains, **{key: getattr(mpc.config, key) for key in tuning.mpc_fields()})
    report = tuning.report()
    used_report = used.report()
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
    return EstimatedState(plant, mpc.gait, sensors, terrain=mpc.config.terrain)


def _check_terrain(robot: RobotModel, scenario: Scenario, config: RunConfig) -> None:
    """A scenario on a terrain needs MuJoCo (the pinocchio plant's ground is a plane) and a start pose on the
    terrain, not inside it (`sim.terrain_geoms.check_start_pose`); checked before anything is built."""
    terrain = scenario.terrain(robot)
    if terrain is None:
        return
    if config.plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' walks on a terrain ({terrain.name}), which only the MuJoCo plant "
                          "builds: use --plant mujoco")
    from wbmpc.sim.terrain_geoms import check_start_pose

    check_start_pose(robot, terrain, scenario.start_pose(robot))



def write_outputs(robot: RobotModel, result: ScenarioResult, out_dir: Path) -> list[Path]:
    """metrics.json, PNG plots and a self-contained HTML replay, published together (`outputs.py`)."""

    def write(folder: Path) -> list[Path]:
        from wbmpc.viz import save_plots, save_replay

        paths = [folder / "metrics.json"]
        paths[0].write_text(to_json(result.metrics, indent=2) + "\n")
        scenario = result.scenario
        reference = scenario.ee_reference(robot)
        paths += save_plots(robot, result.log, folder, ee_reference=reference,
                            ee_error=lambda t, ee: scenario.ee_tracking_error(robot, t, ee),
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
