"""`RunLog`: what a closed-loop run did, per control tick (500 Hz) and per MPC step, in bounded memory."""

from __future__ import annotations

import numpy as np

from wbmpc.chunked_table import DEFAULT_CHUNK_ROWS, ChunkedTable, ChunkWriter
from wbmpc.control.commands import Commands
from wbmpc.control.realtime_channel import COMMAND_WIDTH, command_from_row, command_row
from wbmpc.control.step_anatomy import SEGMENTS
from wbmpc.control.streaming_stats import StreamingStats
from wbmpc.errors import ConfigError

RECOVERY_MARK = "(recovery after"  # in the status of a step that needed a recovery re-solve


TICK_KEYS = ("t", "q", "v", "tau", "tau_ff", "q_des", "contact_forces")
STEP_KEYS = ("mpc_t", "solve_ms", "iterations", "success", "planned_contact")
SOLVER_DETAIL_KEYS = ("sqp_iterations", "primal_residual", "dual_residual", "budget_ms", "late")
RSS_SAMPLE_PERIOD_S = 10.0  # simulated seconds between resident-memory samples


class RunLog:
    """What happened: per control tick (500 Hz) and per MPC step (80 Hz), in bounded memory.

    Ticks and steps go into `ChunkedTable`s (one preallocated chunk each, full chunks spilled to
    `.npy` files in `spill_dir`, a temporary directory by default), so a run of any length holds a
    few MB. The spills are written by the log's own writer thread (`ChunkWriter`), off the loop that
    records the rows. Read whole columns with `arrays(keys)` (`every=k`: every k-th tick, for plots and
    replays), stream them with `tick_chunks(keys)`; the attributes `t`, `q`, ... `mpc_t`,
    `status`, `commands` read whole columns back too. Counters (failures, recoveries) are kept as
    the steps are logged. `rss_samples` holds (simulated s since the start, resident MB) every
    RSS_SAMPLE_PERIOD_S of a run.
    """

    def __init__(self, spill_dir=None, chunk_rows: int = DEFAULT_CHUNK_ROWS):
        self.spill_dir = spill_dir
        self.chunk_rows = chunk_rows
        self._writer = ChunkWriter()  # writes the full chunks of every table below
        self._ticks: ChunkedTable | None = None  # built at the first row, when the sizes are known
        self._steps: ChunkedTable | None = None
        self._delays = ChunkedTable({"delay_ms": ((), float)}, chunk_rows, spill_dir, "delays", self._writer)
        # per step of a solver that reports them (the anytime SQP): its SQP iterations, the KKT residuals of the
        # iterate it returned, its budget (NaN: none) and whether it ended past its deadline
        self._solver_details = ChunkedTable({key: ((), float) for key in SOLVER_DETAIL_KEYS}, chunk_rows, spill_dir,
                                            "solver_details", self._writer)
        # real time: where each plan's delay went (control/step_anatomy.SEGMENTS, ms), one row per plan taken
        self._anatomy = ChunkedTable({"anatomy_ms": ((len(SEGMENTS),), float)}, chunk_rows, spill_dir, "anatomy",
                                     self._writer)
        self._status_names: list[str] = []  # distinct solver statuses; steps store an index into it
        self._status_codes: dict[str, int] = {}
        self.events: list = []  # (time_s, name) of each event applied to the plant
        self.rss_samples: list[tuple[float, float]] = []
        self.late_solutions = 0
        self.sim_cpu_share: float | None = None  # real time: CPU time of the simulation process / wall time
        self.mpc_cpu_share: float | None = None  # real time: CPU time of the MPC process / wall time
        self.realtime_priority: str | None = None  # real time: scheduling priority granted (see `raise_loop_priority`)
        self.session_nice: int | None = None  # real time: the session group's nice (Linux autogroups), None: none
        self.cpu_plan = None  # real time: where the loop and the solver's threads ran (`solver_process.CpuPlan`)
        self.solver_helper_threads = 0  # real time: the solver's helper threads placed by the plan
        self.solver_scheduling: dict = {}  # real time: its threads' priorities (`SolverProcess.scheduling`)
        self.realtime_competitors: list[int] = []  # real time: other processes at FIFO at its start or end
        # real time: how late after its wall-clock time each joint-loop tick ran (ms, `StreamingStats`: fixed memory)
        self.plant_lateness: StreamingStats | None = None
        self.recovered_solutions = 0  # counted as logged: progress reads it every control tick
        self.failed_solutions = 0
        self.interrupted = False  # stopped early by `stop()` (Ctrl-C): the log holds what ran until then
        self.fell = False
        self.fell_at_s: float | None = None
        self.wall_time_s = 0.0
        self.mpc_rate_hz: float | None = None  # the loop's configured MPC rate (`LoopConfig.mpc_rate_hz`)
        self.control_rate_hz: float | None = None  # ... and its joint loop's (`LoopConfig.control_rate_hz`)

    # ------------------------------------------------------------------ writing
    def record_tick(self, t_s: float, q, v, tau, tau_ff, q_des, contact_forces) -> None:
        row = {"t": t_s, "q": q, "v": v, "tau": tau, "tau_ff": tau_ff, "q_des": q_des, "contact_forces": contact_forces}
        if self._ticks is None:
            self._ticks = self._table(row, "ticks")
        self._ticks.append(row)

    def record_step(self, t_s: float, solve_ms: float, iterations: int, success: bool, status, command: Commands,
                    planned_contact) -> None:
        status = str(status)
        code = self._status_codes.get(status)
        if code is None:
            code = self._status_codes[status] = len(self._status_names)
            self._status_names.append(status)
        row = {"mpc_t": t_s, "solve_ms": solve_ms, "iterations": iterations, "success": bool(success),
               "planned_contact": planned_contact, "status_code": code, "command": command_row(command)}
        if self._steps is None:
            self._steps = self._table(row, "steps")
        self._steps.append(row)
        if not success:
            self.failed_solutions += 1
        elif RECOVERY_MARK in status:
            self.recovered_solutions += 1

    def record_solution(self, t_s: float, command: Commands, solution) -> None:
        """One MPC step from its `Solution`: solve time (the solver's, else the step's wall time), iterations,
        success, status (recoveries and failures counted from it), the command and the first planned contacts;
        the solver's details (SQP iterations, residuals) once a solver reports them."""
        solve_s = solution.stats.solve_time_s if solution.stats.solve_time_s else solution.wall_time_s
        self.record_step(t_s, solve_s * 1e3, solution.stats.iterations, solution.success, solution.stats.status, command,
                         solution.contact[0])
        if solution.stats.details or self.has_solver_details:  # one row per step once a solver reports them
            self.record_solver_details(solution.stats.details)

    @property
    def spilled_chunks(self) -> int:
        """Chunks of control ticks written to the spill directory so far (the memory held stays one chunk)."""
        return self._ticks.spilled_chunks if self._ticks is not None else 0

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

    def record_anatomy(self, segments_ms) -> None:
        """Real time: one plan's delay in its segments (`step_anatomy.segments`)."""
        self._anatomy.append({"anatomy_ms": segments_ms})

    def anatomy(self) -> np.ndarray:
        """(plans, len(SEGMENTS)) of a real-time run (no rows for the other delay modes)."""
        return self._anatomy.column("anatomy_ms")

    def _table(self, row: dict, name: str) -> ChunkedTable:
        """A table whose columns have the shapes of `row`'s values: floats, integers or booleans."""
        kinds = {"f": np.float64, "i": np.int64, "u": np.int64, "b": np.bool_}
        columns = {}
        for key, value in row.items():
            array = np.asarray(value)
            if array.dtype.kind not in kinds:
                raise ConfigError(f"run log column '{key}' needs numbers, got {type(value).__name__} {value!r}")
            columns[key] = (array.shape, kinds[array.dtype.kind])
        return ChunkedTable(columns, self.chunk_rows, self.spill_dir, name, self._writer)

    def close(self) -> None:
        """Delete the spilled chunks now (otherwise when the log is garbage collected)."""
        for table in (self._ticks, self._steps, self._delays, self._solver_details, self._anatomy):
            if table is not None:
                table.close()

    def start_writer(self) -> None:
        """Start the chunk writer's thread now (`ChunkWriter.start`: a real-time loop, before its priority)."""
        self._writer.start()

    def flush(self) -> None:
        """Wait until every full chunk handed to the writer thread is on disk (`ChunkWriter.flush`)."""
        self._writer.flush()

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
