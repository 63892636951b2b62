"""The deployment pipeline (section V-B): MPC at 80 Hz, interpolation and joint PD at 500 Hz.

Delay modes: `none` (the simulation waits for the solver, section VI-B1), `measured` (the
step's CPU time elapses in simulation before its solution applies, VI-B2: the time the step takes on
a core of its own, whatever else the machine runs), `measured-wall` (its wall time instead), a fixed
delay in milliseconds, and `realtime` (the MPC runs in its own process while the simulation
advances at wall-clock speed). Until a newer solution is ready the
last good one keeps being interpolated; failed solves are counted and never applied.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import pinocchio as pin

from wbmpc.control.interpolator import PdGains, interpolate, pd_torque
from wbmpc.control.mpc import MPC, Commands
from wbmpc.control.solution import Solution
from wbmpc.errors import ConfigError, check_number

DELAY_MODES = ("none", "measured", "measured-wall", "realtime")
RECOVERY_MARK = "(recovery after"  # in the status of a step that needed a recovery re-solve

Progress = Callable[[float, int], None]  # (share of the run done, recovered steps so far)


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
        return fixed_delay_s(self.delay)


MAX_FIXED_DELAY_MS = 1000.0


def fixed_delay_s(delay: str) -> float | None:
    """The delay in seconds for a number of ms, None for the named modes; refuses anything else."""
    if delay in DELAY_MODES:
        return None
    try:
        value = float(delay)
    except (TypeError, ValueError):
        raise ConfigError.for_field("delay", f"must be none, measured, measured-wall, realtime or a number of ms; got '{delay}'") from None
    check_number("delay", value, low=0.0, high=MAX_FIXED_DELAY_MS, unit="ms")
    return value / 1e3


class CommandSource(Protocol):
    """Commands at time t given the measured state (feedback commands such as arm tracking need it)."""

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray) -> Commands: ...


@dataclass
class Event:
    """Something done to the plant at a time, e.g. a push: `action(plant)`; `name` labels it in plots."""

    time_s: float
    action: Callable
    done: bool = False
    name: str = "event"


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
    events: list = field(default_factory=list)  # (time_s, name) of each event applied to the plant
    late_solutions: int = 0
    sim_cpu_share: float | None = None  # real time: CPU time of the simulation process / wall time
    mpc_cpu_share: float | None = None  # real time: CPU time of the MPC process / wall time
    realtime_priority: str | None = None  # real time: scheduling priority the processes got (see `raise_priority`)
    recovered_solutions: int = 0  # counted as logged: progress reads it every control tick
    interrupted: bool = False  # stopped early by `stop()` (Ctrl-C): the log holds what ran until then
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

    @property
    def mpc_recoveries(self) -> int:
        """Steps whose first solve failed and a recovery re-solve succeeded (`MPC._recover`)."""
        return self.recovered_solutions


class ClosedLoop:
    """Runs an `MPC` against a plant (`wbmpc.sim`) with the paper's interpolation, PD and delays."""

    def __init__(self, mpc: MPC, plant, config: LoopConfig = LoopConfig(), state_source=None):
        """`state_source.measure() -> (q, v)` replaces the plant's true state (e.g. a state estimator)."""
        self.mpc = mpc
        self.state_source = state_source
        self.robot = mpc.robot
        self.plant = plant
        self.config = config
        self.kp, self.kd = config.gains.vectors(~self.robot.leg_joint_mask)
        self._rng = np.random.default_rng(config.seed)
        self._filtered_v: np.ndarray | None = None

    # ------------------------------------------------------------------ measurement
    def _measure(self) -> tuple[np.ndarray, np.ndarray]:
        """State estimate: plant state plus optional joint noise and the low-pass on joint velocities."""
        if self.state_source is not None:
            return self.state_source.measure()
        q, v = self.plant.state()
        cfg = self.config
        if cfg.joint_position_noise_rad:
            noise = np.r_[np.zeros(6), self._rng.normal(0, cfg.joint_position_noise_rad, self.robot.n_joints)]
            q = pin.integrate(self.robot.model, q, noise)
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
            events: list[Event] | None = None, progress: Progress | None = None,
            stop: Callable[[], bool] | None = None) -> RunLog:
        """Run for `duration_s` simulated seconds or until the robot falls or `stop()` turns true
        (polled every control tick, e.g. `wbmpc.interrupt.InterruptFlag`; the log then has `interrupted`)."""
        if not duration_s > 0:
            raise ConfigError(f"duration must be positive, got {duration_s}")
        commands = commands or (lambda t, q, v: Commands())
        events = sorted(events or [], key=lambda e: e.time_s)
        if self.config.delay == "realtime":
            return self._run_realtime(duration_s, commands, events, progress, stop)
        return self._run_simulated_time(duration_s, commands, events, progress, stop)

    def _solve(self, log: RunLog, t: float, commands: CommandSource) -> Solution:
        q, v = self._measure()
        command = commands(t, q, v)
        start, start_cpu = time.perf_counter(), time.thread_time()
        solution = self.mpc.solve(q, v, command, t)
        solution.wall_time_s = time.perf_counter() - start  # type: ignore[attr-defined]
        solution.cpu_time_s = time.thread_time() - start_cpu  # type: ignore[attr-defined]
        self._log_solution(log, t, command, solution)
        return solution

    @staticmethod
    def _log_solution(log: RunLog, t: float, command: Commands, solution: Solution) -> None:
        log.mpc_t.append(t)
        log.solve_ms.append(solution.stats.solve_time_s * 1e3 if solution.stats.solve_time_s else solution.wall_time_s * 1e3)
        log.iterations.append(solution.stats.iterations)
        log.success.append(solution.success)
        log.status.append(solution.stats.status)
        if solution.success and RECOVERY_MARK in str(solution.stats.status):
            log.recovered_solutions += 1
        log.commands.append(command)
        log.planned_contact.append(solution.contact[0].copy())

    def _control_tick(self, log: RunLog, active: Solution, t: float) -> np.ndarray:
        q, v = self._measure()
        reference = interpolate(active, t)
        q_j = self.robot.joint_positions(q, near=reference.q_des)
        tau = pd_torque(reference, q_j, v[6:], self.kp, self.kd, self.robot.tau_max)
        q_true, v_true = self.plant.state()
        log.t.append(t)
        log.q.append(q_true)
        log.v.append(v_true)
        log.tau.append(tau)
        log.tau_ff.append(reference.tau_ff)
        log.q_des.append(reference.q_des)
        log.contact_forces.append(self.plant.contact_forces())
        return tau

    def _low_level(self, log, active, t, next_control, tau, t0, duration_s, progress, stop=None):
        """The 500 Hz loop (eqs. 9-10) when due: returns (torques to hold, next tick, end the run)."""
        if t < next_control - 1e-9:
            return tau, next_control, False
        tau = self._control_tick(log, active, t)
        next_control += 1.0 / self.config.control_rate_hz
        if self._fallen(log.q[-1]):
            log.fell, log.fell_at_s = True, t - t0
            return tau, next_control, True
        if progress:
            progress((t - t0) / duration_s, log.mpc_recoveries)
        if stop is not None and stop():
            log.interrupted = True
            return tau, next_control, True
        return tau, next_control, False

    def _apply_events(self, events: list[Event], t: float, log: RunLog) -> None:
        for event in events:
            if not event.done and t >= event.time_s:
                event.action(self.plant)
                event.done = True
                log.events.append((t, event.name))

    def _run_simulated_time(self, duration_s, commands, events, progress, stop=None) -> RunLog:
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
            self._apply_events(events, t, log)
            if t >= next_mpc - 1e-9 and t >= solver_free_at - 1e-9:
                solution = self._solve(log, t, commands)
                delay = 0.0 if cfg.delay == "none" else (
                    solution.cpu_time_s if cfg.delay == "measured" else
                    solution.wall_time_s if cfg.delay == "measured-wall" else cfg.fixed_delay_s)
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
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress, stop)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        return log

    def _run_realtime(self, duration_s, commands, events, progress, stop=None) -> RunLog:
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
        cpus = _cpu_split()
        worker = context.Process(target=mpc_worker, args=(self.robot.spec, self.mpc.config, child_conn, cpus[1]),
                                 daemon=True)
        single_threaded = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
        saved = {name: os.environ.get(name) for name in single_threaded}
        os.environ.update(single_threaded)  # the worker inherits it: no BLAS threads competing with the solver
        try:
            worker.start()
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
        if cpus[0]:
            os.sched_setaffinity(0, cpus[0])
        own_nice = os.getpriority(os.PRIO_PROCESS, 0) if hasattr(os, "getpriority") else None
        log.realtime_priority = raise_priority()
        try:
            for _ in range(1500):  # up to 300 s for the worker's build, Ctrl-C honoured meanwhile
                if conn.poll(0.2) or (stop is not None and stop()) or not worker.is_alive():
                    break
            if stop is not None and stop():
                log.interrupted = True
                return log
            if not conn.poll(0) or conn.recv() != "ready":
                raise ConfigError("the real-time MPC process did not start (see its error above)")
            t0 = plant.time_s
            active = self._solve(log, t0, commands)
            if not active.success:
                raise ConfigError(f"the MPC failed on the initial state ({active.stats.status})")
            mpc_period = 1.0 / cfg.mpc_rate_hz
            next_mpc, next_control = t0 + mpc_period, t0
            busy, request = False, None
            tau = np.zeros(self.robot.n_joints)
            conn.send("cpu")
            mpc_cpu_start = conn.recv()
            wall_start, cpu_start = time.perf_counter(), time.process_time()
            while plant.time_s - t0 < duration_s - 1e-9:
                t = plant.time_s
                lag = (t - t0) - (time.perf_counter() - wall_start)
                if lag > 0:
                    time.sleep(lag)
                self._apply_events(events, t, log)
                if busy and conn.poll():
                    solution = conn.recv()
                    busy = False
                    elapsed = max(time.perf_counter() - wall_start, 1e-9)
                    log.mpc_cpu_share = (solution.process_cpu_s - mpc_cpu_start) / elapsed
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
                tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress,
                                                          stop)
                if fell:
                    break
                plant.step(tau)
            log.wall_time_s = time.perf_counter() - wall_start
            log.sim_cpu_share = (time.process_time() - cpu_start) / max(log.wall_time_s, 1e-9)
        finally:
            if cpus[0]:
                os.sched_setaffinity(0, cpus[0] | cpus[1])
            if own_nice is not None and log.realtime_priority != "default":
                try:
                    os.setpriority(os.PRIO_PROCESS, 0, own_nice)  # back to the caller's priority
                except OSError:
                    pass
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
            worker.join(timeout=5)
            if worker.is_alive():
                worker.terminate()
        return log


