"""The MPC's configuration policy: (robot, task's needs, delay mode, solver, options) -> `MpcConfig`.

Every front end (`wbmpc run`'s scenarios, `wbmpc deploy`, campaigns, benchmarks) passes its choices
(`MpcChoices`: the options a user sets, each declared once with its flag) and what its task needs
(`TaskNeeds`: gait, a held or sweeping hand, obstacles, an object model, weights); `mpc_config` derives
the rest here, in one place: the robot's tuning (control/tuning.py), the solver where none was named
(`default_solver`), collision avoidance where left open, the step budget of a solver with a deadline,
delay compensation and the recovery of failed steps for a plant that does not wait, and the step
cadence after a push.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

from wbmpc.control.biped import biped_on_terrain
from wbmpc.control.config import BASE_TRACKING_MODES, MpcConfig, PushConfig, RecoveryConfig
from wbmpc.control.delay import DELAY_MODES, MAX_FIXED_DELAY_MS, check_delay
from wbmpc.control.loop import MPC_RATE_HZ
from wbmpc.control.tuning import RobotTuning, tuning_for
from wbmpc.control.weights import CostWeights
from wbmpc.errors import ConfigError, unknown_name
from wbmpc.ocp.formulations import FORMULATIONS
from wbmpc.ocp.grid import MAX_INTERVALS, MAX_STEP_S, TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.options import check_fields, option
from wbmpc.robots import RobotModel
from wbmpc.robots.collision_model import CollisionConfig
from wbmpc.solvers.nlp import SOLVERS, SolverConfig

DELAYED_RECOVERY_PERIODS = 4  # a failed step's recovery budget with a delay, in MPC periods (0.05 s at 80 Hz)
RECOVERY_ITERATIONS_DELAYED = 10  # the RTI's Fatrop re-solve of a failed QP, when the plant does not wait (~50 ms)
# a warm-started step converges in ~4 iterations; one still unsolved after 30 has stalled (pushes) and goes to
# the bounded recovery instead of burning 100
MAX_ITERATIONS = 30
# the anytime SQP's step budget without --step-budget: the MPC period less the transport and the loop's own work
# in real time, the same budget on CPU time with a simulated delay (the plant waits, the plan still applies
# --delay-ms late), on wall time without delay
REALTIME_OVERHEAD_S = 2.5e-3
# rows a solver with a deadline drops in push recovery mode (PushConfig.relaxed_rows): the arm's velocity rows of
# eq. (7) pin the hand in the world while the base flies off and make the post-push QPs infeasible (HPIPM runs
# into its iteration cap, duals diverging); b1_z1's 0.8 m/s pushes in 8 directions stay up with it, not without
DEADLINE_PUSH_RELAXED_ROWS = ("ee_vel",)
# quadratic weight of the arm's soft velocity rows with collision avoidance, (m/s)^-2 (`collision_weights`)
COLLISION_SOFT_WEIGHT_SQ = 1e4


@dataclass(frozen=True)
class TaskNeeds:
    """What a task asks of the MPC (a scenario's `needs`, a deployment's)."""

    gait: str = "trot"
    commands_ee: bool = False  # the hand's velocity or force is commanded (the robot's hand-held tuning)
    sweeps_ee: bool = False  # the hand sweeps the workspace (collision avoidance on by default with an arm)
    obstacles: tuple = ()  # boxes fixed in the world that collision avoidance keeps the robot off
    object_model: object | None = None  # the manipulated object inside the OCP (`wbmpc.ocp.objects`), or None
    terrain: object | None = None  # the ground (`wbmpc.terrain.Terrain`) the task walks on; None: the flat floor
    # the task's cost weights given the robot's (None: the robot's)
    adjust_weights: Callable[[CostWeights], CostWeights] | None = field(default=None, compare=False)

    def weights(self, robot_weights: CostWeights) -> CostWeights:
        return self.adjust_weights(robot_weights) if self.adjust_weights is not None else robot_weights


@dataclass
class MpcChoices:
    """The MPC options a user chooses, each declared once (`wbmpc.options`): `wbmpc run`'s flags and `RunConfig`'s
    fields of the same names, `wbmpc deploy`'s, campaign cases'. `solver` "auto" (the CLI's) or None (the Python
    API's) is resolved here (`default_solver`); `collision_avoidance` None by `for_robot`."""

    delay_mode: str = option("none", flag="--delay-mode", choices=DELAY_MODES, help="when a plan reaches the plant: "
                             "none (the simulation waits for the solver) | measured (the step's CPU time elapses: its "
                             "time on a core of its own) | measured-wall (its wall time) | fixed (--delay-ms) | "
                             "realtime (solver in its own process, wall-clock paced)")
    delay_ms: float | None = option(None, flag="--delay-ms", metavar="MS", low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms",
                                    help="a fixed delay of the plans (implies --delay-mode fixed)")
    mpc_rate_hz: float = option(MPC_RATE_HZ, flag="--mpc-rate", metavar="HZ", low=0.0, high=1000.0, low_open=True,
                                unit="Hz", help="MPC steps per second (the anytime SQP's default step budget is its "
                                "period less the transport)")
    nodes: int = option(15, flag="--nodes", help="horizon nodes", integer=True, low=2, high=MAX_INTERVALS + 1,
                        default_text="15 = the paper's")
    uniform_dt_ms: float | None = option(None, flag="--uniform-dt", metavar="MS", help="uniform time steps of MS ms "
                                         "instead of the geometric 10-100 ms grid", low=0.0, high=1e3 * MAX_STEP_S,
                                         low_open=True, unit="ms")
    solver: str | None = option(None, flag="--solver", cli_default="auto", help="auto (fatrop-direct for --compiled "
                                "runs with --delay-mode none, else sqp), fatrop (converged), fatrop-direct (the same Fatrop "
                                "through its C interface, always compiled), ipopt, rti (one SQP iteration per step on "
                                "HPIPM's QP) or sqp (anytime SQP: iterations with a line search until converged or the "
                                "step's deadline)")
    formulation: str = option("wb_inverse", flag="--formulation", help="OCP formulation of Table I (see bench table1)")
    compiled: bool = option(False, flag="--compiled", help="generate C for the NLP, compile it once (cached in "
                            "~/.cache/wbmpc) and use it")
    base_tracking: str = option("position", flag="--base-tracking", choices=BASE_TRACKING_MODES,
                                help="position: base x/y/yaw anchored to the integrated command, corrects drift; "
                                "velocity: the paper's velocity-only base tracking, drift uncorrected")
    collision_avoidance: bool | None = option(
        None, flag="--collision-avoidance", choices=("on", "off"), const="on", parse=lambda text: text == "on",
        help="hard rows keeping the arm off the base and the legs and the legs apart (capsules from the URDF's "
        "collision geometry) and the scene's boxes (arm-track --target-path around-obstacle) off the arm; the arm's "
        "velocity command becomes soft, so the hand stops at or slides along the margin instead of the OCP turning "
        "infeasible; solver auto: the anytime SQP",
        default_text="on for arm-track on a legged base carrying an arm, off otherwise")
    collision_margin_m: float = option(0.03, flag="--collision-margin", help="with --collision-avoidance: smallest "
                                       "distance kept between two capsules", low=0.0, high=0.3, unit="m")
    # PushConfig.gait_period_scale; None: the solver's default (`push_cadence`)
    push_gait_period_scale: float | None = option(
        None, flag="--push-cadence", metavar="SCALE", low=0.0, high=1.0, low_open=True,
        help="after a push (any scenario) the gait period is scaled by this while in push recovery mode and 1 s "
        "after; 1: the paper's fixed schedule",
        default_text="0.5625: the 0.8 s trot steps every 0.45 s; with --solver rti 1")
    solver_options: dict = option(default_factory=dict, flag="--solver-option", metavar="KEY=VALUE", repeat=True,
                                  parse=lambda items: parse_solver_options(items),
                                  help="a setting of the rti/sqp solvers (RtiConfig/AnytimeConfig), repeatable: e.g. "
                                  "sqp_iterations=2, budget_ms=5, clock=cpu")
    # MpcConfig.delay_compensation; None: `delay_compensation_default`
    delay_compensation: bool | None = option(
        None, flag="--delay-compensation", choices=("on", "off"), parse=lambda text: text == "on",
        help="plan from the state predicted for when the plan applies (the measurement rolled forward over the "
        "expected delay: the joint loop run on the last plan, stance feet held)",
        default_text="on with any delay mode but none")
    # MpcConfig.step_budget_s of the anytime solver; None: `step_budget_s`
    step_budget_ms: float | None = option(
        None, flag="--step-budget", metavar="MS", low=0.0, high=1e4, low_open=True, unit="ms",
        help="sqp: the MPC step's time budget", default_text="the MPC period (12.5 ms at 80 Hz) less 2.5 ms of "
        "transport, on CPU time with a simulated delay")
    friction_mu: float | None = option(None, flag="--friction", metavar="MU", low=0.0, high=2.0, low_open=True,
                                       help="the ground's friction coefficient the MPC plans with (the cone rows of "
                                       "eq. 6)", default_text="the robot's tuning, `wbmpc info` shows it")
    touchdown_events: bool = option(False, flag="--touchdown-events", help="the contact schedule follows the feet's "
                                    "measured touch-down (foot forces): an early foot stays down, a late one keeps "
                                    "reaching for the ground (control/touchdown.py)")
    identify_mass: bool = option(False, flag="--identify-mass", help="estimate the base CoM offset and a payload at "
                                 "the hand online from the measured motion and torques and plan with them (NLP "
                                 "parameters); reports base_com_offset_estimate_m and payload_estimate_kg")
    # the MPC's gait clock is read by a state estimator (its stance feet): the push cadence must stay visible to it
    estimated_state: bool = False
    # the task's object goes inside the OCP (`ScenarioOptions.object_model`, --object-model): the solver's choice
    object_model: bool = False
    # set where `solver` was "auto": `for_robot` chooses again once collision avoidance is decided
    auto_solver: bool = field(default=False, repr=False)

    def __post_init__(self):
        """Ranges and the choices' consistency, checked before anything is built (errors name the field)."""
        check_fields(self)
        if self.delay_ms is not None and self.delay_mode == "none":
            self.delay_mode = "fixed"
        check_delay(self.delay_mode, self.delay_ms)
        if self.solver in ("auto", None):
            self.auto_solver = self.solver == "auto"
            self.solver = default_solver(self.compiled, self.delay_mode, bool(self.collision_avoidance),
                                         self.object_model, api=self.solver is None)
        if self.formulation not in FORMULATIONS:
            raise ConfigError(unknown_name("formulation", self.formulation, FORMULATIONS))
        if self.solver not in SOLVERS:
            raise ConfigError(unknown_name("solver", self.solver, SOLVERS))
        if self.push_gait_period_scale not in (None, 1.0) and self.estimated_state and self.delay_mode == "realtime":
            raise ConfigError("a faster step cadence after a push (--push-cadence) changes the MPC's gait clock in the "
                              "solver process, which the estimator of --state estimated --delay-mode realtime cannot "
                              "see: leave --push-cadence out (that run keeps the fixed schedule) or set it to 1")
        if self.solver_options and self.solver not in ("rti", "sqp"):
            raise ConfigError(f"--solver-option sets the rti/sqp solvers' settings; the {self.solver} solver has none "
                              "(use --solver rti or --solver sqp)")
        if self.solver_options:  # unknown names and bad values refused before anything is built
            from wbmpc.solvers.anytime import AnytimeConfig
            from wbmpc.solvers.rti import RtiConfig

            (AnytimeConfig if self.solver == "sqp" else RtiConfig).from_options(self.solver_options)
        if self.identify_mass and (self.delay_mode == "realtime" or not self.formulation.startswith("wb_")):
            raise ConfigError(IDENTIFY_MASS_NEEDS)

    def for_robot(self, robot: RobotModel, sweeps_ee: bool) -> MpcChoices:
        """These choices on `robot` for a task that sweeps its hand or not: collision avoidance decided where left
        open (`collision_avoidance_default`) and an automatic solver chosen again with it."""
        if self.collision_avoidance is not None:
            return self
        on = collision_avoidance_default(sweeps_ee, robot)
        return dataclasses.replace(self, collision_avoidance=on, solver="auto" if self.auto_solver else self.solver)


IDENTIFY_MASS_NEEDS = ("--identify-mass observes the MuJoCo plant's steps and updates the whole-body model of the MPC "
                       "in this process: use --plant mujoco, a wb_* --formulation and no --delay-mode realtime")


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


def follows_contact_switches(robot: RobotModel | None) -> bool:
    """Whether the geometric grid's far nodes sit on the gait's contact switches (`TimeGrid.follow_contact_switches`):
    for flat feet (g1 at an 11 ms delay, 5 s: walking in place 3.83 -> 3.11 Fatrop iterations a step, walking forward
    4.58 -> 3.82; docs/design/solve-time.md); point feet keep the fixed grid."""
    return robot is not None and bool(robot.soles)


def mpc_config(robot: RobotModel | None, task: TaskNeeds, choices: MpcChoices) -> MpcConfig:
    """The complete MPC configuration of a task on `robot` (None: the paper robot's tuning, no obstacles nor
    object) with the user's `choices` (module docstring)."""
    if robot is not None:
        choices = choices.for_robot(robot, task.sweeps_ee)
    n = choices.nodes - 1
    flat_feet = robot is not None and bool(robot.soles)
    grid = (TimeGrid.uniform_steps(n, choices.uniform_dt_ms / 1e3) if choices.uniform_dt_ms is not None
            else TimeGrid(n_intervals=n, follow_contact_switches=follows_contact_switches(robot)))
    tuning = (tuning_for(robot) if robot is not None else RobotTuning()).for_task(task.commands_ee)
    collision = (CollisionConfig(margin_m=choices.collision_margin_m,
                                 obstacles=tuple(task.obstacles) if robot is not None else ())
                 if choices.collision_avoidance else None)
    soft_arm = collision is not None and (robot is None or robot.arm_ee is not None)
    ocp = OcpConfig(formulation=choices.formulation, grid=grid, collision=collision,
                    soft_rows=("ee_vel",) if soft_arm else (), inertial_parameters=choices.identify_mass,
                    object_model=task.object_model if robot is not None else None)
    solver = SolverConfig(name=choices.solver, compiled=choices.compiled, max_iterations=MAX_ITERATIONS,
                          extra_options=solver_options(choices, flat_feet))
    gait_period_s = tuning.gait_period_s
    references = tuning.reference_config(base_tracking=choices.base_tracking, terrain=task.terrain,
                                         touchdown_events=choices.touchdown_events)
    if robot is not None and len(robot.feet) == 2 and task.terrain is not None and not task.terrain.is_flat:
        gait_period_s, references = biped_on_terrain(gait_period_s, references)
    return MpcConfig(
        ocp=ocp, solver=solver, gait=task.gait, gait_period_s=gait_period_s, swing=tuning.swing,
        weights=collision_weights(task.weights(tuning.weights), soft_arm), references=references,
        recovery=recovery_config(choices, flat_feet),
        push=tuning.push_config(gait_period_scale=push_cadence(choices), relaxed_rows=push_relaxed_rows(choices)),
        delay_compensation=(delay_compensation_default(choices) if choices.delay_compensation is None
                            else choices.delay_compensation),
        step_budget_s=step_budget_s(choices), soft_rows_always=soft_arm,
        friction_coefficient=tuning.friction_coefficient if choices.friction_mu is None else choices.friction_mu)


def default_solver(compiled: bool, delay_mode: str, collision_avoidance: bool = False, object_model: bool = False,
                   api: bool = False) -> str:
    """The one place that picks a solver where none was named. `api`: the Python API's default (`solver=None`):
    casadi's Fatrop, but the anytime SQP with an object model or collision avoidance, as for `--solver auto`.

    `--solver auto`: converged Fatrop for a compiled run whose plant waits for it (the paper's closed loop),
    through the direct binding (`fatrop-direct`: the same iterates as casadi's Fatrop without its nlpsol copies
    and per-solve initialisation; it falls back to casadi's Fatrop with a warning where the shim cannot be
    built); otherwise the anytime SQP, which keeps the MPC period: with a delay the plan must come in time, and
    uncompiled Fatrop takes about twice the period on b1_z1 where one uncompiled SQP iteration takes ~5 ms. With
    collision avoidance the anytime SQP always: Fatrop's interior point needs 11-16 iterations per step on the
    arm's soft velocity rows (3-5 with them hard). With the object inside the MPC too: Fatrop's line search fails
    on most push-box steps (hand-box contact rows with the box's smoothed friction); the SQP's QPs take them."""
    if object_model or collision_avoidance:
        return "sqp"
    if api:
        return "fatrop"
    return "fatrop-direct" if compiled and delay_mode == "none" else "sqp"


def collision_avoidance_default(sweeps_ee: bool, robot: RobotModel) -> bool:
    """Collision avoidance where the user left it open: on for tasks that sweep the hand through the workspace
    on a legged base carrying an arm (the paper's arm-track path brings the Z1's wrist onto its shoulder housing
    in MuJoCo); a humanoid's hand (flat feet) keeps it off (its arm-track measured without contacts)."""
    return sweeps_ee and robot.arm_ee is not None and not robot.soles


def delay_compensation_default(choices: MpcChoices) -> bool:
    """Delay compensation where the user left it open: with any delay mode but none, on every robot.

    It was off on flat feet while the prediction integrated the last plan's accelerations: the joint PD puts g1's
    light arms on the plan's references instead, so the predicted state missed the plant and the arms oscillated
    at the MPC's period once plans came 12 ms late (QPs failed, RTI fell). The prediction now runs the motor law
    (control/delay.py): with fixed delays of 12.5 and 20 ms g1 walks with no failed step, with less drift and
    velocity error than planning from the measurement (which fell walking forward at 12.5 ms with fatrop-direct)."""
    return choices.delay_mode != "none"


def hold_on_failure(choices: MpcChoices, flat_feet: bool) -> bool:
    """A failed QP step holds the last good plan at once (no Fatrop re-solve, no IPOPT fallback): the SQP solvers
    on flat feet with a plant that does not wait. g1's failed QPs come where the state has left the plan
    (infeasible from there), not on a degenerate QP a converged solver would get through, and its capped Fatrop
    re-solve takes ~200 ms while the plan goes stale."""
    return flat_feet and choices.solver in ("rti", "sqp") and choices.delay_mode != "none"


def solver_options(choices: MpcChoices, flat_feet: bool = False) -> dict:
    """SolverConfig.extra_options: --solver-option, and for rti/sqp with a delay a capped Fatrop re-solve of a
    failed QP (none on flat feet, nor a re-solve in HPIPM's balance mode: `hold_on_failure`); the anytime SQP
    measures its budget on CPU time where the plant waits for it."""
    options = {}
    if choices.solver in ("rti", "sqp") and choices.delay_mode != "none":
        options["recovery_max_iterations"] = RECOVERY_ITERATIONS_DELAYED
    if hold_on_failure(choices, flat_feet):
        options.update(recovery_barrier_init=None, fallback_qp_mode=None)
    if choices.solver == "sqp" and choices.delay_mode not in ("realtime", "none", "measured-wall"):
        options["clock"] = "cpu"  # what the step would take on a core of its own, whatever else the machine runs
    return {**options, **choices.solver_options}


def recovery_config(choices: MpcChoices, flat_feet: bool) -> RecoveryConfig:
    """Failed steps: with a delay the plant does not wait, so a long recovery leaves the robot on a stale plan:
    it is cut shorter (DELAYED_RECOVERY_PERIODS) and the last good plan, shifted in time, is held instead. When
    the plant waits (delay mode "none") the re-solves are capped by iterations only: a CPU or wall-time budget
    would make a run's outcome depend on the machine's load, and a waiting run must be reproducible. The
    anytime SQP continues from its own best iterate: no converged solver first after a rescue (an uncompiled
    IPOPT step takes 100+ ms)."""
    default = RecoveryConfig()
    return RecoveryConfig(
        fallback_first_s=0.0 if choices.solver == "sqp" else default.fallback_first_s,
        fallback_solver=None if hold_on_failure(choices, flat_feet) else default.fallback_solver,
        budget_s=None if choices.delay_mode == "none" else DELAYED_RECOVERY_PERIODS / choices.mpc_rate_hz)


def step_budget_s(choices: MpcChoices) -> float | None:
    """The anytime SQP's step budget (REALTIME_OVERHEAD_S); --step-budget where given; None for other solvers."""
    if choices.step_budget_ms is not None:
        return choices.step_budget_ms / 1e3
    if choices.solver != "sqp":
        return None
    return 1.0 / choices.mpc_rate_hz - REALTIME_OVERHEAD_S


def push_cadence(choices: MpcChoices) -> float | None:
    """PushConfig.gait_period_scale: the one asked for, else faster steps after a push with the converged solvers
    and the anytime SQP, the fixed schedule with RTI (one SQP step per MPC step: b1_z1's 0.8 m/s push falls with
    the faster steps and stays up without), and the fixed schedule where the estimator cannot see the MPC's clock
    (a solver process in real time). None: the fixed schedule."""
    if choices.estimated_state and choices.delay_mode == "realtime":
        return None
    scale = choices.push_gait_period_scale
    if scale is None:
        scale = 1.0 if choices.solver == "rti" else PushConfig.gait_period_scale
    return None if scale == 1 else scale


def push_relaxed_rows(choices: MpcChoices) -> tuple[str, ...]:
    return DEADLINE_PUSH_RELAXED_ROWS if step_budget_s(choices) is not None else PushConfig.relaxed_rows


def collision_weights(weights: CostWeights, soft_arm: bool) -> CostWeights:
    """With collision avoidance the arm's velocity rows are soft on every step, their slacks weighed
    quadratically too (COLLISION_SOFT_WEIGHT_SQ): the hand follows its command wherever the collision rows
    allow and slides along a surface the command points into. With the L1 weight alone the plan trades hand
    velocity for posture (at the default 100) or stops a hand sent through a post at it (at 1000)."""
    if not soft_arm:
        return weights
    return dataclasses.replace(weights, soft_constraint_quadratic=max(weights.soft_constraint_quadratic,
                                                                     COLLISION_SOFT_WEIGHT_SQ))
