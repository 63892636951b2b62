"""What a scenario is (`Scenario`) and the user knobs every scenario reads (`ScenarioOptions`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import Event, RunLog
from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError
from wbmpc.gait import GAIT_NAMES
from wbmpc.robots import RobotModel


@dataclass
class ScenarioOptions:
    """User-tunable knobs shared by the scenarios (CLI flags). None means the scenario's default."""

    speed_m_s: float = 0.2
    push_speed_m_s: float = 0.8
    push_direction_deg: float = 90.0  # 90 = to the robot's left (lateral)
    push_time_s: float = 2.0
    arm_amplitude_m: float = 0.15
    arm_period_s: float = 4.0
    arm_feedback_gain_1_s: float = 4.0
    gait: str | None = None  # overrides the scenario's gait
    # loco-manipulation (section VI-C)
    load_kg: float = 10.0  # pull: mass of the load on the floor
    load_friction_mu: float = 0.3  # pull: load-floor friction coefficient
    cable_length_m: float = 1.6
    pull_speed_m_s: float = 0.1  # pull: walking speed backwards (or arm retraction speed in stance)
    force_n: float | None = None  # end-effector force target magnitude (pull: from the load when None)
    box_kg: float = 5.0
    board: str = "vertical"  # wipe: vertical (whiteboard) | horizontal (table)
    board_friction_mu: float = 0.3
    wipe_pattern: str = "circle"  # circle | eight
    wipe_size_m: float = 0.1
    wipe_period_s: float = 4.0
    wipe_pad_stiffness_n_m: float = 2000.0  # wipe: sprung pad on the end-effector (0: the rigid sphere)
    wipe_integral_gain_1_s2: float = 30.0  # wipe: integral action on the in-plane path error (0: none)
    hand_force_n: float = 30.0  # compliant: peak force of the external hand
    compliant_kp_arm: float = 2.0
    compliant_kd_arm: float = 0.3
    compliant_return_gain_1_s: float = 0.5  # 0: the paper's pure zero end-effector velocity target

    def __post_init__(self):
        if self.gait is not None and self.gait not in GAIT_NAMES:
            raise ConfigError(f"unknown gait '{self.gait}'; available gaits: {', '.join(GAIT_NAMES)}")
        for name in ("load_kg", "box_kg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"--{name.replace('_kg', '-kg').replace('_', '-')} must be a positive mass in kg, got {value}")
        if self.force_n is not None and not (np.isfinite(self.force_n) and self.force_n > 0):
            raise ConfigError(f"--force-n is the magnitude of the end-effector force target and must be positive, got {self.force_n}")
        for name in ("load_friction_mu", "board_friction_mu", "wipe_pad_stiffness_n_m", "wipe_integral_gain_1_s2", "hand_force_n", "compliant_kp_arm", "compliant_kd_arm",
                     "compliant_return_gain_1_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be >= 0, got {value}")
        for name in ("cable_length_m", "wipe_size_m", "wipe_period_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be positive, got {value}")
        if self.pull_speed_m_s < 0:
            raise ConfigError(f"pull speed must be >= 0 m/s (the direction is backwards), got {self.pull_speed_m_s}")
        if self.board not in ("vertical", "horizontal"):
            raise ConfigError(f"--board must be vertical or horizontal, got {self.board!r}")
        if self.wipe_pattern not in ("circle", "eight"):
            raise ConfigError(f"--pattern must be circle or eight, got {self.wipe_pattern!r}")


@dataclass
class Scenario:
    """Commands, disturbances, scene objects, low-level gains and metrics of one named task."""

    name: str
    description: str
    gait: str
    default_duration_s: float
    needs_arm: bool = False
    options: ScenarioOptions = field(default_factory=ScenarioOptions)

    def __post_init__(self):
        if self.options.gait is not None:
            self.gait = self.options.gait

    def commands(self, robot: RobotModel):
        return lambda t, q, v: Commands()

    def events(self, robot: RobotModel) -> list[Event]:
        return []

    def ee_reference(self, robot: RobotModel):
        """Callable t -> EE position reference (world), or None."""
        return None

    ee_error_label = "|p - p_ref|"

    def ee_tracking_error(self, robot: RobotModel, t: np.ndarray, ee: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(error vectors (n, 3), mask of the samples counted) of measured end-effector positions `ee`
        at times `t`: what `ee_pos_rmse_m` and the end-effector plot's RMSE are computed from. By
        default the 3D distance to `ee_reference` over the whole run; None without a reference."""
        reference = self.ee_reference(robot)
        if reference is None:
            return None
        return ee - np.array([np.asarray(reference(float(tk)), dtype=float) for tk in t]), np.ones(len(t), dtype=bool)

    def scene(self, robot: RobotModel):
        """`wbmpc.sim.objects.Scene` with the objects of the task, or None (robot on a flat floor)."""
        return None

    def pd_gains(self, gains: PdGains) -> PdGains:
        """Joint PD gains of eq. (10) for this task, given the configured ones."""
        return gains

    def check(self, robot: RobotModel) -> None:
        """Raise `ConfigError` (or warn) before a run when the options cannot work on `robot`."""

    def extra_metrics(self, robot: RobotModel, log: RunLog) -> dict:
        return {}

    def extra_plots(self, robot: RobotModel, log: RunLog, out_dir) -> list:
        return []
