"""The deployment pipeline (section V-B): MPC at 80 Hz, interpolation and joint PD at 500 Hz.

Delay modes: `none` (the simulation waits for the solver, section VI-B1), `measured` (the
solver's wall time elapses in simulation before its solution applies, VI-B2), a fixed delay in
milliseconds, and `realtime` (the MPC runs in its own process while the simulation advances at
wall-clock speed). Until a newer solution is ready the
last good one keeps being interpolated; failed solves are counted and never applied.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import pinocchio as pin

from wbmpc.control.interpolator import PdGains, interpolate, pd_torque
from wbmpc.control.mpc import MPC, Commands
from wbmpc.control.solution import Solution
from wbmpc.errors import ConfigError

DELAY_MODES = ("none", "measured", "realtime")


@dataclass(frozen=True)
class LoopConfig:
    mpc_rate_hz: float = 80.0
    control_rate_hz: float = 500.0
    delay: str = "none"  # "none" | "measured" | "realtime" | a number of milliseconds
    gains: PdGains = field(default_factory=PdGains)
    joint_position_noise_rad: float = 0.0
    joint_velocity_noise_rad_s: float = 0.0
    velocity_filter_hz: float | None = None  # first-order low-pass on joint velocities (paper: 50 Hz)
    fall_height_ratio: float = 0.5  # fell when the base drops below this share of its nominal height
    seed: int = 0

    def __post_init__(self):
        if not (self.mpc_rate_hz > 0 and self.control_rate_hz > 0):
            raise ConfigError("MPC and control rates must be positive")
        self.fixed_delay_s  # validates the delay

    @property
    def fixed_delay_s(self) -> float | None:
        if self.delay in DELAY_MODES:
            return None
        try:
            value = float(self.delay)
        except (TypeError, ValueError):
            raise ConfigError(f"unknown delay '{self.delay}'; use none, measured, realtime or a number of ms") from None
        if not value >= 0:
            raise ConfigError(f"a fixed delay must be >= 0 ms, got {value}")
        return value / 1e3


class CommandSource(Protocol):
    """Commands at time t given the measured state (feedback commands such as arm tracking need it)."""

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray) -> Commands: ...


@dataclass
class Event:
    """Something done to the plant at a time, e.g. a push: `action(plant)`."""

    time_s: float
    action: Callable
    done: bool = False


@dataclass
class RunLog:
    """What happened: per control tick (500 Hz) and per MPC step (80 Hz)."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    v: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    tau_ff: list = field(default_factory=list)
    q_des: list = field(default_factory=list)
    contact_forces: list = field(default_factory=list)
    mpc_t: list = field(default_factory=list)
    solve_ms: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    success: list = field(default_factory=list)
    status: list = field(default_factory=list)
    delay_ms: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    planned_contact: list = field(default_factory=list)
    late_solutions: int = 0
    fell: bool = False
    fell_at_s: float | None = None
    wall_time_s: float = 0.0

    def arrays(self) -> dict[str, np.ndarray]:
        out = {}
        for name in ("t", "q", "v", "tau", "tau_ff", "q_des", "contact_forces", "mpc_t", "solve_ms",
                     "iterations", "success", "delay_ms", "planned_contact"):
            out[name] = np.array(getattr(self, name))
        return out

    @property
    def mpc_failures(self) -> int:
        return int(len(self.success) - np.sum(self.success))


