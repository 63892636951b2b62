"""`MpcConfig`: everything an `MPC` is built with, in typed groups.

The top level holds the problem (OCP, solver, gait, swing, friction, weights) and the step's timing
(delay compensation, step budget); the groups hold the command limits (`CommandLimits`), how the
per-step targets are formed (`ReferenceConfig`, control/references.py), what a failed step does
(`RecoveryConfig`, control/recovery.py) and push recovery mode (`PushConfig`, control/push.py).
`wbmpc.control.policy` fills all of it for a robot and a task; the defaults are the paper robot's.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from dataclasses import dataclass, field

from wbmpc.control.delay import MotorLaw
from wbmpc.control.weights import CostWeights
from wbmpc.errors import ConfigError, check_number
from wbmpc.gait import SwingProfile
from wbmpc.ocp.problem import OcpConfig
from wbmpc.solvers.nlp import SolverConfig
from wbmpc.terrain import FootholdConfig, Terrain

BASE_TRACKING_MODES = ("position", "velocity")
RELAXABLE_ROWS = ("ee_vel", "foot_vel")


@dataclass
class CommandLimits:
    """The largest commands `MPC.solve` accepts (larger ones are refused, not clipped)."""

    base_speed_m_s: float = 1.5
    yaw_rate_rad_s: float = 1.5
    ee_speed_m_s: float = 1.0
    ee_force_n: float | None = None  # None: the robot's weight

    def __post_init__(self):
        for name in ("base_speed_m_s", "yaw_rate_rad_s", "ee_speed_m_s"):
            check_number(f"limits.{name}", getattr(self, name), low=0.0, low_open=True)
        check_number("limits.ee_force_n", self.ee_force_n, low=0.0, low_open=True, unit="N", allow_none=True)


@dataclass
class ReferenceConfig:
    """How each step's targets are formed from the commands (control/references.py)."""

    # "position": the base x/y/yaw targets integrate the commanded velocity from where the run started, so the
    # cost's position rows pull drift back (an anchor). "velocity": the paper's velocity-only tracking; the x/y/yaw
    # targets restart from the measured base every step, so drift is not corrected.
    base_tracking: str = "position"
    # leg joint posture targets follow the feet's motion at the commanded velocity (control/foot_placement.py:
    # touch-down at Raibert's neutral point v T_st / 2 ahead of the hip); False: the nominal pose at every node
    stance_posture: bool = True
    # share of the way from the centre of the feet to the centre of each node's stance feet that the base xy
    # target moves (0: fixed targets, the paper's). Bipeds: their CoM must lean over the next stance foot
    support_sway: float = 0.0
    support_lead_s: float = 0.0  # ... of the stance feet this much later (a biped: its double-support phase)
    support_sway_free_ee: float | None = None  # ... while the hands swing free; None: support_sway
    # swing feet's horizontal velocities carried to a landing point (`foot_placement.SwingPlacement`: Raibert's
    # with capture-point feedback) instead of free; bipeds, whose light posture cost does not make them step
    swing_placement: bool = False
    # with no end-effector velocity command the arm's velocity rows of eq. (7) are dropped (the posture cost
    # holds the arm) instead of carrying the hand with the base: a humanoid's hand pinned in the world while
    # its pelvis sways over the stance foot drives the arm into its limits and stalls the solver
    free_ee_without_command: bool = False
    # the ground (issue 35, `wbmpc.terrain`): footholds, swing splines, cone normals and base targets follow it
    # (control/terrain_references.py); None or a flat one: the flat floor at 0. Per-step data only: the OCP and
    # its (compiled) solver are the same on any terrain
    terrain: Terrain | None = None
    footholds: FootholdConfig | None = None  # the keep-out band at edges (None: from the feet's size)
    # the contact schedule follows measured touch-down (control/touchdown.py): `MPC.solve(..., measured_contact=...)`
    # keeps an early foot down and a late one reaching; off by default (docs/design/reality-gap.md: measured no better)
    touchdown_events: bool = False

    def __post_init__(self):
        if self.base_tracking not in BASE_TRACKING_MODES:
            raise ConfigError(f"base tracking must be one of {', '.join(BASE_TRACKING_MODES)} "
                              f"(--base-tracking), got {self.base_tracking!r}")