REALTIME_NICE = -10  # asked for by both real-time processes; granted where the user may (root, CAP_SYS_NICE)


def raise_priority(nice: int = REALTIME_NICE) -> str:
    """Ask the scheduler to prefer this process over ordinary work (a real-time control loop shares the
    machine with builds, browsers, other jobs). Returns what was granted: "nice -10" or "default"
    (not permitted: the loop runs at normal priority and other load can make solutions late)."""
    if not hasattr(os, "setpriority"):
        return "default"
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        if current > nice:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
        return f"nice {min(current, nice)}"
    except OSError:
        return "default"


def _cpu_split() -> tuple[set[int], set[int]]:
    """(simulation CPUs, MPC CPUs): one core each where there are two or more, so neither starves
    the other; empty sets (no pinning) on a single core or where affinity is not supported."""
    try:
        available = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(), set()
    if len(available) < 2:
        return set(), set()
    return {available[0]}, set(available[1:])


def mpc_worker(spec, mpc_config, conn, cpus: set[int] | None = None) -> None:
    """Real-time mode's solver process: build the MPC, then answer (q, v, commands, t) requests
    ("cpu" asks for the process's CPU time so far)."""
    import signal

    from wbmpc.robots import RobotModel

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent decides
    if cpus:
        os.sched_setaffinity(0, cpus)
    raise_priority()
    mpc = MPC(RobotModel(spec), mpc_config)
    mpc.prepare_fallback()  # a failed step must not pay for building its recovery solvers
    conn.send("ready")
    while True:
        message = conn.recv()
        if message is None:
            return
        if message == "cpu":
            conn.send(time.process_time())
            continue
        q, v, command, t = message
        start = time.perf_counter()
        solution = mpc.solve(q, v, command, t)
        solution.wall_time_s = time.perf_counter() - start
        solution.process_cpu_s = time.process_time()  # type: ignore[attr-defined]
        conn.send(solution)
