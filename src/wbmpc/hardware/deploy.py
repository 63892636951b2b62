"""`wbmpc deploy`: the whole-body MPC driving a robot (or `wbmpc robot-sim`) over LowState/LowCmd.

Per LowState (500 Hz): checks (CRC, header, motor set), the state estimator (section V-B), then
by phase: stand-up (joint PD from the measured pose to the nominal one), MPC (80 Hz solves,
interpolation eq. 9 sent as the motor law eq. 10: q_des, dq_des, kp, kd, tau_ff per joint), then
lie-down and damping. Every command passes `clamp_command` (joint and torque limits).

Safety: no LowState within `first_state_timeout_s` (2 s) -> error, nothing commanded; no LowState
for `state_timeout_ms` -> stop commanding (the robot's own watchdog then damps it); a fall
(estimated tilt or height) -> damping; Ctrl-C -> lie down, then damping; a second Ctrl-C -> damping.

Timing: with `lockstep` every MPC step is solved before the LowCmd of that tick goes out (pair it
with `robot-sim --mode lockstep`); otherwise the MPC solves in its own process while this loop
keeps answering LowState at the robot's rate with the last good solution.
"""

from __future__ import annotations

import signal
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from wbmpc.control.interpolator import PdGains, interpolate
from wbmpc.control.mpc import MPC, Commands, MpcConfig
from wbmpc.errors import ConfigError, RunError
from wbmpc.estimation.estimator import EstimatorConfig, StateEstimator
from wbmpc.gait import make_gait
from wbmpc.hardware.mapping import unitree_motor_map
from wbmpc.hardware.messages import (
    MessageError,
    MotorCommand,
    decode_low_state,
    encode_low_cmd,
)
from wbmpc.hardware.network import check_interface
from wbmpc.hardware.robot_sim import LOW_CMD_TOPIC, LOW_STATE_TOPIC
from wbmpc.hardware.safety import (
    SafetyConfig,
    clamp_command,
    fallen,
    lying_joint_positions,
    posture_command,
)
from wbmpc.hardware.sdk import load_sdk
from wbmpc.robots import RobotModel


class NoRobotStateError(ConfigError, RuntimeError):
    """No (valid) LowState arrived in time; nothing was commanded or commanding stopped. A set-up problem
    (robot off, wrong interface or domain): exit code 2, like other bad input."""


@dataclass(frozen=True)
class DeployConfig:
    network: str = "lo"
    domain_id: int = 0
    duration_s: float = 10.0  # MPC phase, seconds of robot time
    lockstep: bool = False
    first_state_timeout_s: float = 2.0
    hold_s: float = 0.5  # standing still between stand-up and MPC
    lie_down: bool = True
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    gains: PdGains = field(default_factory=PdGains)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)

    def __post_init__(self):
        if not self.duration_s > 0:
            raise ConfigError(f"--duration must be positive, got {self.duration_s}")
        if not 0 <= self.domain_id <= 232:
            raise ConfigError(f"DDS domain id must be in 0..232, got {self.domain_id}")