@dataclass
class RecoveryConfig:
    """What a failed step does (control/recovery.py): re-solves of bounded effort, then the last good plan."""

    barrier_init: float | None = 0.1  # a fresh Fatrop from this initial barrier re-solves a failed step; None: not
    fatrop_max_iterations: int = 15  # ... capped at this many iterations
    fallback_solver: str | None = "ipopt"  # then re-solves a step still failed; None disables
    fallback_max_iterations: int = 40
    # CPU seconds a step's solves may spend before no further attempt starts (the step then holds the last good
    # plan); IPOPT also stops itself after this long (wall time). The Fatrop attempts are capped by iterations,
    # so a step ends within about this budget plus one attempt. None: no budget
    budget_s: float | None = 0.5
    # after a rescue by the fallback solver it is tried first for this long (after a push the warm Fatrop keeps
    # stalling for tens of steps)
    fallback_first_s: float = 0.25
    hold_previous: bool = True  # a step still failed: the last good plan, shifted in time
    # a failed step of a solver with a deadline (the anytime SQP) goes through the re-solves above only if True;
    # False: it holds the last good plan at once (a re-solve past the deadline would apply a plan periods old)
    past_deadline: bool = False

    def __post_init__(self):
        check_number("recovery.barrier_init", self.barrier_init, low=0.0, low_open=True, allow_none=True)
        for name in ("fatrop_max_iterations", "fallback_max_iterations"):
            check_number(f"recovery.{name}", getattr(self, name), low=1)
        check_number("recovery.budget_s", self.budget_s, low=0.0, low_open=True, unit="s", allow_none=True)
        check_number("recovery.fallback_first_s", self.fallback_first_s, low=0.0, unit="s")


@dataclass
class PushConfig:
    """Push recovery mode (control/push.py): entered when the measured base velocity is off the last plan by more
    than `velocity_error_m_s` (or when a hard step with soft rows fails), kept for `hold_s` and for as long as the
    base velocity stays that far off the command. In it the soft rows' slacks are free, `relaxed_rows` are dropped
    and the gait's period is scaled by `gait_period_scale` (until `cadence_hold_s` after the mode ends)."""

    velocity_error_m_s: float = 0.3
    hold_s: float = 0.5
    # ("ee_vel",): the arm's velocity rows of eq. (7) pin the hand in the world while the base flies off and make
    # the post-push problems infeasible or degenerate; dropping them saves some pushes and loses others
    relaxed_rows: tuple[str, ...] = ()
    # faster steps place more feet within the horizon after a push (b1_z1's 0.8 s trot steps every 0.45 s). A
    # factor, not a period, so a slower gait is not sped up as much. None: the paper's fixed schedule
    gait_period_scale: float | None = 0.5625
    cadence_hold_s: float = 1.0

    def __post_init__(self):
        check_number("push.velocity_error_m_s", self.velocity_error_m_s, low=0.0, low_open=True, unit="m/s")
        check_number("push.hold_s", self.hold_s, low=0.0, unit="s")
        check_number("push.gait_period_scale", self.gait_period_scale, low=0.0, high=1.0, low_open=True,
                     allow_none=True)
        check_number("push.cadence_hold_s", self.cadence_hold_s, low=0.0, unit="s")
        bad = [tag for tag in self.relaxed_rows if tag not in RELAXABLE_ROWS]
        if bad:
            raise ConfigError(f"push relaxed_rows may hold {' and '.join(RELAXABLE_ROWS)}, got {bad}")


