"""What a scenario is (`Scenario`) and the user knobs every scenario reads (`ScenarioOptions`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import Event
from wbmpc.control.policy import TaskNeeds
from wbmpc.control.run_log import RunLog
from wbmpc.control.weights import CostWeights
from wbmpc.gait import GAIT_NAMES
from wbmpc.options import check_fields, option
from wbmpc.robots import RobotModel

PUSH, ARM_TRACK, PULL, WIPE, COMPLIANT = ("push",), ("arm-track",), ("pull",), ("wipe",), ("compliant",)
TERRAIN_COURSES = ("stairs", "slope", "stepping-stones")  # scenarios/terrain.py


@dataclass
class ScenarioOptions:
    """User-tunable knobs of the scenarios, each declared once with its flag, help, range and the
    scenarios that read it (`wbmpc.options`); the names are also campaign axes. None means the
    scenario's default."""

    speed_m_s: float = option(0.2, flag="--speed", help="forward speed", low=-1.5, high=1.5, unit="m/s",
                              scenarios=("trot-forward", "walk-forward", "arm-track") + TERRAIN_COURSES)
    push_speed_m_s: float = option(0.8, flag="--push-speed", help="base velocity kick", low=0.0, high=5.0, unit="m/s",
                                   scenarios=PUSH)
    push_direction_deg: float = option(90.0, flag="--push-direction", help="direction of the kick in the heading "
                                       "frame (90: to the robot's left)", low=-360.0, high=360.0, unit="deg",
                                       scenarios=PUSH)
    push_time_s: float = option(2.0, flag="--push-time", help="time of the kick", low=0.0, unit="s",
                                scenarios=PUSH)
    # arm-track's reference (no flag: Python API and campaign axes)
    arm_amplitude_m: float = option(0.15, help="height amplitude of the end-effector reference", low=0.0, high=0.5,
                                    unit="m", scenarios=ARM_TRACK)
    arm_period_s: float = option(4.0, help="period of the end-effector reference", low=0.0, high=60.0,
                                 low_open=True, unit="s", scenarios=ARM_TRACK)
    arm_feedback_gain_1_s: float = option(4.0, help="feedback gain on the end-effector position error", low=0.0,
                                          high=100.0, unit="1/s", scenarios=ARM_TRACK)
    arm_integral_gain_1_s2: float = option(8.0, flag="--arm-integral", metavar="1/S2", help="integral gain on the "
                                           "end-effector position error (0: proportional feedback only): removes "
                                           "the steady offset of an arm heavier than the model", low=0.0,
                                           high=1e4, unit="1/s^2", scenarios=ARM_TRACK)
    arm_target_path: str = option("sine", flag="--target-path", choices=("sine", "behind-base", "around-obstacle"),
                                  help="sine: the low/high reference of Fig. 3; behind-base: from the nominal hand "
                                  "position straight to behind the base at trunk height, through the trunk's rear "
                                  "(provokes self-collisions; --collision-avoidance), held, and back; "
                                  "around-obstacle: trotting in place (--speed ignored), the hand sweeps from the "
                                  "robot's front left to its front right straight through a post standing there "
                                  "(a fixed box in MuJoCo, an obstacle of --collision-avoidance), and back",
                                  scenarios=ARM_TRACK)
    gait: str | None = option(None, flag="--gait", choices=GAIT_NAMES, help="override the scenario's gait (pull: "
                              "stand = pull in stance)", default_text="the scenario's")
    # loco-manipulation (section VI-C)
    load_kg: float = option(10.0, flag="--load-kg", help="mass of the load on the floor", low=0.0, high=1000.0,
                            low_open=True, unit="kg", scenarios=PULL)
    load_friction_mu: float = option(0.3, flag="--load-friction", help="load-floor friction coefficient", low=0.0,
                                     high=5.0, scenarios=PULL)
    cable_length_m: float = option(1.6, flag="--cable-length", help="cable length", low=0.0, high=10.0,
                                   low_open=True, unit="m", scenarios=PULL)
    pull_speed_m_s: float = option(0.1, flag="--pull-speed", help="backwards walking (or arm, in stance) speed",
                                   low=0.0, high=1.5, unit="m/s", scenarios=PULL)
    force_n: float | None = option(None, flag="--force-n", help="end-effector force target", low=0.0, high=1e4,
                                   low_open=True, unit="N", scenarios=("pull", "push-box", "wipe"),
                                   default_text="pull: the load's sliding tension; push-box: 20; wipe: 10 normal")
    box_kg: float = option(5.0, flag="--box-kg", help="mass of the box", low=0.0, high=1000.0, low_open=True,
                           unit="kg", scenarios=("push-box",))
    box_path: str = option("wall", flag="--box-path", choices=("wall", "turn"), help="wall: press the box against a "
                           "wall trotting in place; turn: push a free box along a path at 0.1 m/s with a 90 degree "
                           "turn (--box-turn-radius; implied by --object-model), a force command without --object-model",
                           scenarios=("push-box",))
    # the manipulated object inside the MPC (wbmpc.ocp.objects)
    object_model: bool = option(False, flag="--object-model", help="plan with the manipulated object inside the "
                                "MPC: its state and dynamics in the OCP, the hand force a variable, the object's "
                                "motion the command (push-box: the box's path; pull: the load's speed)",
                                scenarios=("push-box", "pull"))
    box_turn_radius_m: float = option(0.8, flag="--box-turn-radius", help="the radius of push-box's 90 degree turn "
                                      "(--box-path turn, --object-model)", low=0.0, high=100.0, low_open=True,
                                      unit="m", scenarios=("push-box",))
    push_height_m: float | None = option(None, flag="--push-height", help="with --object-model: the hand's height on "
                                         "the box's face (a contact row of the OCP; the base crouches to 85 percent)",
                                         low=0.0, high=3.0, low_open=True, unit="m", scenarios=("push-box",),
                                         default_text="where the robot's nominal posture holds the hand")
    board: str = option("vertical", flag="--board", choices=("vertical", "horizontal"),
                        help="vertical (whiteboard) or horizontal (table)", scenarios=WIPE)
    board_friction_mu: float = option(0.3, flag="--board-friction", help="board friction coefficient", low=0.0,
                                      high=5.0, scenarios=WIPE)
    wipe_pattern: str = option("circle", flag="--pattern", choices=("circle", "eight"), help="wiping pattern",
                               scenarios=WIPE)
    wipe_size_m: float = option(0.1, flag="--wipe-size", help="pattern radius", low=0.0, high=0.5, low_open=True,
                                unit="m", scenarios=WIPE)
    wipe_period_s: float = option(4.0, flag="--wipe-period", help="pattern period", low=0.0, high=60.0,
                                  low_open=True, unit="s", scenarios=WIPE)
    wipe_pad_stiffness_n_m: float = option(2000.0, flag="--pad-stiffness", metavar="N/M", help="stiffness of the "
                                           "sprung wiping pad on the end-effector (0: rigid sphere)", low=0.0,
                                           high=1e6, unit="N/m", scenarios=WIPE)
    wipe_integral_gain_1_s2: float = option(30.0, flag="--wipe-integral", metavar="1/S2", help="integral gain on the "
                                            "in-plane path error (0: proportional feedback only)", low=0.0,
                                            high=1e4, unit="1/s^2", scenarios=WIPE)
    # issue 35: off the flat floor (wbmpc.terrain, scenarios/terrain.py)
    terrain_file: str | None = option(None, flag="--terrain", metavar="FILE", help="walk on the terrain of a YAML "
                                      "file (boxes, ramps, heightmaps; docs/terrain.md): MuJoCo builds it, the MPC "
                                      "plans on it", scenarios=("trot-forward", "walk-forward", "arm-track", "pull"))
    steps: int = option(5, flag="--steps", metavar="N", help="risers of the staircase", integer=True, low=1, high=50,
                        scenarios=("stairs",))
    step_rise_m: float | None = option(None, flag="--step-rise", help="height of each step", low=0.0, high=0.5,
                                       low_open=True, unit="m", scenarios=("stairs",),
                                       default_text="the robot's: 23 percent of its standing height on four feet (12 "
                                       "cm on b1_z1, 8 on go2), 10 cm on two")
    step_tread_m: float | None = option(None, flag="--step-tread", help="depth of each step", low=0.1, high=3.0,
                                        unit="m", scenarios=("stairs",),
                                        default_text="the robot's: 57 percent of its standing height, at least 25 cm "
                                        "(30 cm on b1_z1, 25 on go2); 30 cm on two feet")
    stairs_direction: str = option("up-down", flag="--stairs", choices=("up-down", "up", "down"),
                                   help="up (to a landing), down (from a landing, where the robot starts) or up-down "
                                   "(up, across the landing, down)", scenarios=("stairs",))
    slope_deg: float | None = option(None, flag="--slope-deg", metavar="DEG", help="slope: a ramp up at this angle, a "
                                     "plateau and a ramp down; arm-track, pull: a ramp up along the robot's path",
                                     low=0.0, high=35.0, low_open=True, unit="deg",
                                     scenarios=("slope", "arm-track", "pull"),
                                     default_text="slope: 15; arm-track and pull: the flat floor")
    gap_m: float = option(0.1, flag="--gap", help="gap between stepping stones, along and across the path", low=0.0,
                          high=0.5, unit="m", scenarios=("stepping-stones",))
    stone_size_m: float = option(0.25, flag="--stone-size", help="side of the square stepping stones", low=0.1,
                                 high=1.0, unit="m", scenarios=("stepping-stones",))
    hand_force_n: float = option(30.0, flag="--hand-force", help="peak force of the external hand", low=0.0,
                                 high=1e3, unit="N", scenarios=COMPLIANT)
    compliant_kp_arm: float = option(2.0, flag="--compliant-kp-arm", help="arm joint Kp", low=0.0, high=1e4,
                                     scenarios=COMPLIANT)
    compliant_kd_arm: float = option(0.3, flag="--compliant-kd-arm", help="arm joint Kd", low=0.0, high=1e4,
                                     scenarios=COMPLIANT)
    compliant_return_gain_1_s: float = option(0.5, flag="--compliant-return", metavar="1/S", help="gain of the slow "
                                              "return to the nominal end-effector place (0: the paper's zero "
                                              "end-effector velocity target)", low=0.0, high=100.0, unit="1/s",
                                              scenarios=COMPLIANT)

    def __post_init__(self):
        """Ranges and choices of every knob, checked before anything is built (the CLI names the flag)."""
        check_fields(self)


