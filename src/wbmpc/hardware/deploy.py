"""`wbmpc deploy`: the whole-body MPC driving a robot (or `wbmpc robot-sim`): legs over LowState/LowCmd
(Unitree SDK2, DDS), a Z1 arm over its own UDP interface (`wbmpc.hardware.z1_udp`).

Per LowState (500 Hz): checks (CRC, header, motor set), the latest Z1 state, the state estimator
(section V-B), then by phase: stand-up (joint PD from the measured pose to the nominal one), MPC (solves at
`DeployConfig.mpc_rate_hz`, 80 Hz by default, interpolation eq. 9 sent as the motor law eq. 10: q_des, dq_des, kp, kd, tau_ff per joint), then
lie-down and damping. Every command passes `clamp_command` (joint and torque limits); the LowCmd and the
Z1 command of a tick go out together, the Z1 joints the model locks held by PD at their reference.

Start: a valid LowState within `first_state_timeout_s` (2 s), a Z1 state within the same time (before
any leg command), the MPC built, the robot's sport mode released (`wbmpc.hardware.motion_switcher`),
the Z1 switched to LOWCMD. Nothing is commanded when any of these fails (exit code 1); when LowStates
arrived but every one was rejected, the error counts them and names why (`wbmpc.hardware.link`): the link or
the robot chosen is wrong (exit code 2).

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
from dataclasses import replace

import numpy as np

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.control.interpolator import interpolate
from wbmpc.errors import ConfigError, WbmpcError
from wbmpc.estimation.estimator import StateEstimator
from wbmpc.estimation.inertial import InertialIdentification
from wbmpc.gait import GaitClock, make_gait
from wbmpc.hardware.deploy_config import DeployConfig, DeployFailure, LinkMismatchError, NoRobotStateError
from wbmpc.hardware.deploy_plans import DeployPlans
from wbmpc.hardware.deploy_report import DeployReport
from wbmpc.hardware.deploy_scheduling import DeployScheduling
from wbmpc.hardware.deploy_tick import DeployPhase, DeployTick
from wbmpc.hardware.link import LowStateLink
from wbmpc.hardware.link_timing import LinkTiming
from wbmpc.hardware.mapping import has_z1_arm, unitree_motor_map, z1_arm_map
from wbmpc.hardware.messages import MessageError, MotorCommand, encode_low_cmd
from wbmpc.hardware.network import check_interface
from wbmpc.hardware.robot_sim import LOW_CMD_TOPIC, LOW_STATE_TOPIC
from wbmpc.hardware.safety import Posture, clamp_command, fallen, lying_joint_positions, posture_command
from wbmpc.hardware.sdk import load_sdk
from wbmpc.hardware.z1_messages import (
    DEFAULT_KD_UNITS,
    DEFAULT_KP_UNITS,
    KD_UNIT_NM_S_PER_RAD,
    KP_UNIT_NM_PER_RAD,
    N_Z1_JOINTS,
    ArmFsmState,
    Z1Command,
)
from wbmpc.robots import RobotModel


class Controller:
    """The deploy loop; `run(commands)` returns a `DeployReport` (raises NoRobotStateError, DeployFailure)."""

    def __init__(self, robot: RobotModel, mpc_config: MpcConfig, config: DeployConfig = DeployConfig(), mpc: MPC | None = None,
                 solver_process=None):
        """`solver_process(robot, mpc_config)`: the real-time solver process (request/ready/receive/close), by
        default the one `wbmpc run --delay-mode realtime` solves with, on the same CPU plan (`DeployScheduling`);
        lock-step solves in this process with `mpc` (built here when None)."""
        check_interface(config.network)
        self.report = DeployReport()
        if not config.lockstep and mpc_config.push.gait_period_scale is not None:
            # the estimator here reads the gait schedule; a solver process's clock, which speeds up after
            # a push, is out of its sight: the fixed schedule (lock-step shares the MPC's clock instead)
            mpc_config = replace(mpc_config, push=replace(mpc_config.push, gait_period_scale=None))
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
        # the estimator's gait in real time (the MPC's own in lock-step); stand <-> walk commands switch it too
        self.gait = GaitClock(make_gait(mpc_config.gait, len(robot.feet), mpc_config.gait_period_s,
                                        leg_length_m=float(robot.q_nominal[2])))
        self.tick_listeners: list = []  # callables(DeployTick) after each valid LowState (remote, live view)
        self.estimator = StateEstimator(robot, make_gait("stand", len(robot.feet)), config.estimator)
        self.kp, self.kd = config.gains.vectors(~robot.leg_joint_mask)
        self.timing = LinkTiming(config.robot_link)  # the link's command period and hold, before the MPC phase
        self._reference_lead_s = 0.0  # eq. 9 sampled this far ahead; it and the gains: the hold measured (`LinkTiming`)
        self.identification = InertialIdentification.from_estimated_state(robot) if config.identify_mass else None
        self._cond = threading.Condition()
        self._latest = None
        self._fresh = False
        self._interrupts = 0
        self._stop = None  # the operator's lie-down (`run(stop=...)`)
        self._publisher = None
        self._z1 = None
        self.scheduling = DeployScheduling(realtime=not config.lockstep)  # the loop's priority and core, the solver's
        self._solver_process = solver_process or self.scheduling.solver_process

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
    def run(self, commands=None, progress=None, ee_reference=None, stop=None) -> DeployReport:
        """`commands(t, q, v)`: the task's commands at MPC time t; `ee_reference(t)`: the end effector's target
        (world, MPC time) whose error is reported, if given; `stop()`: true when the operator asks to lie down
        (checked every tick while standing or in the MPC phase)."""
        sdk = load_sdk()
        cfg, report = self.config, self.report
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
        self._worker = self._sport = self._arm_link = None
        self._stop = stop
        try:
            self.scheduling.raise_loop()
            latest = self._start()
            self._publisher, self._z1 = publisher, self._arm_link  # from here on, every exit goes through damping
            self._loop(latest, commands, self._worker, progress, ee_reference)
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
            self.scheduling.restore()
            report.scheduling = self.scheduling.summary()
            if self.identification is not None:
                report.inertial = self.identification.metrics()
            if previous_handler is not None:
                signal.signal(signal.SIGINT, previous_handler)
            self._close()
            subscriber.Close()
            publisher.Close()
        return report

    def _start(self):
        """Before the first command: a valid LowState and Z1 state, the MPC built (or its solver process started),
        the sport mode released, the Z1 in LOWCMD holding its pose. Returns the LowState to answer first."""
        from wbmpc.hardware.z1_udp import ArmNotAnsweringError, Z1Client

        cfg, robot = self.config, self.robot
        if self.arm_map is not None:
            self._arm_link = Z1Client(cfg.z1_ip, cfg.z1_ports[0], cfg.z1_ports[1], cfg.arm_state_timeout_ms)
        z1 = self._arm_link
        self._first_valid_state()
        if z1 is not None and z1.wait_state(cfg.first_state_timeout_s) is None:
            raise ArmNotAnsweringError(
                f"the Z1 arm sent no valid state within {cfg.first_state_timeout_s:.1f} s (UDP {cfg.z1_ip}:"
                f"{cfg.z1_ports[0]} -> port {cfg.z1_ports[1]} here; rejected {dict(z1.rejected)}): is z1_controller "
                "(or `wbmpc robot-sim --arm z1`) running on this computer? Nothing was commanded.")
        if cfg.lockstep and self.mpc is None:
            self.mpc = MPC(robot, self.mpc_config)
        elif not cfg.lockstep:
            self._worker = self._solver_process(robot, self.mpc_config)
            self.scheduling.pin_loop()
        if self.identification is not None and cfg.lockstep:  # the estimate goes to this process's MPC
            self.identification.mpc = self.mpc
        if cfg.sport_release:  # after the build: the robot stays under its own controller until we command it
            from wbmpc.hardware.motion_switcher import SportModeRelease

            self._sport = SportModeRelease()
            self.report.sport_mode = {"released": self._sport.release(), "restored": None}
        if z1 is not None:
            # the arm holds its measured pose with the gains of the stand-up (locked joints: the Z1's defaults)
            hold = self._arm_command(posture_command(robot.q_nominal[7:], robot.q_nominal[7:], 1.0, 0.0, cfg.safety,
                                                     robot.tau_max))
            z1.enter_lowcmd(cfg.first_state_timeout_s, hold.kp, hold.kd)
        latest = self._next_state(cfg.first_state_timeout_s)  # the robot kept publishing during the build
        if latest is None:
            raise NoRobotStateError("the robot stopped publishing LowState while the MPC was built; nothing "
                                    "was commanded")
        return latest

    def _close(self) -> None:
        """After the run, whatever ended it: the solver process stopped, the sport mode restored, the arm link's
        counters reported."""
        report, z1 = self.report, self._arm_link
        if self._worker is not None:
            self._worker.close()
        if self._sport is not None and report.sport_mode is not None:
            report.sport_mode["restored"] = self._sport.restore()
        if z1 is not None:
            age = report.arm_state_age_ms.summary()
            report.arm = {"states_received": z1.received, "states_rejected": dict(z1.rejected),
                          "commands_sent": z1.commands_sent, "state_age_ms_p50": age["p50"],
                          "state_age_ms_max": age["max"]}
            z1.close()
        report.states_rejected = dict(self.link.rejected)
        report.link = self.link.summary()

    def _first_valid_state(self):
        cfg = self.config
        deadline = time.monotonic() + cfg.first_state_timeout_s
        while True:
            state = self._next_state(max(0.0, deadline - time.monotonic()))
            if state is None and self.link.received:
                raise LinkMismatchError(f"{self.link.all_rejected_message(LOW_STATE_TOPIC, cfg.first_state_timeout_s)}. "
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
        """Answer every LowState until the damping phase (or a fault): one `_tick` each."""
        self._phase = DeployPhase()
        self._plans = DeployPlans(self.mpc, worker, 1.0 / self.config.mpc_rate_hz, self.report,
                                  inertial=self.identification.parameters if self.identification is not None else None)
        self._t_last = self.link.last_time_s or 0.0
        self._posture = Posture(self.robot, self.config.safety)
        self._lying = lying_joint_positions(self.robot)
        while self._tick(state, commands, progress, ee_reference):
            state = self._next_state(self.config.safety.state_timeout_ms / 1e3)
            if state is None:
                self._fail("state-watchdog", f"no LowState for {self.config.safety.state_timeout_ms:.0f} ms",
                           self._t_last)

    def _tick(self, state, commands, progress, ee_reference) -> bool:
        """One LowState: checks, the estimate, the phase's command sent; False once damping was sent."""
        start = time.perf_counter()
        self._watch_arm()
        try:
            reading = self._reading(state)
        except MessageError:
            return True  # rejected (counted by the link): nothing answered
        report, phase = self.report, self._phase
        report.states_received += 1
        t = self._t_last = reading.time_s
        q, v = self.estimator.update(reading)
        for listener in self.tick_listeners:  # before the phase events: an operator's lie-down acts this tick
            listener(DeployTick(t, t - self._mpc_t0 if phase.name == "mpc" else None, state[0], q, v,
                                self._plans.active, phase.name))
        if phase.name in (None, "stand-up", "hold"):
            self.timing.note(t)
        self._phase_events(q, t, reading.joint_position_rad)
        solve_ms = 0.0
        if phase.name == "stand-up":
            command = self._stand_up(t, reading.joint_position_rad)
        elif phase.name == "hold":
            command, solve_ms = self._hold(q, v, commands, t, reading.joint_position_rad)
        if phase.name == "mpc":
            command, solve_ms = self._mpc_step(q, v, commands, t, reading.joint_position_rad, progress, ee_reference)
        if phase.name == "lie-down":
            command = self._lie_down(t, reading.joint_position_rad)
        if phase.name == "damping":
            self._damp(echo_tick=state[0].tick)
            if report.stopped_by == "mpc-failed":
                raise DeployFailure(report.error + "; legs and arm were sent damping")
            return False
        command = clamp_command(self.robot, command, reading.joint_position_rad, reading.joint_velocity_rad_s,
                                self.config.safety)
        if self.identification is not None and phase.name == "mpc":  # the torque the motors apply until the next
            self.identification.on_torque(command.torque(reading.joint_position_rad, reading.joint_velocity_rad_s))
        self._send(command, echo_tick=state[0].tick)
        report.tick_ms.add(1e3 * (time.perf_counter() - start) - solve_ms)
        return True

    def _watch_arm(self) -> None:
        """The Z1's watchdog: a silent arm stops the run (damping)."""
        z1 = self._z1
        if z1 is None:
            return
        z1.poll()
        age_ms = 1e3 * z1.watchdog.age_s()
        self.report.arm_state_age_ms.add(age_ms)
        if z1.watchdog.expired():
            self._fail("arm-state-lost", f"no valid Z1 state for {age_ms:.0f} ms (limit "
                       f"{self.config.arm_state_timeout_ms:.0f} ms; rejected {dict(z1.rejected)})", self._t_last)

    def _enter(self, name: str, t: float, q_joints) -> None:
        self._phase.name, self._phase.t0, self._phase.pose_start = name, t, np.array(q_joints, dtype=float).copy()
        self.report.phases.append((round(t, 4), name))

    def _phase_events(self, q, t: float, q_joints) -> None:
        """The start, a fall (damping), the operator's lie-down and Ctrl-C (lie down; a second one: damping) change
        the phase."""
        cfg, phase, report = self.config, self._phase, self.report
        if phase.name is None:
            self._enter("stand-up", t, q_joints)
        standing = phase.name in ("hold", "mpc")  # low on purpose while standing up or lying down: tilt only
        if phase.name in ("stand-up", "hold", "mpc", "lie-down") and fallen(self.robot, q, cfg.safety,
                                                                            check_height=standing):
            report.fell, report.stopped_by = True, "fall"
            self._enter("damping", t, q_joints)
        if self._stop is not None and phase.name in ("hold", "mpc") and self._stop():
            report.stopped_by = "operator"
            self._enter("lie-down" if cfg.lie_down else "damping", t, q_joints)
        if self._interrupts and phase.name in ("stand-up", "hold", "mpc"):
            report.stopped_by = "ctrl-c"
            self._enter("lie-down" if cfg.lie_down else "damping", t, q_joints)
        if self._interrupts > 1 and phase.name == "lie-down":
            self._enter("damping", t, q_joints)

    def _stand_up(self, t: float, q_joints) -> MotorCommand:
        phase, safety, nominal = self._phase, self.config.safety, self.robot.q_nominal[7:]
        elapsed = t - phase.t0
        command = self._posture.command(phase.pose_start, nominal, elapsed, safety.stand_up_s)
        if elapsed >= safety.stand_up_s:
            self._enter("hold", t, nominal)
        return command

    def _hold(self, q, v, commands, t: float, q_joints) -> tuple[MotorCommand, float]:
        """Hold the nominal pose; after `hold_s` ask for the first plan, and start the MPC phase once one came."""
        phase, plans = self._phase, self._plans
        command = self._posture.command(phase.pose_start, self.robot.q_nominal[7:], 1.0, 0.0)
        solve_ms = 0.0
        if t - phase.t0 >= self.config.hold_s and plans.active is None:
            solution, solve_ms = plans.first(q, v, commands)
            if solution is not None:
                self._first_plan(solution, t, q_joints)
        if phase.name == "hold" and t - phase.t0 >= self.config.hold_s and plans.active is not None:
            self.kp, self.kd, self._reference_lead_s, self.report.joint_loop = self.timing.for_mpc_phase(
                self.config.joint_loop_gains, self.kp, self.kd, self.robot.leg_joint_mask)
            self._enter("mpc", t, q_joints)
            self._mpc_t0 = t
            plans.start()
            self.estimator.gait = self.mpc.gait if self.mpc is not None else self.gait
            self.estimator.gait_t0_s = t
        return command, solve_ms

    def _first_plan(self, solution, t: float, q_joints) -> None:
        """The first plan, or the count of failed first solves: at `first_solve_attempts` the robot lies down."""
        cfg, report = self.config, self.report
        if solution.success:
            self._plans.active = solution
            return
        report.first_solve_failures += 1
        if report.first_solve_failures >= cfg.first_solve_attempts:
            report.stopped_by = "mpc-failed"
            report.error = (f"the first MPC solve failed {report.first_solve_failures} times "
                            f"({solution.stats.status}): the robot lies down")
            self._enter("lie-down" if cfg.lie_down else "damping", t, q_joints)

    def _mpc_step(self, q, v, commands, t: float, q_joints, progress, ee_reference) -> tuple[MotorCommand, float]:
        """The MPC phase's command: the plan in use interpolated (eq. 9) as the motor law (eq. 10); the plan no older
        than `max_plan_age_s`; after `duration_s` the robot lies down."""
        cfg, report, robot, plans = self.config, self.report, self.robot, self._plans
        t_mpc = t - self._mpc_t0
        solve_ms = plans.step(t_mpc, q, v, commands)
        age_s = t_mpc - plans.active.t_s
        report.plan_age_ms.add(1e3 * age_s)
        if age_s > cfg.max_plan_age_s:
            self._fail("stale-plan", f"the MPC plan in use is {1e3 * age_s:.0f} ms old (limit "
                       f"{1e3 * cfg.max_plan_age_s:.0f} ms): the solver fell behind", t)
        reference = interpolate(plans.active, t_mpc + self._reference_lead_s)
        command = MotorCommand(reference.q_des, reference.v_des, self.kp, self.kd, reference.tau_ff)
        if self.identification is not None:
            self.identification.on_estimate(t, q, v)
        report.record_position(q[:2])
        if ee_reference is not None:
            ee = robot.frame_trajectories(q[None, :], [robot.arm_ee])[robot.arm_ee][0]
            report.record_ee_error(float(np.linalg.norm(ee_reference(t_mpc) - ee)))
        if t_mpc >= cfg.duration_s:
            self._enter("lie-down" if cfg.lie_down else "damping", t, q_joints)
        if progress:
            progress(min(t_mpc / cfg.duration_s, 1.0))
        return command, solve_ms

    def _lie_down(self, t: float, q_joints) -> MotorCommand:
        phase, safety = self._phase, self.config.safety
        elapsed = t - phase.t0  # the phase may have started in this tick
        command = self._posture.command(phase.pose_start, self._lying, elapsed, safety.lie_down_s)
        if elapsed >= safety.lie_down_s + 0.3:
            self._enter("damping", t, q_joints)
        return command

