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

from wbmpc.control.chunked_table import DEFAULT_CHUNK_ROWS, ChunkedTable
from wbmpc.control.interpolator import PdGains, interpolate, pd_torque
from wbmpc.control.mpc import MPC, Commands
from wbmpc.control.realtime_channel import COMMAND_WIDTH, command_from_row, command_row
from wbmpc.control.solution import Solution
from wbmpc.control.solver_process import SolverProcess, cpu_split, raise_priority
from wbmpc.errors import ConfigError, RunError, check_number
from wbmpc.resident_memory import rss_mb

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
    # the ground (`wbmpc.terrain.Terrain`): the fall check measures the base's height from its support there
    terrain: object | None = None
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


TICK_KEYS = ("t", "q", "v", "tau", "tau_ff", "q_des", "contact_forces")
STEP_KEYS = ("mpc_t", "solve_ms", "iterations", "success", "planned_contact")
SOLVER_DETAIL_KEYS = ("sqp_iterations", "primal_residual", "dual_residual", "budget_ms", "late")
RSS_SAMPLE_PERIOD_S = 10.0  # simulated seconds between resident-memory samples


class RunLog:
    """What happened: per control tick (500 Hz) and per MPC step (80 Hz), in bounded memory.

    Ticks and steps go into `ChunkedTable`s (one preallocated chunk each, full chunks spilled to
    `.npy` files in `spill_dir`, a temporary directory by default), so a run of any length holds a
    few MB. Read whole columns with `arrays(keys)` (`every=k`: every k-th tick, for plots and
    replays), stream them with `tick_chunks(keys)`; the attributes `t`, `q`, ... `mpc_t`,
    `status`, `commands` read whole columns back too. Counters (failures, recoveries) are kept as
    the steps are logged. `rss_samples` holds (simulated s since the start, resident MB) every
    RSS_SAMPLE_PERIOD_S of a run.
    """

    def __init__(self, spill_dir=None, chunk_rows: int = DEFAULT_CHUNK_ROWS):
        self.spill_dir = spill_dir
        self.chunk_rows = chunk_rows
        self._ticks: ChunkedTable | None = None  # built at the first row, when the sizes are known
        self._steps: ChunkedTable | None = None
        self._delays = ChunkedTable({"delay_ms": ((), float)}, chunk_rows, spill_dir, "delays")
        # per step of a solver that reports them (the anytime SQP): its SQP iterations, the KKT residuals of the
        # iterate it returned, its budget (NaN: none) and whether it ended past its deadline
        self._solver_details = ChunkedTable({key: ((), float) for key in SOLVER_DETAIL_KEYS}, chunk_rows, spill_dir,
                                            "solver_details")
        self._status_names: list[str] = []  # distinct solver statuses; steps store an index into it
        self._status_codes: dict[str, int] = {}
        self.events: list = []  # (time_s, name) of each event applied to the plant
        self.rss_samples: list[tuple[float, float]] = []
        self.late_solutions = 0
        self.sim_cpu_share: float | None = None  # real time: CPU time of the simulation process / wall time
        self.mpc_cpu_share: float | None = None  # real time: CPU time of the MPC process / wall time
        self.realtime_priority: str | None = None  # real time: scheduling priority granted (see `raise_priority`)
        self.recovered_solutions = 0  # counted as logged: progress reads it every control tick
        self.failed_solutions = 0
        self.interrupted = False  # stopped early by `stop()` (Ctrl-C): the log holds what ran until then
        self.fell = False
        self.fell_at_s: float | None = None
        self.wall_time_s = 0.0

    # ------------------------------------------------------------------ writing
    def record_tick(self, t: float, q, v, tau, tau_ff, q_des, contact_forces) -> None:
        row = {"t": t, "q": q, "v": v, "tau": tau, "tau_ff": tau_ff, "q_des": q_des, "contact_forces": contact_forces}
        if self._ticks is None:
            self._ticks = self._table(row, "ticks")
        self._ticks.append(row)

    def record_step(self, t: float, solve_ms: float, iterations: int, success: bool, status, command: Commands,
                    planned_contact) -> None:
        status = str(status)
        code = self._status_codes.get(status)
        if code is None:
            code = self._status_codes[status] = len(self._status_names)
            self._status_names.append(status)
        row = {"mpc_t": t, "solve_ms": solve_ms, "iterations": iterations, "success": bool(success),
               "planned_contact": planned_contact, "status_code": code, "command": command_row(command)}
        if self._steps is None:
            self._steps = self._table(row, "steps")
        self._steps.append(row)
        if not success:
            self.failed_solutions += 1
        elif RECOVERY_MARK in status:
            self.recovered_solutions += 1

    @classmethod
    def from_columns(cls, t, q, v, tau, tau_ff=None, q_des=None, contact_forces=None, *, mpc_t=(), solve_ms=None,
                     iterations=None, success=None, status=None, commands=None, planned_contact=None,
                     chunk_rows: int = DEFAULT_CHUNK_ROWS) -> "RunLog":
        """A log of whole columns (synthetic runs in tests and tools). Missing tick columns are zeros
        (one foot for the contact forces); missing step columns 0 ms, 0 iterations, success, "ok",
        zero `Commands` and no planned contact."""
        log = cls(chunk_rows=chunk_rows)
        n, n_joints = len(t), np.shape(tau)[1]
        tau_ff = np.zeros((n, n_joints)) if tau_ff is None else tau_ff
        q_des = np.zeros((n, n_joints)) if q_des is None else q_des
        contact_forces = np.zeros((n, 1, 3)) if contact_forces is None else contact_forces
        for k in range(n):
            log.record_tick(t[k], q[k], v[k], tau[k], tau_ff[k], q_des[k], contact_forces[k])
        m = len(mpc_t)
        for k in range(m):
            log.record_step(mpc_t[k], 0.0 if solve_ms is None else solve_ms[k], 0 if iterations is None else iterations[k],
                            True if success is None else success[k], "ok" if status is None else status[k],
                            Commands() if commands is None else commands[k],
                            np.zeros(1) if planned_contact is None else planned_contact[k])
        return log

    def record_solver_details(self, details: dict | None) -> None:
        """A step's solver details (`SolverStats.details` of the anytime SQP); missing keys are NaN (a step a
        recovery solver took over has none)."""
        row = {}
        for key in SOLVER_DETAIL_KEYS:
            value = (details or {}).get(key)
            row[key] = float("nan") if value is None else float(value)
        self._solver_details.append(row)

    @property
    def has_solver_details(self) -> bool:
        return len(self._solver_details) > 0

    def solver_details(self) -> dict[str, np.ndarray]:
        """{key: one value per step that reported details} (empty arrays when no step did)."""
        return {key: self._solver_details.column(key) for key in SOLVER_DETAIL_KEYS}

    def record_delay(self, delay_ms: float) -> None:
        """The delay of a solution that was applied (failed ones are not)."""
        self._delays.append({"delay_ms": delay_ms})

    def _table(self, row: dict, name: str) -> ChunkedTable:
        """A table whose columns have the shapes of `row`'s values: floats, integers or booleans."""
        kinds = {"f": np.float64, "i": np.int64, "u": np.int64, "b": np.bool_}
        columns = {}
        for key, value in row.items():
            array = np.asarray(value)
            if array.dtype.kind not in kinds:
                raise ConfigError(f"run log column '{key}' needs numbers, got {type(value).__name__} {value!r}")
            columns[key] = (array.shape, kinds[array.dtype.kind])
        return ChunkedTable(columns, self.chunk_rows, self.spill_dir, name)

    def close(self) -> None:
        """Delete the spilled chunks now (otherwise when the log is garbage collected)."""
        for table in (self._ticks, self._steps, self._delays, self._solver_details):
            if table is not None:
                table.close()

    # ------------------------------------------------------------------ reading
    @property
    def n_ticks(self) -> int:
        return len(self._ticks) if self._ticks is not None else 0

    @property
    def n_steps(self) -> int:
        return len(self._steps) if self._steps is not None else 0

    def last_tick(self, key: str) -> np.ndarray:
        return self._ticks.last(key)

    def first_tick(self, key: str) -> np.ndarray:
        return self._ticks.first(key)

    def arrays(self, keys: tuple[str, ...] | None = None, every: int = 1) -> dict[str, np.ndarray]:
        """Whole columns {name: array with one row per tick or step}; `every=k` keeps every k-th control
        tick (from the first) and leaves the MPC-step columns whole. Default: all of TICK_KEYS,
        STEP_KEYS and `delay_ms`."""
        keys = TICK_KEYS + STEP_KEYS + ("delay_ms",) if keys is None else tuple(keys)
        out = {}
        for key in keys:
            if key in TICK_KEYS:
                out[key] = self._ticks.column(key, every) if self._ticks is not None else np.zeros(0)
            elif key in STEP_KEYS:
                out[key] = self._steps.column(key) if self._steps is not None else np.zeros(0)
            elif key == "delay_ms":
                out[key] = self._delays.column(key)
            else:
                raise ConfigError(f"the run log has no column '{key}'; it has {', '.join(TICK_KEYS + STEP_KEYS)}, delay_ms")
        return out

    def tick_chunks(self, keys: tuple[str, ...] = TICK_KEYS):
        """The control ticks in order, a chunk at a time ({key: rows}): whole-run statistics in bounded memory."""
        if self._ticks is not None:
            yield from self._ticks.iter_chunks(keys)

    def _step_list(self, key: str) -> list:
        return self.arrays((key,))[key].tolist()

    t = property(lambda self: self.arrays(("t",))["t"], doc="control tick times (s), whole column")
    q = property(lambda self: self.arrays(("q",))["q"])
    v = property(lambda self: self.arrays(("v",))["v"])
    tau = property(lambda self: self.arrays(("tau",))["tau"])
    tau_ff = property(lambda self: self.arrays(("tau_ff",))["tau_ff"])
    q_des = property(lambda self: self.arrays(("q_des",))["q_des"])
    contact_forces = property(lambda self: self.arrays(("contact_forces",))["contact_forces"])
    mpc_t = property(lambda self: self._step_list("mpc_t"), doc="MPC step times (s), a list")
    solve_ms = property(lambda self: self._step_list("solve_ms"))
    iterations = property(lambda self: self._step_list("iterations"))
    success = property(lambda self: self._step_list("success"))
    delay_ms = property(lambda self: self._delays.column("delay_ms").tolist())
    planned_contact = property(lambda self: list(self.arrays(("planned_contact",))["planned_contact"]))

    @property
    def status(self) -> list[str]:
        if self._steps is None:
            return []
        return [self._status_names[code] for code in self._steps.column("status_code")]

    @property
    def commands(self) -> list[Commands]:
        if self._steps is None:
            return []
        return [command_from_row(row) for row in self._steps.column("command")]

    def command_array(self) -> np.ndarray:
        """(steps, COMMAND_WIDTH) commands as numbers (see `command_row`), without building `Commands`."""
        return self._steps.column("command") if self._steps is not None else np.zeros((0, COMMAND_WIDTH))

    @property
    def mpc_failures(self) -> int:
        return self.failed_solutions

    @property
    def mpc_recoveries(self) -> int:
        """Steps whose first solve failed and a recovery re-solve succeeded (`MPC._recover`)."""
        return self.recovered_solutions


