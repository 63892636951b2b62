"""`wbmpc deploy`: the whole-body MPC driving a robot (or `wbmpc robot-sim`): legs over LowState/LowCmd
(Unitree SDK2, DDS), a Z1 arm over its own UDP interface (`wbmpc.hardware.z1_udp`).

Per LowState (500 Hz): checks (CRC, header, motor set), the latest Z1 state, the state estimator
(section V-B), then by phase: stand-up (joint PD from the measured pose to the nominal one), MPC (80 Hz
solves, interpolation eq. 9 sent as the motor law eq. 10: q_des, dq_des, kp, kd, tau_ff per joint), then
lie-down and damping. Every command passes `clamp_command` (joint and torque limits); the LowCmd and the
Z1 command of a tick go out together, the Z1 joints the model locks held by PD at their reference.

Start: a valid LowState within `first_state_timeout_s` (2 s), a Z1 state within the same time (before
any leg command), the MPC built, the robot's sport mode released (`wbmpc.hardware.motion_switcher`),
the Z1 switched to LOWCMD. Nothing is commanded when any of these fails (exit code 2); when LowStates
arrived but every one was rejected, the error counts them and names why (`wbmpc.hardware.link`).

Robot link (`robot_link`): "robot" (strict: a robot fills header, CRC, tick and motor temperatures) or
"sim" (Unitree's simulator, unitree_mujoco: those fields unset, time from the receive clock); the report
says what was accepted. Messages follow the model's family: unitree_go for quadrupeds, unitree_hg for G1
(its `mode_machine` echoed in every LowCmd, the motors of joints the model locks held at their reference).

Fail safe: a fall (estimated tilt or height) -> damping; Ctrl-C -> lie down, then damping (a second
Ctrl-C -> damping); a plan older than `max_plan_age_s` (stale), a lost LowState (`state_timeout_ms`) or
lost Z1 state (`arm_state_timeout_ms`), a first MPC solve failed `first_solve_attempts` times, or any
exception -> a last damping command to legs and arm, then an error (exit code 1). The sport mode found at
start is selected again on the way out. Rejected messages (either link) are counted and never used.

Timing: with `lockstep` every MPC step is solved before the LowCmd of that tick goes out (pair it
with `robot-sim --mode lockstep`); otherwise the MPC solves in its own process while this loop
keeps answering LowState at the robot's rate with the last good solution.
"""

from __future__ import annotations

import dataclasses
import signal
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

from wbmpc.control.interpolator import PdGains, interpolate
from wbmpc.control.mpc import MPC, Commands, MpcConfig
from wbmpc.errors import ConfigError, RunError, WbmpcError
from wbmpc.estimation.estimator import EstimatorConfig, StateEstimator
from wbmpc.gait import make_gait
from wbmpc.hardware.link import LowStateLink, check_link
from wbmpc.hardware.mapping import has_z1_arm, unitree_motor_map, z1_arm_map
from wbmpc.hardware.messages import (
    MessageError,
    MotorCommand,
    encode_low_cmd,
)
from wbmpc.hardware.network import check_interface
from wbmpc.hardware.robot_sim import LOW_CMD_TOPIC, LOW_STATE_TOPIC
from wbmpc.hardware.safety import (
    Posture,
    SafetyConfig,
    clamp_command,
    fallen,
    lying_joint_positions,
    posture_command,
)
from wbmpc.hardware.sdk import load_sdk
from wbmpc.hardware.z1_messages import (
    CONTROLLER_IP,
    CONTROLLER_PORT,
    DEFAULT_KD_UNITS,
    DEFAULT_KP_UNITS,
    KD_UNIT_NM_S_PER_RAD,
    KP_UNIT_NM_PER_RAD,
    N_Z1_JOINTS,
    SDK_PORT,
    ArmFsmState,
    Z1Command,
)
from wbmpc.robots import RobotModel

# a robot's motor drivers evaluate eq. (10) at kHz with the last LowCmd's references: the hold its gains must
# stand (`wbmpc.control.joint_loop`); at 1 ms no preset's tuned Kd is capped
ROBOT_MOTOR_LAW_PERIOD_S = 1e-3