@dataclass
class MpcConfig:
    """The MPC's settings (module docstring); `MpcConfig()` is the paper robot's trot."""

    ocp: OcpConfig = field(default_factory=OcpConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    gait: str = "trot"
    gait_period_s: float | None = None  # None: the gait's own
    swing: SwingProfile = field(default_factory=SwingProfile)
    friction_coefficient: float = 0.7
    weights: CostWeights = field(default_factory=CostWeights)
    warm_start: bool = True
    limits: CommandLimits = field(default_factory=CommandLimits)
    references: ReferenceConfig = field(default_factory=ReferenceConfig)
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    push: PushConfig = field(default_factory=PushConfig)
    # delay compensation (control/delay.py): `solve(..., delay_s=d)` plans from the state predicted for t + d
    # (the measurement carried forward by the motor law on the previous plan, feet in stance held) and returns a
    # plan starting at t + d; off: the plan starts at the measurement, d late
    # False: off; True: on, predicting with the robot's tuned motor law (gains at 500 Hz); a `MotorLaw`: on, with
    # that joint loop (`ClosedLoop` puts its own in)
    delay_compensation: bool | MotorLaw = False
    # the whole step's budget (s, on the solver's clock) for solvers with a deadline (the anytime SQP): the
    # solver stops in time for the MPC's own work after it (measured); None: the solver's own setting
    step_budget_s: float | None = None
    # the soft rows' slacks (OcpConfig.soft_rows) are free on every step, not only in push recovery mode.
    # Collision avoidance: an end-effector velocity command that leads into the body conflicts with the
    # collision rows; with soft arm rows the hand stops at the margin instead of the OCP turning infeasible
    soft_rows_always: bool = False

    def __post_init__(self):
        check_number("gait_period_s", self.gait_period_s, low=0.0, high=10.0, low_open=True, unit="s", allow_none=True)
        check_number("friction_coefficient", self.friction_coefficient, low=0.0, high=5.0, low_open=True)
        check_number("step_budget_s", self.step_budget_s, low=0.0, low_open=True, high=10.0, unit="s", allow_none=True)

    def __getattr__(self, name: str):
        """The flat names of before the groups (one release, deprecated): `config.push_hold_s` reads
        `config.push.hold_s`."""
        if name in LEGACY_FIELDS:
            group, key = LEGACY_FIELDS[name]
            _warn_legacy([name])
            return getattr(getattr(self, group), key)
        raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")

    def __setattr__(self, name: str, value) -> None:
        if name in LEGACY_FIELDS:
            group, key = LEGACY_FIELDS[name]
            _warn_legacy([name])
            setattr(getattr(self, group), key, value)
            return
        super().__setattr__(name, value)


# MpcConfig's flat field names before the groups -> (group, field): accepted one release, with a DeprecationWarning
LEGACY_FIELDS: dict[str, tuple[str, str]] = {
    "max_base_speed_m_s": ("limits", "base_speed_m_s"),
    "max_yaw_rate_rad_s": ("limits", "yaw_rate_rad_s"),
    "max_ee_speed_m_s": ("limits", "ee_speed_m_s"),
    "max_ee_force_n": ("limits", "ee_force_n"),
    "base_tracking": ("references", "base_tracking"),
    "stance_posture_reference": ("references", "stance_posture"),
    "support_sway": ("references", "support_sway"),
    "support_lead_s": ("references", "support_lead_s"),
    "support_sway_free_hands": ("references", "support_sway_free_ee"),
    "swing_placement": ("references", "swing_placement"),
    "free_ee_without_command": ("references", "free_ee_without_command"),
    "recovery_barrier_init": ("recovery", "barrier_init"),
    "recovery_fatrop_max_iterations": ("recovery", "fatrop_max_iterations"),
    "fallback_solver": ("recovery", "fallback_solver"),
    "fallback_max_iterations": ("recovery", "fallback_max_iterations"),
    "recovery_time_limit_s": ("recovery", "budget_s"),
    "fallback_first_s": ("recovery", "fallback_first_s"),
    "hold_previous_on_failure": ("recovery", "hold_previous"),
    "recover_past_deadline": ("recovery", "past_deadline"),
    "push_velocity_error_m_s": ("push", "velocity_error_m_s"),
    "push_hold_s": ("push", "hold_s"),
    "push_relaxed_rows": ("push", "relaxed_rows"),
    "push_gait_period_scale": ("push", "gait_period_scale"),
    "push_cadence_hold_s": ("push", "cadence_hold_s"),
}


def _warn_legacy(names) -> None:
    new = ", ".join(f"{name} -> {'.'.join(LEGACY_FIELDS[name])}" for name in names)
    warnings.warn(f"MpcConfig's flat settings are deprecated and go in the next release; use the groups: {new}",
                  DeprecationWarning, stacklevel=3)


def _accepting_legacy_fields(init):
    """MpcConfig(push_hold_s=...) as MpcConfig(push=PushConfig(hold_s=...)), with a DeprecationWarning."""

    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        legacy = {name: kwargs.pop(name) for name in list(kwargs) if name in LEGACY_FIELDS}
        init(self, *args, **kwargs)
        if legacy:
            _warn_legacy(legacy)
            groups: dict[str, dict] = {}
            for name, value in legacy.items():
                group, key = LEGACY_FIELDS[name]
                groups.setdefault(group, {})[key] = value
            for group, values in groups.items():  # replace() checks the group's ranges again
                object.__setattr__(self, group, dataclasses.replace(getattr(self, group), **values))

    return __init__


MpcConfig.__init__ = _accepting_legacy_fields(MpcConfig.__init__)
