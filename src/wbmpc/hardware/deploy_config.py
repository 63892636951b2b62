"""What `wbmpc deploy` is configured with (`DeployConfig`) and how it fails (`NoRobotStateError`, `DeployFailure`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import MPC_RATE_HZ
from wbmpc.errors import ConfigError, RunError
from wbmpc.estimation.estimator import EstimatorConfig
from wbmpc.hardware.link import check_link
from wbmpc.hardware.safety import SafetyConfig
from wbmpc.hardware.z1_messages import CONTROLLER_IP, CONTROLLER_PORT, SDK_PORT


class NoRobotStateError(RunError):
    """No (valid) LowState arrived in time; nothing was commanded (robot off, wrong interface or domain)."""


class LinkMismatchError(ConfigError):
    """LowStates arrived but none passed the link's checks (a simulator heard on the strict robot link, another
    message family): the choice of link or robot is wrong, bad input (exit code 2); nothing was commanded."""


class DeployFailure(RunError):
    """The controller stopped on a fault after commanding (lost state, stale plan, failed MPC, exception):
    legs and arm were sent a last damping command. Exit code 1."""


@dataclass(frozen=True)
class DeployConfig:
    network: str = "lo"
    domain_id: int = 0
    duration_s: float = 10.0  # MPC phase, seconds of robot time
    lockstep: bool = False
    first_state_timeout_s: float = 2.0  # LowState and Z1 state
    hold_s: float = 0.5  # standing still between stand-up and MPC
    lie_down: bool = True
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    gains: PdGains = field(default_factory=PdGains)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    arm: str = "auto"  # "z1": the model's arm is a Z1 over UDP; "auto": z1 when the model has Z1 joints
    z1_ip: str = CONTROLLER_IP
    z1_ports: tuple[int, int] = (CONTROLLER_PORT, SDK_PORT)  # (z1_controller's, ours)
    arm_state_timeout_ms: float = 100.0
    sport_release: bool = True  # release the sport mode first (motion switcher), restore it at exit
    max_plan_age_s: float = 0.25  # an MPC plan solved from a state older than this -> damping
    first_solve_attempts: int = 3
    robot_link: str = "robot"  # robot (strict) | sim (Unitree's simulator: unset header, CRC, tick, temperatures)
    mpc_rate_hz: float = MPC_RATE_HZ  # MPC steps per second of robot time (the MPC config's step budget assumes it)
    # the MPC phase's gains for the hold the link applies: `joint_loop_gains(hold_s) -> PdGains` (the robot's tuning
    # capped for that hold, `RobotTuning.gains_at`); None: `gains` as given
    joint_loop_gains: Callable[[float], PdGains] | None = None
    identify_mass: bool = False  # base CoM offset and payload identified from the estimated state, fed to the MPC

    def __post_init__(self):
        check_link(self.robot_link)
        if self.robot_link == "sim" and self.lockstep:
            raise ConfigError("--lockstep needs a robot process that waits for each LowCmd (robot-sim --mode lockstep); "
                              "Unitree's simulator (--robot-link sim) runs in real time: drop --lockstep")
        if not self.duration_s > 0:
            raise ConfigError(f"--duration must be positive, got {self.duration_s}")
        if not self.mpc_rate_hz > 0:
            raise ConfigError(f"--mpc-rate must be positive, got {self.mpc_rate_hz}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"DDS domain id must be in 0..232, got {self.domain_id}")
        if self.arm not in ("auto", "z1", "none"):
            raise ConfigError(f"--arm must be z1 (the arm over the Z1's UDP interface) or none, got {self.arm!r}")
        if not (self.max_plan_age_s > 0 and self.arm_state_timeout_ms > 0 and self.first_solve_attempts >= 1):
            raise ConfigError("max_plan_age_s and arm_state_timeout_ms must be positive, first_solve_attempts >= 1")
        if self.estimator.use_contact_sensors:
            raise ConfigError("LowState's foot_force are raw, uncalibrated sensor counts: the estimator takes stance "
                              "from the gait on hardware (EstimatorConfig.use_contact_sensors=False)")