@dataclass
class Scenario:
    """Commands, disturbances, scene objects, low-level gains and metrics of one named task."""

    name: str
    description: str
    gait: str
    default_duration_s: float
    needs_arm: bool = False
    options: ScenarioOptions = field(default_factory=ScenarioOptions)
    sweeps_ee = False  # the hand sweeps the workspace: collision avoidance on by default (control/policy.py)

    def __post_init__(self):
        if self.options.gait is not None:
            self.gait = self.options.gait

    def needs(self, robot: RobotModel | None) -> TaskNeeds:
        """What this task asks of the MPC on `robot` (None: the task as declared, no obstacles nor object)."""
        return TaskNeeds(gait=self.gait, commands_ee=self.needs_arm, sweeps_ee=self.sweeps_ee,
                         obstacles=tuple(self.obstacles(robot)) if robot is not None else (),
                         object_model=self.object_model(robot) if self.options.object_model and robot is not None
                         else None, adjust_weights=self.cost_weights,
                         terrain=self.terrain(robot) if robot is not None else None)

    def commands(self, robot: RobotModel):
        return lambda t_s, q, v: Commands()

    def events(self, robot: RobotModel) -> list[Event]:
        return []

    def ee_reference(self, robot: RobotModel):
        """Callable t -> EE position reference (world), or None."""
        return None

    ee_error_label = "|p - p_ref|"

    def ee_tracking_error(self, robot: RobotModel, t_s: np.ndarray, ee: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(error vectors (n, 3), mask of the samples counted) of measured end-effector positions `ee`
        at times `t`: what `ee_pos_rmse_m` and the end-effector plot's RMSE are computed from. By
        default the 3D distance to `ee_reference` over the whole run; None without a reference."""
        reference = self.ee_reference(robot)
        if reference is None:
            return None
        return ee - np.array([np.asarray(reference(float(tk)), dtype=float) for tk in t_s]), np.ones(len(t_s), dtype=bool)

    def scene(self, robot: RobotModel):
        """`wbmpc.sim.objects.Scene` with the objects of the task, or None (robot on a flat floor)."""
        return None

    def terrain(self, robot: RobotModel):
        """The ground (`wbmpc.terrain.Terrain`: MuJoCo builds it, the MPC plans on it), or None: the flat floor."""
        return None

    def start_pose(self, robot: RobotModel) -> np.ndarray:
        """The configuration the run starts from: the nominal pose, raised onto the terrain under it."""
        terrain = self.terrain(robot)
        q = robot.q_nominal.copy()
        if terrain is not None:
            from wbmpc.control.terrain_references import support_footprint

            q[2] += float(support_footprint(robot, terrain).height(q[:2], 0.0))
        return q

    def object_model(self, robot: RobotModel):
        """The OCP's model of the manipulated object (`wbmpc.ocp.objects.ObjectModel`, `--object-model`), or None."""
        return None

    def obstacles(self, robot: RobotModel) -> tuple:
        """Boxes fixed in the world (`wbmpc.robots.collision_model.Obstacle`) that collision avoidance keeps
        the hand and the feet off (the scene's own boxes, seen by the MPC); none by default."""
        return ()

    def pd_gains(self, gains: PdGains) -> PdGains:
        """Joint PD gains of eq. (10) for this task, given the configured ones."""
        return gains

    def cost_weights(self, weights: CostWeights) -> CostWeights:
        """Weights of eq. (3) for this task, given the robot's (control/tuning.py)."""
        return weights

    def check(self, robot: RobotModel) -> None:
        """Raise `ConfigError` (or warn) before a run when the options cannot work on `robot`."""

    def extra_metrics(self, robot: RobotModel, log: RunLog) -> dict:
        return {}

    def failure(self, metrics: dict) -> str | None:
        """Why the run failed its task (`wbmpc run` then exits 1), or None: by default, a fall."""
        if metrics.get("fell"):
            return f"the robot fell at {metrics['fell_at_s']:.2f} s"
        return None

    def extra_plots(self, robot: RobotModel, log: RunLog, out_dir) -> list:
        return []
