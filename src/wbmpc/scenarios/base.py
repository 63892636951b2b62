"""What a scenario is (`Scenario`) and the user knobs every scenario reads (`ScenarioOptions`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import Event, RunLog
from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError, check_number
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
        """Ranges of every knob, checked before anything is built (the CLI names the flag of a field)."""
        if self.gait is not None and self.gait not in GAIT_NAMES:
            raise ConfigError.for_field("gait", f"must be one of {', '.join(GAIT_NAMES)}; got '{self.gait}'")
        ranges = {  # field: (low, high, low_open, unit)
            "speed_m_s": (-1.5, 1.5, False, "m/s"),
            "push_speed_m_s": (0.0, 5.0, False, "m/s"),
            "push_direction_deg": (-360.0, 360.0, False, "deg"),
            "push_time_s": (0.0, None, False, "s"),
            "arm_amplitude_m": (0.0, 0.5, False, "m"),
            "arm_period_s": (0.0, 60.0, True, "s"),
            "arm_feedback_gain_1_s": (0.0, 100.0, False, "1/s"),
            "load_kg": (0.0, 1000.0, True, "kg"),
            "load_friction_mu": (0.0, 5.0, False, ""),
            "cable_length_m": (0.0, 10.0, True, "m"),
            "pull_speed_m_s": (0.0, 1.5, False, "m/s"),  # the direction is backwards
            "force_n": (0.0, 1e4, True, "N"),
            "box_kg": (0.0, 1000.0, True, "kg"),
            "board_friction_mu": (0.0, 5.0, False, ""),
            "wipe_size_m": (0.0, 0.5, True, "m"),
            "wipe_period_s": (0.0, 60.0, True, "s"),
            "hand_force_n": (0.0, 1e3, False, "N"),
            "compliant_kp_arm": (0.0, 1e4, False, ""),
            "compliant_kd_arm": (0.0, 1e4, False, ""),
            "compliant_return_gain_1_s": (0.0, 100.0, False, "1/s"),
            "wipe_pad_stiffness_n_m": (0.0, 1e6, False, "N/m"),
            "wipe_integral_gain_1_s2": (0.0, 1e4, False, "1/s^2"),
        }
        for name, (low, high, low_open, unit) in ranges.items():
            check_number(name, getattr(self, name), low=low, high=high, low_open=low_open, unit=unit,
                         allow_none=name == "force_n")
        if self.board not in ("vertical", "horizontal"):
            raise ConfigError.for_field("board", f"must be vertical or horizontal, got {self.board!r}")
        if self.wipe_pattern not in ("circle", "eight"):
            raise ConfigError.for_field("wipe_pattern", f"must be circle or eight, got {self.wipe_pattern!r}")


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

    def failure(self, metrics: dict) -> str | None:
        """Why the run failed its task (`wbmpc run` then exits 1), or None: by default, a fall."""
        if metrics.get("fell"):
            return f"the robot fell at {metrics['fell_at_s']:.2f} s"
        return None

    def extra_plots(self, robot: RobotModel, log: RunLog, out_dir) -> list:
        return []
