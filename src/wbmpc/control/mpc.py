"""`MPC`: measured state + commands + time -> `Solution` (section V-A).

One OCP and one solver are built at construction; every step only packs parameters and bounds,
warm-starts from the previous solution shifted in time (contact forces re-initialised: weight
shared over the stance feet, zero on swing feet, section V-A2) and calls the solver.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.control.delay import roll_forward
from wbmpc.control.foot_placement import StanceReference, SwingPlacement
from wbmpc.control.solution import Solution
from wbmpc.control.terrain_references import TerrainReferences
from wbmpc.errors import ConfigError, check_number
from wbmpc.gait import GaitClock, SwingProfile, make_gait
from wbmpc.ocp.objects import ObjectCommand
from wbmpc.ocp.problem import OcpConfig, OcpProblem, StageBounds
from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.solvers import make_solver
from wbmpc.solvers.buffered import BufferedFunction
from wbmpc.solvers.nlp import FATROP_SOLVERS, NlpSolver, SolverConfig
from wbmpc.terrain import FootholdConfig, Terrain

COLD_FALLBACK_ITERATIONS = 300  # the fallback's cap on a run's first step (no plan to hold while it solves)


@dataclass
class CostWeights:
    """Diagonal Q and R of eq. (3). Parameters of the NLP: change them between steps freely.

    Posture weights dominate the force pull (otherwise the optimum trades height for equal force
    shares and the robot sinks); the regularisation of a, F and tau keeps Fatrop at ~5 iterations.
    """

    base_position: tuple[float, float, float] = (500.0, 500.0, 1e4)
    base_orientation: tuple[float, float, float] = (1e4, 1e4, 2000.0)  # roll, pitch, yaw
    leg_joint_position: float = 50.0
    arm_joint_position: float = 100.0
    base_linear_velocity: float = 50.0
    base_angular_velocity: float = 50.0
    joint_velocity: float = 1.0
    acceleration: float = 1e-2
    contact_force: float = 1e-3  # pull towards the weight shared over the stance feet
    joint_torque: float = 1e-3
    # L1 weight of the soft rows' slacks (OcpConfig.soft_rows) per unit violation (m/s for the arm's
    # velocity): above the rows' multipliers on nominal trot steps (<= 60 on b1_z1), so those plans
    # stay exact; 1e3 leaves nominal Fatrop steps unconverged after 200 iterations, 50 is not exact
    soft_constraint: float = 100.0
    # quadratic weight of the same slacks per (m/s)^2 (0: the exact L1 penalty alone). With collision avoidance
    # the arm's command meets the collision rows: under L1 alone a command pointing within 45 deg of a surface's
    # normal stops the hand there (moving along the surface costs more than stopping), a quadratic weight makes it
    # slide along (the command's projection); Fatrop's interior point also converges on it where a 1e3 L1 does not
    soft_constraint_quadratic: float = 0.0

    def __post_init__(self):
        for name, value in vars(self).items():
            for item in np.atleast_1d(np.asarray(value, dtype=float)):
                check_number(f"weights.{name}", float(item), low=0.0)

    def vectors(self, robot: RobotModel, nf: int) -> dict[str, np.ndarray]:
        nj = robot.n_joints
        joints = np.where(robot.leg_joint_mask, self.leg_joint_position, self.arm_joint_position)
        return {
            "w_dq": np.concatenate([self.base_position, self.base_orientation, joints]),
            "w_v": np.concatenate([[self.base_linear_velocity] * 3, [self.base_angular_velocity] * 3, [self.joint_velocity] * nj]),
            "w_a": np.full(robot.nv, self.acceleration),
            "w_F": np.full(nf, self.contact_force),
            "w_tau": np.full(nj, self.joint_torque),
            "w_slack": [self.soft_constraint],
            "w_slack_sq": [self.soft_constraint_quadratic],
        }


BASE_TRACKING_MODES = ("position", "velocity")


@dataclass
class MpcConfig:
    ocp: OcpConfig = field(default_factory=OcpConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    gait: str = "trot"
    gait_period_s: float | None = None
    swing: SwingProfile = field(default_factory=SwingProfile)
    friction_coefficient: float = 0.7
    weights: CostWeights = field(default_factory=CostWeights)
    warm_start: bool = True
    max_base_speed_m_s: float = 1.5
    max_yaw_rate_rad_s: float = 1.5
    max_ee_speed_m_s: float = 1.0
    recovery_barrier_init: float | None = 0.1  # a fresh Fatrop with this initial barrier re-solves a failed step
    fallback_solver: str | None = "ipopt"  # then re-solves a step still failed; None disables
    max_ee_force_n: float | None = None  # largest end-effector force command; None: the robot's weight
    # "position": the base x/y/yaw targets integrate the commanded velocity from where the run
    # started, so the cost's position rows pull drift back (an anchor). "velocity": the paper's
    # velocity-only tracking; the x/y/yaw targets restart from the measured base every step, so
    # only the base velocity rows act on the horizontal motion and drift is not corrected.
    base_tracking: str = "position"
    # leg joint posture targets follow the feet's motion at the commanded velocity (control/foot_placement.py:
    # touch-down at Raibert's neutral point v T_st / 2 ahead of the hip); False: the nominal pose at every node
    stance_posture_reference: bool = True

    # bounded recovery: iteration caps of the fresh Fatrop and of the fallback solver, an optional
    # wall-time budget for the whole recovery, and how long after a fallback rescue the fallback
    # solver is tried first (after a push the warm Fatrop keeps stalling for tens of steps)
    recovery_fatrop_max_iterations: int = 15
    fallback_max_iterations: int = 40
    # CPU seconds a step's solves may spend before no further recovery attempt starts (the step then
    # holds the last good plan); IPOPT also stops itself after this long (wall time). The Fatrop attempts
    # are capped by iterations, so a step ends within about this budget plus one attempt: at most 0.8 s
    # of CPU per step on b1_z1 after 0.6-1.0 m/s pushes (up to 1 s CPU, 3.6 s wall without it); None: no
    # budget. 0.5 s: the push map (8 directions x 0.6/0.8/1.0 m/s, kick at 0.8 s) lost 90 deg 0.6/0.8 and
    # 315 deg 0.8 with 0.25 s, which cut IPOPT's rescues short; 0.5 s behaves as no budget there
    # (90 deg 0.8: same 79 held steps, stays up), longest step 0.63 s wall
    recovery_time_limit_s: float | None = 0.5
    fallback_first_s: float = 0.25
    hold_previous_on_failure: bool = True  # a step still failed: the last good plan, shifted in time
    # push recovery mode: entered when the measured base velocity is off the last plan by more than
    # push_velocity_error_m_s (or, with OcpConfig.soft_rows, when a hard step fails), kept for push_hold_s
    # and for as long as the base velocity stays that far off the command. In it soft rows' slacks are free
    # and the rows push_relaxed_rows are dropped.
    # ("ee_vel",): the arm's velocity rows of eq. (7) pin the hand in the world while the base flies off,
    # the post-push OCPs turn infeasible or degenerate and Fatrop stalls (without them it converges in
    # 8-28 iterations); on b1_z1 that saves 270 deg 1.0 m/s pushes but makes the default 90 deg 0.8 m/s
    # push fall 2.5 s after the kick, so it is off by default
    push_velocity_error_m_s: float = 0.3
    push_hold_s: float = 0.5
    push_relaxed_rows: tuple[str, ...] = ()
    # step cadence after a push: in push recovery mode the gait's period is scaled by this factor (phases
    # continuous, `GaitClock.retime`) and returns to its own period push_cadence_hold_s after the mode ends.
    # Faster steps place more feet within the 0.56 s horizon. b1_z1's 0.8 s trot, 12 pushes that fell with
    # the fixed period (0.6-1.0 m/s, 7 directions, 2 gait phases; 4 s runs): 0.6 s kept 6 up, 0.5 s 10,
    # 0.45 s (this factor) all 12; push map at 0.8/1.0 m/s, 8 directions x 4 phases: 63 of 64 up, 41 of 64
    # on the fixed period. A factor, not a period, so a slower gait (walk, 1.2 s) is not sped up 2.7x.
    # None: the paper's fixed schedule
    push_gait_period_scale: float | None = 0.5625
    push_cadence_hold_s: float = 1.0
    # True: with no end-effector velocity command (Commands.ee_velocity_m_s None) the arm's velocity rows of
    # eq. (7) are dropped (the posture cost holds the arm) instead of carrying the hand with the base. A
    # humanoid's hand pinned in the world while its pelvis sways over the stance foot drives the arm into its
    # limits: g1's single-support OCPs then stall Fatrop (81 iterations; 17 with the rows dropped)
    free_ee_without_command: bool = False
    # True: the soft rows' slacks (OcpConfig.soft_rows) are free on every step, not only in push recovery
    # mode. Collision avoidance: an end-effector velocity command that leads into the body conflicts with
    # the collision rows; with soft arm rows the hand stops at the margin instead of the OCP turning infeasible
    soft_rows_always: bool = False
    # share of the way from the centre of the feet to the centre of each node's stance feet that the base xy
    # target moves (0: fixed targets, the paper's). Bipeds: their CoM must lean over the next stance foot
    # during double support (MPC._sway_towards_support)
    support_sway: float = 0.0
    support_lead_s: float = 0.0  # ... of the stance feet this much later (a biped: its double-support phase)
    # ... while the hands swing free (free_ee_without_command and no end-effector command); None: support_sway
    support_sway_free_hands: float | None = None
    # swing feet's horizontal velocities carried to a landing point (`foot_placement.SwingPlacement`: Raibert's
    # with capture-point feedback) instead of free; bipeds, whose light posture cost does not make them step
    swing_placement: bool = False
    # delay compensation (control/delay.py): `solve(..., delay_s=d)` plans from the state predicted for t + d
    # (the measurement rolled forward with the previous plan's accelerations) and returns a plan starting at
    # t + d; off: the plan starts at the measurement, d late
    delay_compensation: bool = False
    # the ground (issue 35, `wbmpc.terrain`): footholds, swing splines, cone normals and base targets follow it
    # (`control/terrain_references.py`); None or a flat one: the flat floor at 0. Per-step data only: the OCP
    # and its (compiled) solver are the same on any terrain
    terrain: Terrain | None = None
    footholds: FootholdConfig | None = None  # the keep-out band at edges (None: from the feet's size)
    # the whole step's budget (s, on the solver's clock) for solvers with a deadline (the anytime SQP): the
    # solver stops in time for the MPC's own work after it (measured); None: the solver's own setting
    step_budget_s: float | None = None
    # a failed step of a solver with a deadline (the anytime SQP with step_budget_s or budget_s) goes to the
    # recovery ladder above (soft rows, Fatrop, the fallback solver) only if True; False: it holds the last
    # good plan at once (after b1_z1's 0.8 m/s pushes the ladder took 50-150 ms, a real-time plan 4-12 periods old)
    recover_past_deadline: bool = False

    def __post_init__(self):
        check_number("gait_period_s", self.gait_period_s, low=0.0, high=10.0, low_open=True, unit="s", allow_none=True)
        check_number("friction_coefficient", self.friction_coefficient, low=0.0, high=5.0, low_open=True)
        for name in ("max_base_speed_m_s", "max_yaw_rate_rad_s", "max_ee_speed_m_s"):
            check_number(name, getattr(self, name), low=0.0, low_open=True)
        check_number("recovery_barrier_init", self.recovery_barrier_init, low=0.0, low_open=True, allow_none=True)
        check_number("max_ee_force_n", self.max_ee_force_n, low=0.0, low_open=True, unit="N", allow_none=True)
        if self.base_tracking not in BASE_TRACKING_MODES:
            raise ConfigError(f"base tracking must be one of {', '.join(BASE_TRACKING_MODES)} "
                              f"(--base-tracking), got {self.base_tracking!r}")
        for name in ("recovery_fatrop_max_iterations", "fallback_max_iterations"):
            check_number(name, getattr(self, name), low=1)
        check_number("recovery_time_limit_s", self.recovery_time_limit_s, low=0.0, low_open=True, unit="s", allow_none=True)
        check_number("fallback_first_s", self.fallback_first_s, low=0.0, unit="s")
        check_number("push_velocity_error_m_s", self.push_velocity_error_m_s, low=0.0, low_open=True, unit="m/s")
        check_number("push_hold_s", self.push_hold_s, low=0.0, unit="s")
        check_number("push_gait_period_scale", self.push_gait_period_scale, low=0.0, high=1.0, low_open=True,
                     allow_none=True)
        check_number("push_cadence_hold_s", self.push_cadence_hold_s, low=0.0, unit="s")
        check_number("step_budget_s", self.step_budget_s, low=0.0, low_open=True, high=10.0, unit="s", allow_none=True)
        bad = [tag for tag in self.push_relaxed_rows if tag not in ("ee_vel", "foot_vel")]
        if bad:
            raise ConfigError(f"push_relaxed_rows may hold ee_vel and foot_vel, got {bad}")


@dataclass
class Commands:
    """Tracking commands (section V-B): base velocity in the heading frame, arm velocity/force in world.

    `ee_velocity_m_s=None` (default) moves the end-effector with the commanded base velocity, so
    the arm is carried along when the robot walks; an array makes it a world-frame command (eq. 7).
    `ee_force_n` is the force the end-effector applies on the environment; the robot feels its
    opposite (the contact force F_arm of eq. 2).
    """

    base_velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_yaw_rate_rad_s: float = 0.0
    ee_velocity_m_s: np.ndarray | None = None
    ee_force_n: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_height_m: float | None = None
    # with an object model in the OCP (OcpConfig.object_model): the object's measured state and its path; the
    # arm force is then the OCP's (ee_force_n and ee_velocity_m_s are not used)
    object_command: ObjectCommand | None = None

    def __post_init__(self):
        """Refuse NaN/inf and wrong shapes here: a NaN command would give NaN torques."""
        for name in ("base_velocity_m_s", "ee_velocity_m_s", "ee_force_n"):
            value = getattr(self, name)
            if value is None and name == "ee_velocity_m_s":
                continue
            array = np.asarray(value, dtype=float)
            if array.shape != (3,) or not np.all(np.isfinite(array)):
                raise ConfigError.for_field(name, f"must be 3 finite numbers, got {value!r}")
            setattr(self, name, array)
        check_number("base_yaw_rate_rad_s", self.base_yaw_rate_rad_s, unit="rad/s")
        check_number("base_height_m", self.base_height_m, low=0.0, low_open=True, unit="m", allow_none=True)


class MPC:
    """Whole-body MPC on a robot: `solve(q, v, commands, t)` returns the optimal `Solution`."""

    def __init__(self, robot: RobotModel, config: MpcConfig = MpcConfig(), problem: OcpProblem | None = None,
                 solver: NlpSolver | None = None):
        self.robot = robot
        self.config = config
        if not config.friction_coefficient > 0:
            raise ConfigError(f"friction coefficient must be positive, got {config.friction_coefficient}")
        # the MPC's own clock: its period changes after pushes (push_gait_period_scale); estimators read it too.
        # Without a period (the runner's comes from control/tuning.py) the base height stands in for a biped's leg
        self.gait = GaitClock(make_gait(config.gait, len(robot.feet), config.gait_period_s,
                                        leg_length_m=float(robot.q_nominal[2])))
        self.problem = problem or OcpProblem(robot, config.ocp)
        self.solver = solver or make_solver(self.problem, config.solver)
        dyn, N = self.problem.dyn, self.problem.N
        q, dq = ca.SX.sym("q", robot.nq), ca.SX.sym("dq", robot.nv)
        # called on NumPy buffers every step (no DM conversions); outputs are reused: copy what is kept
        self._integrate = BufferedFunction(ca.Function("integrate", [q, dq], [dyn.integrate(q, dq)]).map(N + 1))
        q1 = ca.SX.sym("q1", robot.nq)
        self._difference = BufferedFunction(ca.Function("difference", [q, q1], [dyn.difference(q, q1)]).map(N + 1))
        self._weights = config.weights.vectors(robot, self.problem.nf)
        # the model's mass distribution (OcpConfig.inertial_parameters): NLP parameters, set between steps
        self._inertial = self._nominal_inertial()
        self._trajectories = BufferedFunction(self.problem.trajectory_function())
        self._data = robot.model.createData()
        self._foot_ids = [robot.frame_id(robot.contact_frame(foot)) for foot in robot.feet]  # soles of flat feet
        self._stance_reference = StanceReference(robot) if config.stance_posture_reference else None
        self._swing_placement = SwingPlacement(robot) if config.swing_placement else None
        self._terrain = (TerrainReferences(robot, config.terrain, config.swing, config.footholds)
                         if config.terrain is not None and not config.terrain.is_flat else None)
        self._flat_normals = np.tile([0.0, 0.0, 1.0], (N, len(robot.feet))).T.copy()  # (3 n_feet, N): world z
        self._ee_id = robot.frame_id(robot.arm_ee) if robot.arm_ee else None
        self._previous: Solution | None = None
        self._fallback: NlpSolver | None = None
        self._fallback_cold: NlpSolver | None = None
        self._recovery: NlpSolver | None = None
        self._fallback_until_t: float | None = None  # fallback solver first until this time
        self._push_until_t: float | None = None  # push recovery mode until this time
        self._fast_cadence_until_t: float | None = None  # the push cadence until this time
        self._xy_reference: np.ndarray | None = None
        self._yaw_reference: float | None = None
        self._last_t: float | None = None
        self._after_solve_s = 0.5e-3  # running mean of the step's time after the solver returns (unpacking)

    def _nominal_inertial(self) -> dict[str, np.ndarray]:
        names = [n for n in ("base_com_offset", "payload_kg", "base_payload_kg") if n in self.problem.params.names]
        return {name: np.zeros(self.problem.params.shape(name)[0]) for name in names}

    def set_inertial_parameters(self, base_com_offset_m, payload_kg: float, base_payload_kg: float = 0.0) -> None:
        """The base CoM offset (base frame, m), hand payload (kg; the base's without an arm) and, with an arm, a
        load at the base origin (kg) the next plans use (no rebuild); needs `OcpConfig.inertial_parameters`."""
        if not self._inertial:
            raise ConfigError("this MPC's OCP has no inertial parameters: build it with "
                              "OcpConfig(inertial_parameters=True) (wbmpc run --identify-mass)")
        offset = np.asarray(base_com_offset_m, dtype=float).reshape(3)
        if not (np.all(np.isfinite(offset)) and np.isfinite(payload_kg) and np.isfinite(base_payload_kg)):
            raise ConfigError(f"inertial parameters must be finite, got offset {offset} m, payload {payload_kg} kg "
                              f"and base payload {base_payload_kg} kg")
        if base_payload_kg and "base_payload_kg" not in self._inertial:
            raise ConfigError(f"{self.robot.name} has no arm: its payload_kg already sits at the base origin")
        self._inertial = {"base_com_offset": offset, "payload_kg": np.array([float(payload_kg)]),
                          **({"base_payload_kg": np.array([float(base_payload_kg)])} if "base_payload_kg" in self._inertial
                             else {})}

    def reset(self) -> None:
        """Forget the warm start and the position references (e.g. after a reset of the plant)."""
        self._previous = None
        self._xy_reference = None
        self._yaw_reference = None
        self._last_t = None
        self._fallback_until_t = None
        self._push_until_t = None
        self._fast_cadence_until_t = None
        self.gait.reset()
        if self._terrain is not None:
            self._terrain.reset()
        self._inertial = self._nominal_inertial()  # until an estimator sets it again

    def continue_from(self, solution: Solution) -> None:
        """Take `solution` as the last good plan, as after a successful step: the next step warm-starts
        from it and, if it fails, holds it shifted in time."""
        self._previous = solution

    def enter_push_recovery(self, until_t: float = np.inf) -> None:
        """Push recovery mode (soft rows, relaxed rows, the push cadence) until `until_t`, as the push
        detector sets it after a kick."""
        self._push_until_t = until_t

    # ------------------------------------------------------------------ input checks
    def _check(self, q: np.ndarray, v: np.ndarray, commands: Commands, t: float) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(q, dtype=float).ravel()
        v = np.asarray(v, dtype=float).ravel()
        if q.size != self.robot.nq:
            raise ConfigError(f"state q has {q.size} entries; {self.robot.name} needs nq = {self.robot.nq}")
        if v.size != self.robot.nv:
            raise ConfigError(f"state v has {v.size} entries; {self.robot.name} needs nv = {self.robot.nv}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.isfinite(t)):
            raise ConfigError("state or time contains NaN/inf; pass a finite measured state")
        norm = np.linalg.norm(q[3:7])
        if abs(norm - 1) > 1e-3:
            raise ConfigError(f"base quaternion q[3:7] must be unit (norm {norm:.4f}); normalise the estimate")
        q = q.copy()
        q[3:7] /= norm
        cfg = self.config
        speed = float(np.linalg.norm(commands.base_velocity_m_s[:2]))
        if speed > cfg.max_base_speed_m_s:
            raise ConfigError(f"base velocity command {speed:.2f} m/s exceeds max_base_speed_m_s = {cfg.max_base_speed_m_s}")
        if abs(commands.base_yaw_rate_rad_s) > cfg.max_yaw_rate_rad_s:
            raise ConfigError(f"yaw rate command exceeds max_yaw_rate_rad_s = {cfg.max_yaw_rate_rad_s}")
        if self.robot.arm_ee and commands.ee_velocity_m_s is not None and \
                np.linalg.norm(commands.ee_velocity_m_s) > cfg.max_ee_speed_m_s:
            raise ConfigError(f"end-effector velocity command exceeds max_ee_speed_m_s = {cfg.max_ee_speed_m_s}")
        for name in ("base_velocity_m_s", "ee_velocity_m_s", "ee_force_n"):
            if getattr(commands, name) is None:
                continue
            value = np.asarray(getattr(commands, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise ConfigError(f"command {name} must be 3 finite numbers, got {value}")
        if not np.isfinite(commands.base_yaw_rate_rad_s):
            raise ConfigError(f"command base_yaw_rate_rad_s must be finite, got {commands.base_yaw_rate_rad_s}")
        force = float(np.linalg.norm(commands.ee_force_n))
        limit = cfg.max_ee_force_n or self.robot.mass_kg * GRAVITY_M_S2
        if force > limit:
            raise ConfigError(f"end-effector force command {force:.4g} N exceeds {limit:.0f} N (the robot's weight unless "
                              "MpcConfig.max_ee_force_n says otherwise): the robot cannot apply it; lower the force")
        if commands.base_height_m is not None:
            nominal = self.robot.q_nominal[2]
            if not 0.4 * nominal <= commands.base_height_m <= 1.3 * nominal:
                raise ConfigError(f"base height command {commands.base_height_m:g} m is outside "
                                  f"{0.4 * nominal:.2f}-{1.3 * nominal:.2f} m (40-130 % of the nominal "
                                  f"{nominal:.2f} m of {self.robot.name})")
        return q, v

    # ------------------------------------------------------------------ per-step data
    def _targets(self, q: np.ndarray, rot: np.ndarray, commands: Commands, t: float, node_times: np.ndarray):
        """dq_des per node (nominal posture, base following the commanded velocity), v_des, and the
        commanded base velocity in world coordinates."""
        robot = self.robot
        yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
        dt_since = 0.0 if self._last_t is None else max(0.0, t - self._last_t)
        self._last_t = t
        velocity_only = self.config.base_tracking == "velocity"
        if self._xy_reference is None or velocity_only:
            self._xy_reference, self._yaw_reference = q[:2].copy(), yaw
        cos_y, sin_y = np.cos(self._yaw_reference), np.sin(self._yaw_reference)
        heading = np.array([[cos_y, -sin_y, 0], [sin_y, cos_y, 0], [0, 0, 1]])
        v_world = heading @ np.asarray(commands.base_velocity_m_s, dtype=float)
        if not velocity_only:
            self._xy_reference = self._xy_reference + v_world[:2] * dt_since
            self._yaw_reference = self._yaw_reference + commands.base_yaw_rate_rad_s * dt_since
        # keep the references within reach of the robot (no wind-up after a push)
        offset = self._xy_reference - q[:2]
        if np.linalg.norm(offset) > 0.3:
            self._xy_reference = q[:2] + 0.3 * offset / np.linalg.norm(offset)
        targets = np.tile(robot.q_nominal, (len(node_times), 1))
        if self._stance_reference is not None:
            targets[:, 7:] += self._stance_reference.joint_offsets(
                self.gait, t + node_times, np.asarray(commands.base_velocity_m_s, dtype=float),
                commands.base_yaw_rate_rad_s)
        targets[:, :2] = self._xy_reference + np.outer(node_times, v_world[:2])
        if commands.base_height_m is not None:
            targets[:, 2] = commands.base_height_m
        yaws = self._yaw_reference + commands.base_yaw_rate_rad_s * node_times
        targets[:, 3:7] = np.column_stack([np.zeros_like(yaws), np.zeros_like(yaws), np.sin(yaws / 2), np.cos(yaws / 2)])
        if self._terrain is not None:  # height over the terrain's support, its pitch (control/terrain_references.py)
            self._terrain.shape_base_targets(targets, yaws)
        dq_des = self._difference(np.tile(q, (len(node_times), 1)).T, targets.T, shaped=True)[0].copy()
        v_des = np.zeros(robot.nv)
        v_des[:3] = rot.T @ v_world
        v_des[3:6] = rot.T @ np.array([0.0, 0.0, commands.base_yaw_rate_rad_s])
        return dq_des, v_des, v_world

    def _sway_towards_support(self, q: np.ndarray, rot: np.ndarray, dq_des: np.ndarray, contact: np.ndarray,
                              sway: float) -> np.ndarray:
        """Base xy targets moved by `sway` x (centre of each node's stance feet - centre of all feet):
        a biped's pelvis leans over the foot it will stand on, so the plan shifts its weight in double
        support instead of lifting a foot with the CoM between the feet (measured foot positions)."""
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        feet = np.array([self._data.oMf[i].translation[:2] for i in self._foot_ids])
        stance = contact / np.maximum(contact.sum(axis=1, keepdims=True), 1)
        shift = sway * (stance @ feet - feet.mean(axis=0))  # (nodes, 2) world
        dq_des = dq_des.copy()  # (nv, nodes); its base position part is (nearly) in the base frame
        dq_des[:3] += rot.T[:, :2] @ shift.T
        return dq_des

    def _swing_velocities(self, q, v, rot, t, node_times, command_world) -> np.ndarray | None:
        """Swing feet's xy velocity references to their landing points (`SwingPlacement`), or None."""
        if self._swing_placement is None:
            return None
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        feet = np.array([self._data.oMf[i].translation for i in self._foot_ids])
        yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
        return self._swing_placement.velocities(self.gait, t, node_times, q, rot @ v[:3], command_world, yaw, feet)

    def _terrain_step(self, q, v, rot, t, node_times, command_world):
        """The terrain's swing references, footholds and cone normals of this step (`TerrainReferences.step`)."""
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        feet = np.array([self._data.oMf[i].translation for i in self._foot_ids])
        yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
        return self._terrain.step(self.gait, t, node_times, q, rot @ v[:3], command_world, yaw, feet)

    def _measured_frame_velocities(self, q: np.ndarray, v: np.ndarray) -> dict:
        """Measured world linear velocities of the feet (n_feet, 3) and of the end-effector (3,)."""
        model, data = self.robot.model, self._data
        pin.forwardKinematics(model, data, q, v)

        def velocity(frame_id):
            return pin.getFrameVelocity(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).linear

        out = {"foot_velocity_m_s": np.array([velocity(i) for i in self._foot_ids]),
               "ee_velocity_measured_m_s": velocity(self._ee_id) if self._ee_id is not None else None}
        if self.robot.soles:
            out["foot_angular_velocity_rad_s"] = np.array(
                [pin.getFrameVelocity(model, data, i, pin.LOCAL_WORLD_ALIGNED).angular for i in self._foot_ids])
        return out

    def _object_data(self, q: np.ndarray, t: float, node_times: np.ndarray, commands: Commands) -> tuple[dict, dict]:
        """With an object model: its reference and weights (NLP parameters) and its measured state and contact
        rows (bounds); empty without one."""
        model = self.problem.object
        if model is None:
            return {}, {}
        command = commands.object_command
        if command is None:
            raise ConfigError(f"this MPC plans with the {model.name} inside the OCP: each step's commands need its "
                              "measured state and path (Commands.object_command)")
        if command.state.size != model.n_states:
            raise ConfigError(f"the {model.name}'s state has {model.n_states} values ({', '.join(model.state_names)}), "
                              f"got {command.state.size}")
        reference = np.asarray(command.reference(t + node_times), dtype=float)
        if reference.shape != (len(node_times), model.n_states) or not np.all(np.isfinite(reference)):
            raise ConfigError(f"the {model.name}'s path must give {model.n_states} finite values per node time, got "
                              f"shape {reference.shape}")
        pin.framesForwardKinematics(self.robot.model, self._data, q)
        hand = self._data.oMf[self._ee_id].translation
        return ({"obj_ref": reference.T, "obj_w": model.weights()},
                {"object_state": command.state, "object_contact_measured": model.contact_values(command.state, hand)})

    def _force_guess(self, contact: np.ndarray, commands: Commands) -> np.ndarray:
        """(N, nf) weight shared over the stance feet, zero on swing feet, arm force = -command."""
        N, n_feet = self.problem.N, len(self.robot.feet)
        forces = np.zeros((N, self.problem.nf))
        on_robot = -np.asarray(commands.ee_force_n, dtype=float)
        mass = self.robot.mass_kg + sum(float(self._inertial[name][0]) for name in ("payload_kg", "base_payload_kg")
                                        if name in self._inertial)
        support = mass * GRAVITY_M_S2 - (on_robot[2] if self.robot.arm_ee else 0.0)
        stance = contact[:N]
        n_stance = np.maximum(stance.sum(axis=1, keepdims=True), 1)
        forces[:, 2 : 3 * n_feet : 3] = stance * support / n_stance
        if self.robot.arm_ee:
            forces[:, 3 * n_feet : 3 * n_feet + 3] = on_robot
        return forces

    def schedule(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Node times, contact flags and swing v_z references of the horizon starting at t."""
        node_times = self.problem.config.grid.node_times_s
        times = t + node_times
        contact = self.gait.contact(times)
        progress = self.gait.swing_phase(times)
        swing_vz = self.config.swing.vertical_velocity(progress, self.gait.swing_duration_s)
        return node_times, contact, swing_vz

    # ------------------------------------------------------------------ solve
    def solve(self, q: np.ndarray, v: np.ndarray, commands: Commands | None = None, t: float = 0.0,
              delay_s: float = 0.0, budget_s: float | None = None) -> Solution:
        """The plan from the state (q, v) measured at t. `delay_s`: when the plan will reach the robot, after t;
        with `MpcConfig.delay_compensation` the plan starts there (state rolled forward, `Solution.t_s` = t +
        delay_s). `budget_s`: this step's time budget (overrides `MpcConfig.step_budget_s`) for a solver
        with a deadline."""
        start = time.perf_counter()
        clock = getattr(self.solver, "clock", None)
        clock_start = clock() if clock is not None else None
        commands = commands or Commands()
        q, v = self._check(q, v, commands, t)
        check_number("delay_s", delay_s, low=0.0, high=1.0, unit="s")
        if self.config.delay_compensation and delay_s > 0:
            q, v = roll_forward(self.robot.model, q, v, self._previous, t, delay_s)
            t = t + delay_s
        problem = self.problem
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        dq_des, v_des, base_velocity_world = self._targets(q, rot, commands, t, problem.config.grid.node_times_s)
        after_push = self._after_push(v, rot, base_velocity_world, t)
        self._adapt_cadence(t)
        node_times, contact, swing_vz = self.schedule(t)
        sway = self.config.support_sway
        if self.config.support_sway_free_hands is not None and self._hands_free(commands):
            sway = self.config.support_sway_free_hands
        if sway:  # lean over the feet that will stand support_lead_s later
            dq_des = self._sway_towards_support(q, rot, dq_des, self.gait.contact(t + node_times + self.config.support_lead_s),
                                                sway)
        forces = self._force_guess(contact, commands)
        swing_vxy = self._swing_velocities(q, v, rot, t, node_times, base_velocity_world)
        contact_normal = self._flat_normals
        if self._terrain is not None:  # footholds, swing splines and cone normals from the terrain
            terrain = self._terrain_step(q, v, rot, t, node_times, base_velocity_world)
            swing_vz, swing_vxy, contact_normal = terrain.swing_vz_m_s, terrain.swing_vxy_m_s, terrain.contact_normal
        object_values, object_bounds = self._object_data(q, t, node_times, commands)
        values = {
            "q_ref": q,
            "rot_ref": rot,
            "dt": problem.config.grid.dt_s,
            "dq_des": dq_des,
            "v_des": v_des,
            "F_des": forces.T,
            "mu": [self.config.friction_coefficient],
            "contact_normal": contact_normal,
            **self._weights,
            **self._inertial,
            **object_values,
        }
        p = problem.params.pack(values)
        stage_bounds = StageBounds(
            v0=v, q_ref=q, contact=contact, swing_vz_m_s=swing_vz, swing_vxy_m_s=swing_vxy,
            ee_velocity_m_s=(base_velocity_world if commands.ee_velocity_m_s is None
                             else np.asarray(commands.ee_velocity_m_s, dtype=float)),
            ee_force_on_robot_n=-np.asarray(commands.ee_force_n, dtype=float),
            **self._measured_frame_velocities(q, v),
            soft=after_push or self.config.soft_rows_always, relaxed_rows=self._relaxed_rows(after_push, commands),
            collision_measured_m=problem.collision_rows_at(q) if problem.collision is not None else None,
            **object_bounds,
        )
        if problem.collision is not None and self._previous is None:  # the start: refuse a pose in collision
            problem.collision.check_clear(q)
        x0 = self._initial_guess(q, v, t, node_times, forces, object_bounds.get("object_state"))
        if not after_push:
            x0[problem.slack_index] = 0.0  # pinned: the hard OCP
        bounds = problem.bounds(stage_bounds)
        # with soft rows, a hard step that fails is re-solved with the slacks free first (it may be infeasible)
        soft_bounds = None if after_push or self.config.soft_rows_always or not problem.n_slack_variables else problem.bounds(
            replace(stage_bounds, soft=True, relaxed_rows=self.config.push_relaxed_rows))
        cfg = self.config
        result, solve_end = self._solve_step(p, bounds, soft_bounds, x0, t, budget_s, clock, clock_start)
        solution = self._unpack(result.x, p, q, t, node_times, contact, result.stats)
        if solution.success:
            self._previous = solution
        elif cfg.hold_previous_on_failure and self._previous is not None:
            solution = self._shifted_previous(t, node_times, contact, result.stats)
        if solve_end is not None:  # the MPC's work after a deadline-bound solve: the next deadline leaves room for it
            self._after_solve_s = 0.8 * self._after_solve_s + 0.2 * (clock() - solve_end)
        # parameters, bounds, warm start and unpacking around the solver (NumPy and CasADi calls)
        result.stats.split_ms["python"] = max(1e3 * (time.perf_counter() - start - result.stats.solve_time_s), 0.0)
        return solution

    def _solve_step(self, p, bounds, soft_bounds, x0, t: float, budget_s: float | None, clock, clock_start):
        """One step's solve: the push fallback solver first in the wake of a push, else the solver on this
        step's deadline, then the recovery ladder unless a deadline forbids it. Returns the result and the
        solver clock's time at the end of a deadline-bound solve (None otherwise)."""
        cfg = self.config
        solve_end = None
        if self._fallback_until_t is not None and t < self._fallback_until_t and cfg.fallback_solver:
            result = self._fallback_solver().solve(p, *bounds, x0)  # still in the wake of a push
            result.stats.status = f"{result.stats.status} (recovery: {cfg.fallback_solver} first after a push)"
            if not result.stats.success:
                result = self._recover(result, p, bounds, x0, t, fallback_tried=True, soft_bounds=soft_bounds)
        else:
            budget = budget_s if budget_s is not None else cfg.step_budget_s
            # the cold first step's deadline only checks that the budget fits a QP (its solve converges): it counts
            # from the solver's call, as that step's own work before it holds one-off costs and, on a wall clock,
            # any load spike (a real-time run on a loaded machine was refused at start with 0.3 ms left of 10)
            origin = clock_start if self._previous is not None or clock is None else clock()
            deadline = {} if clock is None or budget is None else \
                {"deadline": origin + budget - self._after_solve_s}
            result = self.solver.solve(p, *bounds, x0, warm_start=self._previous is not None and cfg.warm_start,
                                       **deadline)
            solve_end = clock() if deadline else None
            if not result.stats.success and deadline and self._previous is not None and not cfg.recover_past_deadline:
                # the recovery ladder (converged re-solves) takes 50-150 ms after a push: a step with a deadline
                # holds the last good plan instead and the next step, one period later, tries again
                result.stats.status = f"{result.stats.status}; no recovery re-solve past the step's deadline"
            elif not result.stats.success:
                result = self._recover(result, p, bounds, x0, t, soft_bounds=soft_bounds)
        return result, solve_end

    def _hands_free(self, commands: Commands) -> bool:
        """The end-effector's velocity rows are dropped this step (`free_ee_without_command`, no command)."""
        return bool(self.config.free_ee_without_command and self.robot.arm_ee and commands.ee_velocity_m_s is None)

    def _relaxed_rows(self, after_push: bool, commands: Commands) -> tuple[str, ...]:
        rows = self.config.push_relaxed_rows if after_push else ()
        if self._hands_free(commands):
            rows = tuple(dict.fromkeys((*rows, "ee_vel")))
        return rows

    def prepare_fallback(self) -> None:
        """Build the recovery solvers now (they are otherwise built at the first failed step, which then
        takes the build time: campaigns and real-time use want them before the clock runs)."""
        if self.config.fallback_solver:
            self._fallback_solver()
        if self.config.recovery_barrier_init and self.solver.config.name in FATROP_SOLVERS:
            self._recovery_fatrop()
        prepare_recovery = getattr(self.solver, "prepare_recovery", None)  # RTI: its Fatrop re-solve
        if prepare_recovery is not None:
            prepare_recovery()

    def _fallback_solver(self, cold: bool = False) -> NlpSolver:
        """The fallback solver (IPOPT's regularised factorisation), built on first need, compiled like the
        main one. `cold`: for a step with no plan to hold yet (the first of a run), whose recovery may take
        up to COLD_FALLBACK_ITERATIONS: nothing runs on the robot before it succeeds."""
        if (self._fallback_cold if cold else self._fallback) is None:
            cfg = self.config
            solver = NlpSolver(self.problem, SolverConfig(
                name=cfg.fallback_solver,
                max_iterations=max(cfg.fallback_max_iterations, COLD_FALLBACK_ITERATIONS) if cold else cfg.fallback_max_iterations,
                time_limit_s=None if cold else cfg.recovery_time_limit_s, compiled=self.solver.is_compiled,
                codegen=self.solver.config.codegen,
                # after a push a nearly converged plan (violation <= 1e-4) beats holding an old one
                extra_options={"ipopt": {"acceptable_iter": 2, "acceptable_tol": 1e-3,
                                         "acceptable_constr_viol_tol": 1e-4}} if cfg.fallback_solver == "ipopt" else {}))
            if cold:
                self._fallback_cold = solver
            else:
                self._fallback = solver
        return self._fallback_cold if cold else self._fallback

    def _recovery_fatrop(self) -> NlpSolver:
        """A Fatrop starting from a larger barrier, built once (it keeps one nlpsol per row-count pattern,
        so its options hold: no new solver per failure)."""
        if self._recovery is None:
            cfg = self.config
            self._recovery = self.solver.recreated(barrier_init=cfg.recovery_barrier_init,
                                                   max_iterations=cfg.recovery_fatrop_max_iterations,
                                                   warm_barrier_init=None)
        return self._recovery

    def _after_push(self, v: np.ndarray, rot: np.ndarray, commanded_world: np.ndarray, t: float) -> bool:
        """Whether this step is in push recovery mode: within `push_hold_s` of a step whose measured
        base velocity was more than `push_velocity_error_m_s` off the last plan (the push), kept while it
        stays that far off the command (the robot still moving away after it).

        Only the plan starts the mode: a light robot's trot strays from the command by more than the
        threshold on its own (a1, 15 nodes: 8 % of the steps, 0.38 m/s at most; off its plan by 0.04
        m/s at most), which kept it in the mode 70 % of the time."""
        cfg = self.config
        previous = self._previous
        active = self._push_until_t is not None and t < self._push_until_t
        pushed = (active or previous is None) and \
            np.linalg.norm(rot @ v[:3] - commanded_world) > cfg.push_velocity_error_m_s
        if previous is not None and not pushed:
            planned = _interp_rows(np.array([t]), previous.t_s + previous.node_times_s, previous.v[:, :3])[0]
            pushed = np.linalg.norm(v[:3] - planned) > cfg.push_velocity_error_m_s
        if pushed:
            self._push_until_t = t + cfg.push_hold_s
        return self._push_until_t is not None and t < self._push_until_t

    def _adapt_cadence(self, t: float) -> None:
        """Faster steps while in push recovery mode and push_cadence_hold_s after it, then the gait's own
        period again (both switches keep every foot's phase)."""
        cfg, gait = self.config, self.gait
        if cfg.push_gait_period_scale is None or gait.duty_factor >= 1:
            return
        if self._push_until_t is not None and t < self._push_until_t:
            self._fast_cadence_until_t = self._push_until_t + cfg.push_cadence_hold_s
            fast_period_s = cfg.push_gait_period_scale * gait.nominal_period_s
            if gait.period_s != fast_period_s:
                gait.retime(t, fast_period_s)
        elif self._fast_cadence_until_t is not None and t >= self._fast_cadence_until_t:
            gait.retime(t, gait.nominal_period_s)
            self._fast_cadence_until_t = None

    def _recover(self, failed, p, bounds, x0, t: float, fallback_tried: bool = False, soft_bounds=None):
        """Re-solve a failed step within a bounded effort: first, for a hard step with soft rows, the same
        solver with their slacks free (`soft_bounds`; a success enters push recovery mode), then a
        fresh Fatrop starting from a larger barrier parameter (capped at `recovery_fatrop_max_iterations`;
        it copes with some degenerate problems right after pushes where the warm-started small barrier
        stalls), then the fallback solver (capped at `fallback_max_iterations`). No attempt starts once
        the step's solves have spent `recovery_time_limit_s` of CPU time, unless there is no plan to hold
        yet. A rescue by the fallback makes it the first choice for `fallback_first_s`."""
        cfg = self.config
        result, attempts = failed, [failed.stats.status]
        spent_s, iterations = failed.stats.cpu_time_s, failed.stats.iterations
        wall_s = failed.stats.solve_time_s

        def budget_left() -> bool:  # a step with no plan to hold (the first of a run) has no budget
            return cfg.recovery_time_limit_s is None or self._previous is None or spent_s < cfg.recovery_time_limit_s

        if soft_bounds is not None and budget_left():
            bounds = soft_bounds
            result = (self._fallback_solver() if fallback_tried else self.solver).solve(p, *bounds, x0)
            spent_s, iterations = spent_s + result.stats.cpu_time_s, iterations + result.stats.iterations
            wall_s += result.stats.solve_time_s
            attempts.append(f"soft rows: {result.stats.status}")
            if result.stats.success:
                self._push_until_t = t + cfg.push_hold_s
        if not result.stats.success and cfg.recovery_barrier_init and self.solver.config.name in FATROP_SOLVERS and budget_left():
            result = self._recovery_fatrop().solve(p, *bounds, x0)
            spent_s, iterations = spent_s + result.stats.cpu_time_s, iterations + result.stats.iterations
            wall_s += result.stats.solve_time_s
            attempts.append(f"fatrop mu_init {cfg.recovery_barrier_init:g}: {result.stats.status}")
        if not result.stats.success and cfg.fallback_solver and not fallback_tried and budget_left():
            result = self._fallback_solver(cold=self._previous is None).solve(p, *bounds, x0)
            spent_s, iterations = spent_s + result.stats.cpu_time_s, iterations + result.stats.iterations
            wall_s += result.stats.solve_time_s
            attempts.append(f"{cfg.fallback_solver}: {result.stats.status}")
            if result.stats.success and cfg.fallback_first_s > 0:
                self._fallback_until_t = (self._last_t or 0.0) + cfg.fallback_first_s
        if len(attempts) > 1:
            result.stats.status = f"{attempts[-1]} (recovery after {'; '.join(attempts[:-1])})"
        result.stats.solve_time_s, result.stats.cpu_time_s, result.stats.iterations = wall_s, spent_s, iterations
        return result

    def _shifted_previous(self, t: float, node_times: np.ndarray, contact: np.ndarray, stats) -> Solution:
        """The last good plan re-sampled at the new node times (held beyond its horizon), returned as
        a failed step (`success` False, `held_previous` True): the loop keeps applying a plan that
        moves on in time instead of the stale one."""
        prev = self._previous
        old, new = prev.t_s + prev.node_times_s, t + node_times
        n_tau = prev.tau.shape[0]
        q = _interp_rows(new, old, prev.q)
        q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
        stats.status = f"{stats.status}; holding the last good plan shifted by {1e3 * (t - prev.t_s):.0f} ms"
        shifted = Solution(t_s=t, node_times_s=node_times.copy(), q=q, v=_interp_rows(new, old, prev.v),
                           a=_interp_rows(new[:-1], old[:-1], prev.a), forces=_interp_rows(new[:-1], old[:-1], prev.forces),
                           tau=_interp_rows(new[:n_tau], old[:n_tau], prev.tau), contact=contact, stats=stats,
                           success=False, x=None, q_joints=self._joint_trajectory(q), held_previous=True)
        return shifted

    def _initial_guess(self, q, v, t, node_times, forces, object_state=None) -> np.ndarray:
        """Cold: the measured state held over the horizon, weight-sharing forces. Warm: the previous
        solution's variables shifted to the new node times (any formulation), forces re-initialised (the arm's
        shifted, where an object model makes it a variable of the plan)."""
        problem, idx = self.problem, self.problem.idx
        x0 = problem.initial_state(q, v, object_state)
        guess = {}
        for name in problem.state_names:
            guess[name] = np.tile(x0[problem.state_offsets[name]], (len(idx[name]), 1))
        if problem.object is not None:
            guess["obj_u"] = np.tile(problem.object.input_guess(object_state), (len(idx["obj_u"]), 1))
        for name, value in (("v", v), ("vj", v[6:])):
            if name in idx and name not in problem.state_names:
                guess[name] = np.tile(value, (len(idx[name]), 1))
        previous = self._previous if self.config.warm_start else None
        if previous is not None:
            new_times, old_times = t + node_times, previous.t_s + previous.node_times_s
            parts = problem.unpack(previous.x)
            # the previous configurations re-expressed as increments on the new reference q
            parts["dq"] = self._difference(np.tile(q, (len(node_times), 1)).T, previous.q.T, shaped=True)[0].T.copy()
            for name, values in parts.items():
                if name != "F":
                    guess[name] = _interp_rows(new_times[: len(values)], old_times[: len(values)], values)
            for name in problem.state_names:  # node 0 is the measurement
                guess[name][0] = x0[problem.state_offsets[name]]
            if problem.object is not None:  # the arm force is the plan's: shifted like the motion
                arm = slice(3 * len(self.robot.feet), 3 * len(self.robot.feet) + 3)
                forces = forces.copy()
                forces[:, arm] = _interp_rows(new_times[:-1], old_times[:-1], previous.forces[:, arm])
        guess["F"] = forces
        return problem.pack(guess)

    def _joint_trajectory(self, q_traj: np.ndarray) -> np.ndarray:
        """Joint positions per node; continuous joints unwrapped along the horizon (no 2 pi jumps)."""
        positions = self.robot.joint_positions(q_traj)
        continuous = self.robot.continuous
        positions[:, continuous] = np.unwrap(positions[:, continuous], axis=0)
        return positions

    def _unpack(self, x: np.ndarray, p: np.ndarray, q: np.ndarray, t: float, node_times, contact, stats) -> Solution:
        dq, v, a, forces, tau = (m.T.copy() for m in self._trajectories(x, p, shaped=True))
        q_traj = self._integrate(np.tile(q, (len(node_times), 1)).T, dq.T, shaped=True)[0].T.copy()
        finite = np.all(np.isfinite(x)) and np.all(np.isfinite(tau))
        return Solution(
            t_s=t,
            node_times_s=node_times.copy(),
            q=q_traj,
            v=v,
            a=a,
            forces=forces,
            tau=tau,
            contact=contact,
            stats=stats,
            success=bool(stats.success and finite),
            x=np.asarray(x, dtype=float),
            q_joints=self._joint_trajectory(q_traj),
        )


def _interp_rows(new_times: np.ndarray, old_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of per-node rows at new times, held constant beyond the ends."""
    out = np.empty((len(new_times), values.shape[1]))
    pos = np.clip(np.searchsorted(old_times, new_times) - 1, 0, len(old_times) - 2) if len(old_times) > 1 else None
    if pos is None:
        out[:] = values[0]
        return out
    t0, t1 = old_times[pos], old_times[pos + 1]
    w = np.clip((new_times - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    out[:] = (1 - w) * values[pos] + w * values[pos + 1]
    return out