class ClosedLoop:
    """Runs an `MPC` against a plant (`wbmpc.sim`) with the paper's interpolation, PD and delays."""

    def __init__(self, mpc: MPC, plant, config: LoopConfig = LoopConfig(), state_source=None,
                 log_dir=None, log_chunk_rows: int = DEFAULT_CHUNK_ROWS):
        """`state_source.measure() -> (q, v)` replaces the plant's true state (e.g. a state estimator);
        `log_dir` is where the `RunLog` spills full chunks of `log_chunk_rows` rows (a temporary directory if None)."""
        self.mpc = mpc
        self.log_dir = log_dir
        self.log_chunk_rows = log_chunk_rows
        self.state_source = state_source
        self.robot = mpc.robot
        self.plant = plant
        self.config = config
        self.kp, self.kd = config.gains.vectors(~self.robot.leg_joint_mask)
        self._rng = np.random.default_rng(config.seed)
        self._filtered_v: np.ndarray | None = None
        self._delay_mean_s = 0.0  # running mean of the measured delays (delay compensation's guess)
        self._support = None  # the terrain's support plane under the base (the fall check's ground)
        if config.terrain is not None and not config.terrain.is_flat:
            from wbmpc.control.terrain_references import support_footprint

            self._support = support_footprint(self.robot, config.terrain)

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
        rot = pin.Quaternion(q[3:7]).toRotationMatrix()
        ground = 0.0 if self._support is None else float(self._support.height(q[:2], np.arctan2(rot[1, 0], rot[0, 0])))
        height_ok = q[2] - ground > self.config.fall_height_ratio * self.robot.q_nominal[2]
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

    def _expected_delay_s(self, log: RunLog) -> float:
        """The delay the next plan will see (for `MpcConfig.delay_compensation`): the fixed one, else the
        running mean of the measured ones (0 before any)."""
        if self.config.delay == "none":
            return 0.0
        fixed = self.config.fixed_delay_s
        return fixed if fixed is not None else self._delay_mean_s

    def _note_delay(self, delay_s: float) -> None:
        self._delay_mean_s = delay_s if self._delay_mean_s == 0.0 else 0.8 * self._delay_mean_s + 0.2 * delay_s

    def _solve(self, log: RunLog, t: float, commands: CommandSource, first: bool = False) -> Solution:
        """One MPC step from the state measured now; `first`: the run's first step, applied at once."""
        q, v = self._measure()
        command = commands(t, q, v)
        start, start_cpu = time.perf_counter(), time.thread_time()
        delay_s = 0.0 if first else self._expected_delay_s(log)
        # passed only when there is one: MPC stand-ins (benchmarks' recorders) take (q, v, commands, t)
        solution = self.mpc.solve(q, v, command, t, **({"delay_s": delay_s} if delay_s else {}))
        solution.wall_time_s = time.perf_counter() - start
        solution.cpu_time_s = time.thread_time() - start_cpu
        self._log_solution(log, t, command, solution)
        return solution

    @staticmethod
    def _log_solution(log: RunLog, t: float, command: Commands, solution: Solution) -> None:
        solve_s = solution.stats.solve_time_s if solution.stats.solve_time_s else solution.wall_time_s
        log.record_step(t, solve_s * 1e3, solution.stats.iterations, solution.success, solution.stats.status, command,
                        solution.contact[0])
        if solution.stats.details or log.has_solver_details:  # one row per step once a solver reports them
            log.record_solver_details(solution.stats.details)

    def _new_log(self) -> RunLog:
        return RunLog(self.log_dir, self.log_chunk_rows)

    def _control_tick(self, log: RunLog, active: Solution, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The torques of this tick and the plant's true configuration (logged)."""
        q, v = self._measure()
        reference = interpolate(active, t)
        q_j = self.robot.joint_positions(q, near=reference.q_des)
        tau = pd_torque(reference, q_j, v[6:], self.kp, self.kd, self.robot.tau_max)
        q_true, v_true = self.plant.state()
        log.record_tick(t, q_true, v_true, tau, reference.tau_ff, reference.q_des, self.plant.contact_forces())
        return tau, q_true

    def _low_level(self, log, active, t, next_control, tau, t0, duration_s, progress, stop=None):
        """The 500 Hz loop (eqs. 9-10) when due: returns (torques to hold, next tick, end the run)."""
        if t < next_control - 1e-9:
            return tau, next_control, False
        tau, q_true = self._control_tick(log, active, t)
        next_control += 1.0 / self.config.control_rate_hz
        if t - t0 >= len(log.rss_samples) * RSS_SAMPLE_PERIOD_S - 1e-9:
            log.rss_samples.append((t - t0, rss_mb()))
        if self._fallen(q_true):
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
        log = self._new_log()
        wall_start = time.perf_counter()
        mpc_period = 1.0 / cfg.mpc_rate_hz
        t0 = plant.time_s
        active = self._solve(log, t0, commands, first=True)
        if not active.success:
            raise RunError(f"the MPC failed on the initial state ({active.stats.status}); check the start pose")
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
                self._note_delay(delay)
                if delay > mpc_period:
                    log.late_solutions += 1
                while next_mpc <= t + 1e-9:
                    next_mpc += mpc_period
                if solution.success or solution.held_previous:  # failed: the last plan, shifted
                    log.record_delay(delay * 1e3)
                    pending.append((t + delay, solution))
            while pending and pending[0][0] <= t + 1e-9:
                active = pending.pop(0)[1]
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress, stop)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        log.rss_samples.append((plant.time_s - t0, rss_mb()))
        return log

    def _run_realtime(self, duration_s, commands, events, progress, stop=None) -> RunLog:
        """Simulation paced by the wall clock while the MPC solves in its own process (`SolverProcess`,
        built before the clock starts); each new solve starts at the next MPC tick after the previous one ended."""
        log = self._new_log()
        cpus = cpu_split()
        solver = SolverProcess(self.robot.spec, self.mpc.config, cpus[1], stop)
        if cpus[0]:
            os.sched_setaffinity(0, cpus[0])
        own_nice = os.getpriority(os.PRIO_PROCESS, 0) if hasattr(os, "getpriority") else None
        log.realtime_priority = raise_priority()
        try:
            if solver.interrupted:
                log.interrupted = True
                return log
            t0 = self.plant.time_s
            active = self._solve(log, t0, commands, first=True)
            if not active.success:
                raise RunError(f"the MPC failed on the initial state ({active.stats.status}); check the start pose")
            # the solver process solves the first step too, before the clock: its MPC then warm-starts (a cold
            # step of the anytime SQP ignores its deadline to converge) from the same state as this one's
            q, v = self._measure()
            solver.request(q, v, commands(t0, q, v), t0)
            solver.receive()  # from here on requests and plans go through shared memory
            self._paced_loop(log, solver, active, t0, duration_s, commands, events, progress, stop)
        finally:
            if cpus[0]:
                os.sched_setaffinity(0, cpus[0] | cpus[1])
            if own_nice is not None and log.realtime_priority != "default":
                try:
                    os.setpriority(os.PRIO_PROCESS, 0, own_nice)  # back to the caller's priority
                except OSError:
                    pass
            solver.close()
        return log

    def _paced_loop(self, log: RunLog, solver: SolverProcess, active: Solution, t0: float, duration_s, commands,
                    events, progress, stop) -> None:
        """The 500 Hz simulation on the wall clock: a request to the solver process at each free MPC tick,
        its answer taken as soon as it is ready, the last good plan interpolated meanwhile (eqs. 9-10)."""
        plant, mpc_period = self.plant, 1.0 / self.config.mpc_rate_hz
        next_mpc, next_control = t0 + mpc_period, t0
        request = None  # (t, command, wall time) of the request being solved; None: the solver is free
        # the transport (shared memory, wake-ups, this loop noticing the answer) measured per step: the
        # solver's budget is the period less it, so that the answer is back before the next MPC tick
        transport_s = REALTIME_TRANSPORT_GUESS_S
        tau = np.zeros(self.robot.n_joints)
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        while plant.time_s - t0 < duration_s - 1e-9:
            t = plant.time_s
            lag = (t - t0) - (time.perf_counter() - wall_start)
            if lag > 0:  # wait for the wall clock, woken early by the answer
                if request is not None:
                    solver.wait(lag)
                    lag = (t - t0) - (time.perf_counter() - wall_start)
                if lag > 0:
                    time.sleep(lag)
            self._apply_events(events, t, log)
            if request is not None and solver.ready():
                solution = solver.receive()
                now = time.perf_counter()
                log.mpc_cpu_share = (solution.process_cpu_s - solver.cpu_start_s) / max(now - wall_start, 1e-9)
                transport_s = self._take_answer(log, solution, request, t, now, transport_s)
                if solution.success or solution.held_previous:
                    active = solution
                request = None
            if request is None and t >= next_mpc - 1e-9:
                if not solver.is_alive():
                    raise RunError("the real-time MPC process died (see its error above)")
                q, v = self._measure()
                command = commands(t, q, v)
                budget = max(mpc_period - transport_s - REALTIME_MARGIN_S, REALTIME_MARGIN_S)
                solver.request(q, v, command, t, self._delay_mean_s, budget)
                request = (t, command, time.perf_counter())
                while next_mpc <= t + 1e-9:
                    next_mpc += mpc_period
            tau, next_control, fell = self._low_level(log, active, t, next_control, tau, t0, duration_s, progress, stop)
            if fell:
                break
            plant.step(tau)
        log.wall_time_s = time.perf_counter() - wall_start
        log.rss_samples.append((plant.time_s - t0, rss_mb()))
        log.sim_cpu_share = (time.process_time() - cpu_start) / max(log.wall_time_s, 1e-9)

    def _take_answer(self, log: RunLog, solution: Solution, request, t: float, now: float, transport_s: float) -> float:
        """Log a plan from the solver process with the delay the plant sees (from the measurement to the
        plan's first tick, transport included); returns the updated transport estimate."""
        self._log_solution(log, request[0], request[1], solution)
        delay = max(t - request[0], now - request[2])
        log.record_delay(delay * 1e3)
        self._note_delay(delay)
        if delay > 1.0 / self.config.mpc_rate_hz:
            log.late_solutions += 1
        return 0.8 * transport_s + 0.2 * max(delay - solution.wall_time_s, 0.0)


REALTIME_TRANSPORT_GUESS_S = 1e-3  # the transport's first guess, before one was measured
REALTIME_MARGIN_S = 0.5e-3  # kept free of the budget for the jitter of the transport