@dataclass
class DeployReport:
    phases: list = field(default_factory=list)  # (robot time s, phase name)
    states_received: int = 0
    states_rejected: dict = field(default_factory=dict)
    commands_sent: int = 0
    mpc_solves: int = 0
    mpc_failures: int = 0
    solve_ms: list = field(default_factory=list)
    tick_ms: list = field(default_factory=list)  # controller work per LowState (excluding MPC solves)
    fell: bool = False
    stopped_by: str = "done"
    estimated_xy_m: list = field(default_factory=list)

    def summary(self) -> dict:
        tick = np.array(self.tick_ms)
        return {
            "phases": self.phases,
            "states_received": self.states_received,
            "states_rejected": dict(self.states_rejected),
            "commands_sent": self.commands_sent,
            "mpc_solves": self.mpc_solves,
            "mpc_failures": self.mpc_failures,
            "solve_ms_mean": float(np.mean(self.solve_ms)) if self.solve_ms else None,
            "controller_tick_ms_p50": float(np.percentile(tick, 50)) if tick.size else None,
            "controller_tick_ms_p99": float(np.percentile(tick, 99)) if tick.size else None,
            "fell": self.fell,
            "stopped_by": self.stopped_by,
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
    """The deploy loop; `run(commands)` returns a `DeployReport` (raises NoRobotStateError)."""

    def __init__(self, robot: RobotModel, mpc_config: MpcConfig, config: DeployConfig = DeployConfig(), mpc: MPC | None = None):
        check_interface(config.network)
        if not config.lockstep and mpc_config.push_gait_period_scale is not None:
            # the estimator here reads the gait schedule; a solver process's clock, which speeds up after
            # a push, is out of its sight: the fixed schedule (lock-step shares the MPC's clock instead)
            mpc_config = replace(mpc_config, push_gait_period_scale=None)
        self.robot, self.mpc_config, self.config = robot, mpc_config, config
        self.motors = unitree_motor_map(robot)
        self.mpc = mpc  # lock-step: built once the robot answers (a missing robot is reported in 2 s, not after a build)
        self.gait = make_gait(mpc_config.gait, len(robot.feet), mpc_config.gait_period_s)
        self.estimator = StateEstimator(robot, make_gait("stand", len(robot.feet)), config.estimator)
        self.kp, self.kd = config.gains.vectors(~robot.leg_joint_mask)
        self.report = DeployReport()
        self._rejected: Counter = Counter()
        self._cond = threading.Condition()
        self._latest = None
        self._fresh = False
        self._interrupts = 0

    # ------------------------------------------------------------------ DDS side
    def _on_state(self, msg) -> None:
        with self._cond:
            self._latest, self._fresh = msg, True
            self._cond.notify_all()

    def _next_state(self, timeout_s: float):
        with self._cond:
            if not self._cond.wait_for(lambda: self._fresh, timeout=timeout_s):
                return None
            self._fresh = False
            return self._latest

    def _on_sigint(self, signum, frame) -> None:
        self._interrupts += 1

    # ------------------------------------------------------------------ loop
    def run(self, commands=None, progress=None) -> DeployReport:
        sdk = load_sdk()
        cfg, robot, report = self.config, self.robot, self.report
        commands = commands or (lambda t, q, v: Commands())
        sdk.ChannelFactoryInitialize(cfg.domain_id, cfg.network)
        subscriber = sdk.ChannelSubscriber(LOW_STATE_TOPIC, sdk.LowState_)
        subscriber.Init(self._on_state, 0)
        publisher = sdk.ChannelPublisher(LOW_CMD_TOPIC, sdk.LowCmd_)
        publisher.Init()
        previous_handler = None
        if threading.current_thread() is threading.main_thread():
            previous_handler = signal.signal(signal.SIGINT, self._on_sigint)
        worker = None
        try:
            self._first_valid_state()
            if cfg.lockstep and self.mpc is None:
                self.mpc = MPC(robot, self.mpc_config)
            elif not cfg.lockstep:
                worker = _SolverProcess(robot, self.mpc_config)
            latest = self._next_state(cfg.first_state_timeout_s)  # the robot kept publishing during the build
            if latest is None:
                raise NoRobotStateError("the robot stopped publishing LowState while the MPC was built; nothing "
                                        "was commanded")
            self._loop(latest, publisher, commands, worker, progress)
        finally:
            if previous_handler is not None:
                signal.signal(signal.SIGINT, previous_handler)
            if worker is not None:
                worker.close()
            subscriber.Close()
            publisher.Close()
            report.states_rejected = dict(self._rejected)
        return report

    def _first_valid_state(self):
        cfg = self.config
        deadline = time.monotonic() + cfg.first_state_timeout_s
        while True:
            msg = self._next_state(max(0.0, deadline - time.monotonic()))
            if msg is None:
                raise NoRobotStateError(
                    f"no LowState on '{LOW_STATE_TOPIC}' within {cfg.first_state_timeout_s:.1f} s (interface "
                    f"{cfg.network}, DDS domain {cfg.domain_id}): is the robot or `wbmpc robot-sim` running on that "
                    "interface and domain? Nothing was commanded.")
            try:
                decode_low_state(msg, self.motors)
                return msg
            except MessageError as exc:
                if "motors" in str(exc):
                    raise NoRobotStateError(f"{exc}. Nothing was commanded.") from None
                self._rejected["crc" if "CRC" in str(exc) else "malformed"] += 1

    def _loop(self, msg, publisher, commands, worker, progress) -> None:
        cfg, robot, report, safety = self.config, self.robot, self.report, self.config.safety
        n = robot.n_joints
        phase, phase_t0 = None, 0.0
        pose_start = None
        mpc_t0 = None
        active = None
        next_mpc = 0.0
        lying = lying_joint_positions(robot)
        mpc_period = 1.0 / 80.0
        busy = False

        def enter(name, t, q_joints):
            nonlocal phase, phase_t0, pose_start
            phase, phase_t0, pose_start = name, t, q_joints.copy()
            report.phases.append((round(t, 4), name))

        while True:
            start = time.perf_counter()
            try:
                reading = decode_low_state(msg, self.motors)
            except MessageError as exc:
                self._rejected["crc" if "CRC" in str(exc) else "malformed"] += 1
                reading = None
            if reading is not None:
                report.states_received += 1
                t = reading.time_s
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
                    command = posture_command(pose_start, robot.q_nominal[7:], elapsed, safety.stand_up_s, safety, robot.tau_max)
                    if elapsed >= safety.stand_up_s:
                        enter("hold", t, robot.q_nominal[7:])
                elif phase == "hold":
                    command = posture_command(pose_start, robot.q_nominal[7:], 1.0, 0.0, safety, robot.tau_max)
                    ready = elapsed >= cfg.hold_s
                    if ready and worker is not None and not busy and active is None:
                        worker.request(q, v, commands(0.0, q, v), 0.0)  # first plan while still holding
                        busy = True
                    if worker is not None and busy and worker.poll():
                        solution = worker.receive()
                        busy = False
                        if solution.success:
                            active = solution
                    if ready and (worker is None or active is not None):
                        enter("mpc", t, reading.joint_position_rad)
                        mpc_t0, next_mpc = t, 0.0
                        self.estimator.gait = self.mpc.gait if self.mpc is not None else self.gait
                        self.estimator.gait_t0_s = t
                        if worker is not None:
                            next_mpc = mpc_period
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
                        if busy and worker.poll():
                            solution = worker.receive()
                            busy = False
                            self._count_solve(solution, 1e3 * solution.wall_time_s)
                            if solution.success:
                                active = solution
                        if not busy and t_mpc >= next_mpc - 1e-9:
                            worker.request(q, v, commands(t_mpc, q, v), t_mpc)
                            busy = True
                            while next_mpc <= t_mpc + 1e-9:
                                next_mpc += mpc_period
                    if active is None:  # the first plan failed: lie down from where the robot stands
                        report.stopped_by = "mpc-failed"
                        enter("lie-down", t, reading.joint_position_rad)
                        elapsed = 0.0
                    else:
                        reference = interpolate(active, t_mpc)
                        command = MotorCommand(reference.q_des, reference.v_des, self.kp, self.kd, reference.tau_ff)
                        report.estimated_xy_m.append(q[:2].tolist())
                    if phase == "mpc" and t_mpc >= cfg.duration_s:
                        enter("lie-down" if cfg.lie_down else "damping", t, reading.joint_position_rad)
                    if progress:
                        progress(min(t_mpc / cfg.duration_s, 1.0))
                if phase == "lie-down":
                    elapsed = t - phase_t0  # the phase may have started in this tick
                    command = posture_command(pose_start, lying, elapsed, safety.lie_down_s, safety, robot.tau_max)
                    if elapsed >= safety.lie_down_s + 0.3:
                        enter("damping", t, reading.joint_position_rad)
                if phase == "damping":
                    command = MotorCommand.damping(n, safety.damping_kd)
                else:
                    command = clamp_command(robot, command, reading.joint_position_rad, reading.joint_velocity_rad_s, safety)
                publisher.Write(encode_low_cmd(command, self.motors, echo_tick=msg.tick))
                report.commands_sent += 1
                report.tick_ms.append(1e3 * (time.perf_counter() - start) - solve_ms)
                if phase == "damping":
                    return
            msg = self._next_state(safety.state_timeout_ms / 1e3)
            if msg is None:
                report.stopped_by = "state-watchdog"
                raise NoRobotStateError(f"no LowState for {safety.state_timeout_ms:.0f} ms: stopped commanding "
                                        "(the robot's watchdog switches it to damping)")

    def _count_solve(self, solution, solve_ms: float) -> None:
        self.report.mpc_solves += 1
        self.report.solve_ms.append(solve_ms)
        if not solution.success:
            self.report.mpc_failures += 1


class _SolverProcess:
    """The MPC in its own process (the 500 Hz loop must not wait for a 50-100 ms solve)."""

    def __init__(self, robot: RobotModel, mpc_config: MpcConfig):
        import multiprocessing

        from wbmpc.control.loop import mpc_worker

        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._process = context.Process(target=mpc_worker, args=(robot.spec, mpc_config, child), daemon=True)
        self._process.start()
        if not self._conn.poll(600) or self._conn.recv() != "ready":
            raise RunError("the MPC solver process did not start (see its error above)")

    def request(self, q, v, command, t) -> None:
        self._conn.send((q, v, command, t))

    def poll(self) -> bool:
        return self._conn.poll()

    def receive(self):
        return self._conn.recv()

    def close(self) -> None:
        try:
            self._conn.send(None)
        except (BrokenPipeError, OSError):
            pass
        self._process.join(timeout=5)
        if self._process.is_alive():
            self._process.terminate()