class ClosedLoop:
    """Runs an `MPC` against a plant (`wbmpc.sim`) with the paper's interpolation, PD and delays."""

    def __init__(self, mpc: MPC, plant, config: LoopConfig = LoopConfig()):
        self.mpc = mpc
        self.robot = mpc.robot
        self.plant = plant
        self.config = config
        self.kp, self.kd = config.gains.vectors(~self.robot.leg_joint_mask)
        self._rng = np.random.default_rng(config.seed)
        self._filtered_v: np.ndarray | None = None

    # ------------------------------------------------------------------ measurement
    def _measure(self) -> tuple[np.ndarray, np.ndarray]:
        """State estimate: plant state plus optional joint noise and the low-pass on joint velocities."""
        q, v = self.plant.state()
        cfg = self.config
        if cfg.joint_position_noise_rad:
            q = q.copy()
            q[7:] += self._rng.normal(0, cfg.joint_position_noise_rad, q.size - 7)
        if cfg.joint_velocity_noise_rad_s:
            v = v.copy()
            v[6:] += self._rng.normal(0, cfg.joint_velocity_noise_rad_s, v.size - 6)
        if cfg.velocity_filter_hz:
            dt = 1.0 / cfg.control_rate_hz
            alpha = dt / (dt + 1.0 / (2 * np.pi * cfg.velocity_filter_hz))
            if self._filtered_v is None:
                self._filtered_v = v.copy()
            self._filtered_v[6:] += alpha * (v[6:] - self._filtered_v[6:])
            v = v.copy()
            v[6:] = self._filtered_v[6:]
        return q, v

    def _fallen(self, q: np.ndarray) -> bool:
        height_ok = q[2] > self.config.fall_height_ratio * self.robot.q_nominal[2]
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        upright = rot[2, 2] > 0.5  # tilted less than 60 degrees
        return not (height_ok and upright)

    # ------------------------------------------------------------------ run
    def run(self, duration_s: float, commands: CommandSource | None = None,
            events: list[Event] | None = None, progress: Callable[[float], None] | None = None) -> RunLog:
        if not duration_s > 0:
            raise ConfigError(f"duration must be positive, got {duration_s}")
        commands = commands or (lambda t, q, v: Commands())
        events = sorted(events or [], key=lambda e: e.time_s)
        if self.config.delay == "realtime":
            return self._run_realtime(duration_s, commands, events, progress)
        return self._run_simulated_time(duration_s, commands, events, progress)

    def _solve(self, log: RunLog, t: float, commands: CommandSource) -> Solution:
        q, v = self._measure()
        command = commands(t, q, v)
        start = time.perf_counter()
        solution = self.mpc.solve(q, v, command, t)
        solution.wall_time_s = time.perf_counter() - start  # type: ignore[attr-defined]
        self._log_solution(log, t, command, solution)
        return solution

    @staticmethod
    def _log_solution(log: RunLog, t: float, command: Commands, solution: Solution) -> None:
        log.mpc_t.append(t)
        log.solve_ms.append(solution.stats.solve_time_s * 1e3 if solution.stats.solve_time_s else solution.wall_time_s * 1e3)
        log.iterations.append(solution.stats.iterations)
        log.success.append(solution.success)
        log.status.append(solution.stats.status)
        log.commands.append(command)
        log.planned_contact.append(solution.contact[0].copy())

    def _control_tick(self, log: RunLog, active: Solution, t: float) -> np.ndarray:
        q, v = self._measure()
        reference = interpolate(active, t)
        tau = pd_torque(reference, q[7:], v[6:], self.kp, self.kd, self.robot.tau_max)
        q_true, v_true = self.plant.state()
        log.t.append(t)
        log.q.append(q_true)
        log.v.append(v_true)
        log.tau.append(tau)
        log.tau_ff.append(reference.tau_ff)
        log.q_des.append(reference.q_des)
        log.contact_forces.append(self.plant.contact_forces())
        return tau

    def _low_level(self, log, active, t, next_control, tau, t0, duration_s, progress):
        """The 500 Hz loop (eqs. 9-10) when due: returns (torques to hold, next tick, fell)."""
        if t < next_control - 1e-9:
            return tau, next_control, False
        tau = self._control_tick(log, active, t)
        next_control += 1.0 / self.config.control_rate_hz
        if self._fallen(log.q[-1]):
            log.fell, log.fell_at_s = True, t - t0
            return tau, next_control, True
        if progress:
            progress((t - t0) / duration_s)
        return tau, next_control, False

    def _apply_events(self, events: list[Event], t: float) -> None:
        for event in events:
            if not event.done and t >= event.time_s:
                event.action(self.plant)
                event.done = True

    def _run_simulated_time(self, duration_s, commands, events, progress) -> RunLog:
        cfg, plant = self.config, self.plant
        log = RunLog()
        wall_start = time.perf_counter()
        mpc_period = 1.0 / cfg.mpc_rate_hz
        t0 = plant.time_s
        active = self._solve(log, t0, commands)
        if not active.success:
            raise ConfigError(f"the MPC failed on the initial state ({active.stats.status}); check the start pose")
        pending: list[tuple[float, Solution]] = []
        next_mpc, next_control = t0 + mpc_period, t0
        solver_free_at = t0  # with a delay, the single solver is busy until its solution is out
        tau = np.zeros(self.robot.n_joints)
        while plant.time_s - t0 < duration_s - 1e-9:
            t = plant.time_s
            self._apply_events(events, t)
            if t >= next_mpc - 1e-9 and t >= solver_free_at - 1e-9:
                solution = self._solve(log, t, commands)
                delay = 0.0 if cfg.delay == "none" else (
                    solution.wall_time_s if cfg.delay == "measured" else cfg.fixed_delay_s)
                solver_free_at = t + delay
                if delay > mpc_period:
                    log.late_solutions += 1
                while next_mpc <= t + 1e-9:
                    next_mpc += mpc_period
                if solution.success or getattr(solution, "held_previous", False):  # failed: the last plan, shifted
                    log.delay_ms.append(delay * 1e3)
                    pending.append((t + delay, solution))
            while pending and pending[0][0] <= t + 1e-9:
                active = pending.pop(0)[1]
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        return log

    def _run_realtime(self, duration_s, commands, events, progress) -> RunLog:
        """Simulation paced by the wall clock while the MPC solves in its own process.

        A process, not a thread: the simulation loop is Python and would starve a solver thread of
        the GIL. The worker builds its own MPC from the robot spec and config (a few seconds before
        the clock starts); each new solve starts at the next MPC tick after the previous one ended.
        """
        import multiprocessing

        cfg, plant = self.config, self.plant
        log = RunLog()
        context = multiprocessing.get_context("spawn")
        conn, child_conn = context.Pipe()
        worker = context.Process(target=_mpc_worker, args=(self.robot.spec, self.mpc.config, child_conn), daemon=True)
        worker.start()
        try:
            if not conn.poll(300) or conn.recv() != "ready":
                raise ConfigError("the real-time MPC process did not start (see its error above)")
            t0 = plant.time_s
            active = self._solve(log, t0, commands)
            if not active.success:
                raise ConfigError(f"the MPC failed on the initial state ({active.stats.status})")
            mpc_period = 1.0 / cfg.mpc_rate_hz
            next_mpc, next_control = t0 + mpc_period, t0
            busy, request = False, None
            tau = np.zeros(self.robot.n_joints)
            wall_start = time.perf_counter()
            while plant.time_s - t0 < duration_s - 1e-9:
                t = plant.time_s
                lag = (t - t0) - (time.perf_counter() - wall_start)
                if lag > 0:
                    time.sleep(lag)
                self._apply_events(events, t)
                if busy and conn.poll():
                    solution = conn.recv()
                    busy = False
                    self._log_solution(log, request[0], request[1], solution)
                    log.delay_ms.append(solution.wall_time_s * 1e3)
                    if solution.wall_time_s > mpc_period:
                        log.late_solutions += 1
                    if solution.success or getattr(solution, "held_previous", False):
                        active = solution
                if not busy and t >= next_mpc - 1e-9:
                    q, v = self._measure()
                    command = commands(t, q, v)
                    conn.send((q, v, command, t))
                    busy, request = True, (t, command)
                    while next_mpc <= t + 1e-9:
                        next_mpc += mpc_period
                tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress)
                if fell:
                    break
                plant.step(tau)
            log.wall_time_s = time.perf_counter() - wall_start
        finally:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
            worker.join(timeout=5)
            if worker.is_alive():
                worker.terminate()
        return log


def _mpc_worker(spec, mpc_config, conn) -> None:
    """Real-time mode's solver process: build the MPC, then answer (q, v, commands, t) requests."""
    from wbmpc.robots import RobotModel

    mpc = MPC(RobotModel(spec), mpc_config)
    conn.send("ready")
    while True:
        message = conn.recv()
        if message is None:
            return
        q, v, command, t = message
        start = time.perf_counter()
        solution = mpc.solve(q, v, command, t)
        solution.wall_time_s = time.perf_counter() - start
        conn.send(solution)