class NoRobotStateError(ConfigError, RuntimeError):
    """No (valid) LowState arrived in time; nothing was commanded. A set-up problem (robot off, wrong
    interface or domain): exit code 2, like other bad input."""


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
    # the MPC phase's gains for the hold the link applies (`JointLoopGains`); None: `gains` as given
    joint_loop_gains: object | None = None
    identify_mass: bool = False  # base CoM offset and payload identified from the estimated state, fed to the MPC

    def __post_init__(self):
        check_link(self.robot_link)
        if self.robot_link == "sim" and self.lockstep:
            raise ConfigError("--lockstep needs a robot process that waits for each LowCmd (robot-sim --mode lockstep); "
                              "Unitree's simulator (--robot-link sim) runs in real time: drop --lockstep")
        if not self.duration_s > 0:
            raise ConfigError(f"--duration must be positive, got {self.duration_s}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"DDS domain id must be in 0..232, got {self.domain_id}")
        if self.arm not in ("auto", "z1", "none"):
            raise ConfigError(f"--arm must be z1 (the arm over the Z1's UDP interface) or none, got {self.arm!r}")
        if not (self.max_plan_age_s > 0 and self.arm_state_timeout_ms > 0 and self.first_solve_attempts >= 1):
            raise ConfigError("max_plan_age_s and arm_state_timeout_ms must be positive, first_solve_attempts >= 1")
        if self.estimator.use_contact_sensors:
            raise ConfigError("LowState's foot_force are raw, uncalibrated sensor counts: the estimator takes stance "
                              "from the gait on hardware (EstimatorConfig.use_contact_sensors=False)")


@dataclass
class DeployReport:
    phases: list = field(default_factory=list)  # (robot time s, phase name)
    states_received: int = 0
    states_rejected: dict = field(default_factory=dict)
    commands_sent: int = 0
    arm: dict | None = None  # the Z1 link's counters
    sport_mode: dict | None = None  # {"released": mode found, "restored": bool}
    mpc_solves: int = 0
    mpc_failures: int = 0
    first_solve_failures: int = 0
    solve_ms: list = field(default_factory=list)
    tick_ms: list = field(default_factory=list)  # controller work per LowState (excluding MPC solves)
    plan_age_ms: list = field(default_factory=list)
    arm_state_age_ms: list = field(default_factory=list)  # age of the Z1 state used, per tick
    ee_error_m: list = field(default_factory=list)  # |reference - end effector| from the estimated state, MPC phase
    fell: bool = False
    stopped_by: str = "done"
    error: str | None = None
    estimated_xy_m: list = field(default_factory=list)
    link: dict = field(default_factory=dict)  # robot link, time source, accepted unset fields, mode_machine
    joint_loop: dict | None = None  # the hold measured before the MPC phase and the gains it took
    inertial: dict | None = None  # --identify-mass: the estimate (`InertialEstimator.report`) and its history

    def summary(self) -> dict:
        tick = np.array(self.tick_ms)
        age = np.array(self.plan_age_ms)
        return {
            "phases": self.phases,
            "states_received": self.states_received,
            "states_rejected": dict(self.states_rejected),
            **self.link,
            "joint_loop": self.joint_loop,
            **(self.inertial or {}),
            "commands_sent": self.commands_sent,
            "arm": self.arm,
            "sport_mode": self.sport_mode,
            "mpc_solves": self.mpc_solves,
            "mpc_failures": self.mpc_failures,
            "first_solve_failures": self.first_solve_failures,
            "solve_ms_mean": float(np.mean(self.solve_ms)) if self.solve_ms else None,
            "controller_tick_ms_p50": float(np.percentile(tick, 50)) if tick.size else None,
            "controller_tick_ms_p99": float(np.percentile(tick, 99)) if tick.size else None,
            "plan_age_ms_p50": float(np.percentile(age, 50)) if age.size else None,
            "plan_age_ms_max": float(age.max()) if age.size else None,
            "ee_rmse_estimated_m": float(np.sqrt(np.mean(np.square(self.ee_error_m)))) if self.ee_error_m else None,
            "fell": self.fell,
            "stopped_by": self.stopped_by,
            "error": self.error,
            "mpc_phase_s": self._mpc_phase_s(),
            "estimated_drift_cm_s": self._estimated_drift(),
        }

    def _mpc_phase_s(self) -> float | None:
        times = [t for t, p in self.phases if p == "mpc"]
        later = [t for t, p in self.phases if times and t > times[0]]
        return (later[0] - times[0]) if times and later else None

    def _estimated_drift(self) -> float | None:
        """Base displacement over the MPC phase from the controller's own estimate, cm/s."""
        duration = self._mpc_phase_s()
        if not duration or len(self.estimated_xy_m) < 2:
            return None
        return float(100 * np.linalg.norm(np.subtract(self.estimated_xy_m[-1], self.estimated_xy_m[0])) / duration)


class Controller:
    """The deploy loop; `run(commands)` returns a `DeployReport` (raises NoRobotStateError, DeployFailure)."""

    def __init__(self, robot: RobotModel, mpc_config: MpcConfig, config: DeployConfig = DeployConfig(), mpc: MPC | None = None,
                 solver_process=None):
        """`solver_process(robot, mpc_config)`: the real-time solver process (request/ready/receive/close), by
        default the one `wbmpc run --delay realtime` solves with (`control/solver_process.py`: pinned to its
        own core, shared memory); lock-step solves in this process with `mpc` (built here when None)."""
        check_interface(config.network)
        self.report = DeployReport()
        if not config.lockstep and mpc_config.push_gait_period_scale is not None:
            # the estimator here reads the gait schedule; a solver process's clock, which speeds up after
            # a push, is out of its sight: the fixed schedule (lock-step shares the MPC's clock instead)
            mpc_config = replace(mpc_config, push_gait_period_scale=None)
        self.robot, self.mpc_config, self.config = robot, mpc_config, config
        self.motors = unitree_motor_map(robot)
        self.link = LowStateLink(self.motors, config.robot_link)
        self.report.link = self.link.summary()
        self._leg_index = np.array([robot.joint_names.index(n) for n in self.motors.joint_names], dtype=int)
        z1 = config.arm == "z1" or (config.arm == "auto" and has_z1_arm(robot))
        self.arm_map = z1_arm_map(robot) if z1 else None
        if self.arm_map is not None:
            self._arm_k = np.flatnonzero(self.arm_map.driven)  # Z1 joints the model drives
            self._arm_j = np.array(self.arm_map.model_index)[self._arm_k]  # their model joints
        covered = len(self._leg_index) + (len(self._arm_k) if self.arm_map is not None else 0)
        if covered != robot.n_joints:
            raise ConfigError(f"{robot.name}: {robot.n_joints - covered} model joints are on neither link (LowCmd "
                              f"{self.motors.describe()}; Z1 over UDP {'on' if self.arm_map else 'off'}); pass --arm z1 "
                              "for a Z1 arm")
        self.mpc = mpc  # lock-step: built once the robot answers (a missing robot is reported in 2 s, not after a build)
        self.gait = make_gait(mpc_config.gait, len(robot.feet), mpc_config.gait_period_s)
        self.estimator = StateEstimator(robot, make_gait("stand", len(robot.feet)), config.estimator)
        self.kp, self.kd = config.gains.vectors(~robot.leg_joint_mask)
        self._intervals: list[float] = []  # LowState intervals before the MPC phase (the link's command period)
        self._last_state_s: float | None = None
        self._reference_lead_s = 0.0  # eq. 9 sampled this far ahead: the middle of a command's hold
        self.identification = None
        if config.identify_mass:
            from wbmpc.estimation.inertial import ESTIMATED_STATE_CONFIG, InertialEstimator, InertialIdentification

            self.identification = InertialIdentification(InertialEstimator(robot, ESTIMATED_STATE_CONFIG),
                                                         from_estimate=True)
        self._cond = threading.Condition()
        self._latest = None
        self._fresh = False
        self._interrupts = 0
        self._publisher = None
        self._z1 = None
        self._solver_process = solver_process or _solver_process

    # ------------------------------------------------------------------ DDS side
    def _on_state(self, msg) -> None:
        received_s = time.monotonic()
        with self._cond:
            self._latest, self._fresh = (msg, received_s), True
            self._cond.notify_all()

    def _next_state(self, timeout_s: float):
        """(LowState, its receive time) or None."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._fresh, timeout=timeout_s):
                return None
            self._fresh = False
            return self._latest

    def _on_sigint(self, signum, frame) -> None:
        self._interrupts += 1

    # ------------------------------------------------------------------ commands out
    def _send(self, command: MotorCommand, echo_tick: int) -> None:
        """One tick's commands: the legs' LowCmd and the Z1's LOWCMD (locked Z1 joints held at their reference)."""
        i = self._leg_index
        legs = MotorCommand(command.q_rad[i], command.dq_rad_s[i], command.kp[i], command.kd[i], command.tau_nm[i])
        if self._z1 is not None:
            self._z1.send(self._arm_command(command))
        self._publisher.Write(encode_low_cmd(legs, self.motors, echo_tick=echo_tick, mode_machine=self.link.mode_machine or 0,
                                             held=self._held_command()))
        self.report.commands_sent += 1

    def _held_command(self, damping: bool = False) -> MotorCommand:
        """The motors of joints the model locks (G1's wrists): PD to their reference with the posture gains, or damping."""
        held, safety = self.motors.held, self.config.safety
        if damping:
            return MotorCommand.damping(len(held), safety.damping_kd)
        tau_max = np.array([h.tau_max_nm for h in held])
        zeros = np.zeros(len(held))
        return MotorCommand(np.array([h.q_rad for h in held]), zeros, safety.posture_kp_per_nm * tau_max,
                            safety.posture_kd_per_nm * tau_max, zeros.copy())

    def _arm_command(self, command: MotorCommand) -> Z1Command:
        arm_map = self.arm_map
        q = np.array(arm_map.locked_position_rad)
        dq, tau = np.zeros(N_Z1_JOINTS), np.zeros(N_Z1_JOINTS)
        kp = np.array(DEFAULT_KP_UNITS) * KP_UNIT_NM_PER_RAD
        kd = np.array(DEFAULT_KD_UNITS) * KD_UNIT_NM_S_PER_RAD
        k, j = self._arm_k, self._arm_j
        q[k], dq[k], tau[k], kp[k], kd[k] = (command.q_rad[j], command.dq_rad_s[j], command.tau_nm[j], command.kp[j],
                                             command.kd[j])
        return Z1Command(ArmFsmState.LOWCMD, q, dq, tau, kp, kd)

    def _damp(self, echo_tick: int = 0) -> None:
        """The last command: damping on legs and arm (errors while sending are swallowed: we are stopping)."""
        kd = self.config.safety.damping_kd
        try:
            if self._publisher is not None:
                legs = MotorCommand.damping(self.motors.n_motors, kd)
                self._publisher.Write(encode_low_cmd(legs, self.motors, echo_tick=echo_tick,
                                                     mode_machine=self.link.mode_machine or 0,
                                                     held=self._held_command(damping=True)))
                self.report.commands_sent += 1
        except Exception:  # noqa: BLE001
            pass
        try:
            if self._z1 is not None:
                self._z1.damp(kd)
        except Exception:  # noqa: BLE001
            pass

    # ------------------------------------------------------------------ loop
    def run(self, commands=None, progress=None, ee_reference=None) -> DeployReport:
        """`ee_reference(t)`: the end effector's target (world, MPC time) whose error is reported, if given."""
        from wbmpc.hardware.z1_udp import ArmNotAnsweringError, Z1Client

        sdk = load_sdk()
        cfg, robot, report = self.config, self.robot, self.report
        commands = commands or (lambda t, q, v: Commands())
        sdk.ChannelFactoryInitialize(cfg.domain_id, cfg.network)
        idl = sdk.idl(self.motors.family)
        subscriber = sdk.ChannelSubscriber(LOW_STATE_TOPIC, idl.LowState_)
        subscriber.Init(self._on_state, 0)
        publisher = sdk.ChannelPublisher(LOW_CMD_TOPIC, idl.LowCmd_)
        publisher.Init()
        previous_handler = None
        if threading.current_thread() is threading.main_thread():
            previous_handler = signal.signal(signal.SIGINT, self._on_sigint)
        worker = sport = None
        z1 = None
        try:
            if self.arm_map is not None:
                z1 = Z1Client(cfg.z1_ip, cfg.z1_ports[0], cfg.z1_ports[1], cfg.arm_state_timeout_ms)
            self._first_valid_state()
            if z1 is not None and z1.wait_state(cfg.first_state_timeout_s) is None:
                raise ArmNotAnsweringError(
                    f"the Z1 arm sent no valid state within {cfg.first_state_timeout_s:.1f} s (UDP {cfg.z1_ip}:"
                    f"{cfg.z1_ports[0]} -> port {cfg.z1_ports[1]} here; rejected {dict(z1.rejected)}): is z1_controller "
                    "(or `wbmpc robot-sim --arm z1`) running on this computer? Nothing was commanded.")
            if cfg.lockstep and self.mpc is None:
                self.mpc = MPC(robot, self.mpc_config)
            elif not cfg.lockstep:
                worker = self._solver_process(robot, self.mpc_config)
            if cfg.sport_release:  # after the build: the robot stays under its own controller until we command it
                from wbmpc.hardware.motion_switcher import SportModeRelease

                sport = SportModeRelease()
                report.sport_mode = {"released": sport.release(), "restored": None}
            if z1 is not None:
                # the arm holds its measured pose with the gains of the stand-up (locked joints: the Z1's defaults)
                hold = self._arm_command(posture_command(robot.q_nominal[7:], robot.q_nominal[7:], 1.0, 0.0, cfg.safety,
                                                         robot.tau_max))
                z1.enter_lowcmd(cfg.first_state_timeout_s, hold.kp, hold.kd)
            latest = self._next_state(cfg.first_state_timeout_s)  # the robot kept publishing during the build
            if latest is None:
                raise NoRobotStateError("the robot stopped publishing LowState while the MPC was built; nothing "
                                        "was commanded")
            self._publisher, self._z1 = publisher, z1  # from here on, every exit goes through damping
            self._loop(latest, commands, worker, progress, ee_reference)
        except BaseException as exc:
            if self._publisher is not None:
                self._damp()
                if report.stopped_by == "done":
                    report.stopped_by = "exception"
                report.error = report.error or f"{type(exc).__name__}: {exc}"
                if not isinstance(exc, (WbmpcError, KeyboardInterrupt)):
                    raise DeployFailure(f"the controller failed ({type(exc).__name__}: {exc}); legs and arm were sent "
                                        "damping") from exc
            raise
        finally:
            if self.identification is not None:
                self.report.inertial = self.identification.metrics()
            if previous_handler is not None:
                signal.signal(signal.SIGINT, previous_handler)
            if worker is not None:
                worker.close()
            if sport is not None and report.sport_mode is not None:
                report.sport_mode["restored"] = sport.restore()
            if z1 is not None:
                age = np.array(report.arm_state_age_ms)
                report.arm = {"states_received": z1.received, "states_rejected": dict(z1.rejected),
                              "commands_sent": z1.commands_sent,
                              "state_age_ms_p50": float(np.percentile(age, 50)) if age.size else None,
                              "state_age_ms_max": float(age.max()) if age.size else None}
                z1.close()
            subscriber.Close()
            publisher.Close()
            report.states_rejected = dict(self.link.rejected)
            report.link = self.link.summary()
        return report

    def _first_valid_state(self):
        cfg = self.config
        deadline = time.monotonic() + cfg.first_state_timeout_s
        while True:
            state = self._next_state(max(0.0, deadline - time.monotonic()))
            if state is None and self.link.received:
                raise NoRobotStateError(f"{self.link.all_rejected_message(LOW_STATE_TOPIC, cfg.first_state_timeout_s)}. "
                                        "Nothing was commanded.")
            if state is None:
                raise NoRobotStateError(
                    f"no LowState on '{LOW_STATE_TOPIC}' within {cfg.first_state_timeout_s:.1f} s (interface "
                    f"{cfg.network}, DDS domain {cfg.domain_id}): is the robot or `wbmpc robot-sim` running on that "
                    "interface and domain? Nothing was commanded.")
            try:
                self.link.reading(*state)
                return state
            except MessageError as exc:
                if "motor set" in exc.reasons:
                    raise NoRobotStateError(f"{exc}. Nothing was commanded.") from None

    def _reading(self, state):
        """(LowState, receive time) (+ the latest Z1 state) -> SensorReadings over the model's joints; MessageError
        if rejected."""
        legs = self.link.reading(*state)
        n = self.robot.n_joints
        q, dq = np.zeros(n), np.zeros(n)
        q[self._leg_index], dq[self._leg_index] = legs.joint_position_rad, legs.joint_velocity_rad_s
        if self.arm_map is not None:
            state = self._z1.latest() if self._z1 is not None else None
            if state is None:
                q[self._arm_j] = self.robot.q_nominal[7:][self._arm_j]
            else:
                q[self._arm_j], dq[self._arm_j] = state.q_rad[self._arm_k], state.dq_rad_s[self._arm_k]
        return dataclasses.replace(legs, joint_position_rad=q, joint_velocity_rad_s=dq)

    def _fail(self, reason: str, message: str, t: float) -> None:
        self.report.stopped_by, self.report.error = reason, message
        self.report.phases.append((round(t, 4), "damping"))
        self._damp()
        raise DeployFailure(message + "; legs and arm were sent damping")

    def _loop(self, state, commands, worker, progress, ee_reference=None) -> None:
        cfg, robot, report, safety = self.config, self.robot, self.report, self.config.safety
        phase, phase_t0 = None, 0.0
        pose_start = None
        mpc_t0 = None
        active = None
        next_mpc = 0.0
        lying = lying_joint_positions(robot)
        posture = Posture(robot, safety)
        mpc_period = 1.0 / 80.0
        busy = False
        delay_s, requested_at = 0.0, 0.0  # measured delay of the plans (delay compensation, MpcConfig)
        z1 = self._z1
        t_last = self.link.last_time_s or 0.0

        def enter(name, t, q_joints):
            nonlocal phase, phase_t0, pose_start
            phase, phase_t0, pose_start = name, t, q_joints.copy()
            report.phases.append((round(t, 4), name))

        def first_plan(solution, t, q_joints) -> None:
            nonlocal active
            if solution.success:
                active = solution
                return
            report.first_solve_failures += 1
            if report.first_solve_failures >= cfg.first_solve_attempts:
                report.stopped_by = "mpc-failed"
                report.error = (f"the first MPC solve failed {report.first_solve_failures} times "
                                f"({solution.stats.status}): the robot lies down")
                enter("lie-down" if cfg.lie_down else "damping", t, q_joints)

        while True:
            start = time.perf_counter()
            if z1 is not None:
                z1.poll()
                report.arm_state_age_ms.append(1e3 * z1.watchdog.age_s())
                if z1.watchdog.expired():
                    self._fail("arm-state-lost", f"no valid Z1 state for {report.arm_state_age_ms[-1]:.0f} ms (limit "
                               f"{cfg.arm_state_timeout_ms:.0f} ms; rejected {dict(z1.rejected)})", t_last)
            msg = state[0]
            try:
                reading = self._reading(state)
            except MessageError:
                reading = None
            if reading is not None:
                report.states_received += 1
                t = t_last = reading.time_s
                if phase in (None, "stand-up", "hold"):
                    self._note_interval(t)
                q, v = self.estimator.update(reading)
                if phase is None:
                    enter("stand-up", t, reading.joint_position_rad)
                standing = phase in ("hold", "mpc")  # low on purpose while standing up or lying down: tilt only
                if phase in ("stand-up", "hold", "mpc", "lie-down") and fallen(robot, q, safety, check_height=standing):
                    report.fell, report.stopped_by = True, "fall"
                    enter("damping", t, reading.joint_position_rad)
                if self._interrupts and phase in ("stand-up", "hold", "mpc"):
                    report.stopped_by = "ctrl-c"
                    enter("lie-down" if cfg.lie_down else "damping", t, reading.joint_position_rad)
                if self._interrupts > 1 and phase == "lie-down":
                    enter("damping", t, reading.joint_position_rad)
                elapsed = t - phase_t0
                solve_ms = 0.0
                if phase == "stand-up":
                    command = posture.command(pose_start, robot.q_nominal[7:], elapsed, safety.stand_up_s)
                    if elapsed >= safety.stand_up_s:
                        enter("hold", t, robot.q_nominal[7:])
                elif phase == "hold":
                    command = posture.command(pose_start, robot.q_nominal[7:], 1.0, 0.0)
                    ready = elapsed >= cfg.hold_s
                    if ready and active is None and worker is None:  # lock-step: the first plan while holding
                        tic = time.perf_counter()
                        solution = self.mpc.solve(q, v, commands(0.0, q, v), 0.0)
                        solve_ms = 1e3 * (time.perf_counter() - tic)
                        self._count_solve(solution, solve_ms)
                        first_plan(solution, t, reading.joint_position_rad)
                    if ready and worker is not None and not busy and active is None:
                        worker.request(q, v, commands(0.0, q, v), 0.0)  # first plan while still holding
                        requested_at = time.perf_counter()
                        busy = True
                    if worker is not None and busy and worker.ready():
                        solution = worker.receive()
                        busy = False
                        self._count_solve(solution, 1e3 * solution.wall_time_s)
                        first_plan(solution, t, reading.joint_position_rad)
                    if phase == "hold" and ready and active is not None:
                        self._start_joint_loop()
                        enter("mpc", t, reading.joint_position_rad)
                        mpc_t0, next_mpc = t, mpc_period
                        self.estimator.gait = self.mpc.gait if self.mpc is not None else self.gait
                        self.estimator.gait_t0_s = t
                if phase == "mpc":
                    t_mpc = t - mpc_t0
                    if worker is None and t_mpc >= next_mpc - 1e-9:
                        tic = time.perf_counter()
                        solution = self.mpc.solve(q, v, commands(t_mpc, q, v), t_mpc)
                        solve_ms = 1e3 * (time.perf_counter() - tic)
                        self._count_solve(solution, solve_ms)
                        if solution.success:
                            active = solution
                        while next_mpc <= t_mpc + 1e-9:
                            next_mpc += mpc_period
                    elif worker is not None:
                        if busy and worker.ready():
                            solution = worker.receive()
                            busy = False
                            self._count_solve(solution, 1e3 * solution.wall_time_s)
                            # the delay a plan meets (request to receipt), for the next request's compensation
                            delay_s = 0.8 * delay_s + 0.2 * (time.perf_counter() - requested_at)
                            if solution.success or solution.held_previous:
                                active = solution
                        if not busy and t_mpc >= next_mpc - 1e-9:
                            worker.request(q, v, commands(t_mpc, q, v), t_mpc, delay_s,
                                           inertial=self.identification.parameters() if self.identification else None)
                            requested_at = time.perf_counter()
                            busy = True
                            while next_mpc <= t_mpc + 1e-9:
                                next_mpc += mpc_period
                    age_s = t_mpc - active.t_s
                    report.plan_age_ms.append(1e3 * age_s)
                    if age_s > cfg.max_plan_age_s:
                        self._fail("stale-plan", f"the MPC plan in use is {1e3 * age_s:.0f} ms old (limit "
                                   f"{1e3 * cfg.max_plan_age_s:.0f} ms): the solver fell behind", t)
                    reference = interpolate(active, t_mpc + self._reference_lead_s)
                    command = MotorCommand(reference.q_des, reference.v_des, self.kp, self.kd, reference.tau_ff)
                    if self.identification is not None:
                        self.identification.on_estimate(t, q, v)
                    report.estimated_xy_m.append(q[:2].tolist())
                    if ee_reference is not None:
                        ee = robot.frame_trajectories(q[None, :], [robot.arm_ee])[robot.arm_ee][0]
                        report.ee_error_m.append(float(np.linalg.norm(ee_reference(t_mpc) - ee)))
                    if t_mpc >= cfg.duration_s:
                        enter("lie-down" if cfg.lie_down else "damping", t, reading.joint_position_rad)
                    if progress:
                        progress(min(t_mpc / cfg.duration_s, 1.0))
                if phase == "lie-down":
                    elapsed = t - phase_t0  # the phase may have started in this tick
                    command = posture.command(pose_start, lying, elapsed, safety.lie_down_s)
                    if elapsed >= safety.lie_down_s + 0.3:
                        enter("damping", t, reading.joint_position_rad)
                if phase == "damping":
                    self._damp(echo_tick=msg.tick)
                    if report.stopped_by == "mpc-failed":
                        raise DeployFailure(report.error + "; legs and arm were sent damping")
                    return
                command = clamp_command(robot, command, reading.joint_position_rad, reading.joint_velocity_rad_s, safety)
                if self.identification is not None and phase == "mpc":  # the torque the motors apply until the next
                    self.identification.on_torque(command.torque(reading.joint_position_rad, reading.joint_velocity_rad_s))
                self._send(command, echo_tick=msg.tick)
                report.tick_ms.append(1e3 * (time.perf_counter() - start) - solve_ms)
            state = self._next_state(safety.state_timeout_ms / 1e3)
            if state is None:
                self._fail("state-watchdog", f"no LowState for {safety.state_timeout_ms:.0f} ms", t_last)

    def _note_interval(self, t_s: float) -> None:
        """A LowState's robot time before the MPC phase (the sim link's: its receive clock): the intervals give
        the link's command period (one LowCmd answers each LowState)."""
        if self._last_state_s is not None and len(self._intervals) < 5000:
            self._intervals.append(t_s - self._last_state_s)
        self._last_state_s = t_s

    def _start_joint_loop(self) -> None:
        """At the MPC phase's start: the gains for the hold this link applies, eq. 9's lead, the identification's
        MPC (lock-step: this process's)."""
        intervals = np.array(self._intervals[1:]) if len(self._intervals) > 1 else np.array([2e-3])
        period = float(np.median(intervals))
        # the sim link evaluates eq. 10 once per command and holds it (unitree_mujoco): the longest usual interval;
        # a robot's motor drivers run it at kHz with the command held: their own period
        hold = float(np.percentile(intervals, 95)) if self.config.robot_link == "sim" else ROBOT_MOTOR_LAW_PERIOD_S
        if self.config.joint_loop_gains is not None:
            gains = self.config.joint_loop_gains(hold)
            self.kp, self.kd = gains.vectors(~self.robot.leg_joint_mask)
        self._reference_lead_s = 0.5 * period
        legs = self.robot.leg_joint_mask
        self.report.joint_loop = {"command_period_ms": 1e3 * period, "hold_ms": 1e3 * hold,
                                  "kd_leg": float(self.kd[legs][0]) if legs.any() else None,
                                  "kp_leg": float(self.kp[legs][0]) if legs.any() else None}
        if self.identification is not None and self.mpc is not None:
            self.identification.mpc = self.mpc

    def _count_solve(self, solution, solve_ms: float) -> None:
        self.report.mpc_solves += 1
        self.report.solve_ms.append(solve_ms)
        if not solution.success:
            self.report.mpc_failures += 1


def _solver_process(robot: RobotModel, mpc_config: MpcConfig):
    """The real-time run's solver process, on the cores this controller leaves it (`cpu_split`)."""
    from wbmpc.control.solver_process import SolverProcess, cpu_split

    return SolverProcess(robot.spec, mpc_config, cpu_split()[1] or None)
