"""Shared-memory channel between the real-time simulation and its MPC process (`--delay-mode realtime`).

Each MPC step moves a request (measured q, v, the command, t, the expected delay and the step budget)
one way and a plan (the `Solution` arrays and its solver statistics) the other. Through a pipe that
is two pickles, two copies through the kernel and a poll per simulation tick. Here both live in one
`multiprocessing.shared_memory` block as NumPy views written in place, and each side is woken by a
`Signal` (a semaphore): the solver process blocks on the request, the simulation checks (or waits with a
timeout on) the answer. The layout is taken from a first solution
of the same MPC, so both sides agree on every shape.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.control.solution import Solution
from wbmpc.control.step_anatomy import INDEX, SOLVER_STAMPS
from wbmpc.solvers.nlp import SolverStats

SOLUTION_ARRAYS = ("node_times_s", "q", "v", "a", "forces", "tau", "contact", "q_joints")
STATS_SCALARS = ("t_s", "success", "held_previous", "iterations", "solve_time_s", "cpu_time_s",
                 "max_constraint_violation", "cost", "wall_time_s", "process_cpu_s")
DETAIL_KEYS = ("sqp_iterations", "primal_residual", "dual_residual", "budget_ms", "late")
STATUS_BYTES = 2048
REQUEST_SCALARS = ("t", "delay_s", "budget_s", "stop", "next_request_s")
# the solver process waits for the next request awake (polling its semaphore) from SPIN_LEAD_S before it is due
# (`next_request_s`, on the shared perf_counter clock) to SPIN_AFTER_S after: a sleeping process woken by a post
# waits for the scheduler (under load 0.3 ms on average, 2-4 ms at the 95th percentile on g1 in real time)
SPIN_LEAD_S = 0.3e-3
SPIN_AFTER_S = 1.5e-3
INERTIAL_WIDTH = 5  # identified base CoM offset (3, m), hand payload, base payload (kg); NaN: none


COMMAND_WIDTH = 12  # numbers in a `command_row`


def command_row(command: Commands) -> np.ndarray:
    """`Commands` as COMMAND_WIDTH = 12 numbers (base velocity 3, yaw rate, ee velocity 3, ee force 3, base height,
    walking 1/0) (None as NaN), the inverse of `command_from_row`."""
    ee_velocity = np.full(3, np.nan) if command.ee_velocity_m_s is None else command.ee_velocity_m_s
    height = np.nan if command.base_height_m is None else command.base_height_m
    walking = np.nan if command.walking is None else float(command.walking)
    return np.r_[command.base_velocity_m_s, command.base_yaw_rate_rad_s, ee_velocity, command.ee_force_n, height,
                 walking]


def command_from_row(row: np.ndarray) -> Commands:
    ee_velocity = None if np.isnan(row[4:7]).all() else row[4:7].copy()
    return Commands(base_velocity_m_s=row[0:3].copy(), base_yaw_rate_rad_s=float(row[3]), ee_velocity_m_s=ee_velocity,
                    ee_force_n=row[7:10].copy(), base_height_m=None if np.isnan(row[10]) else float(row[10]),
                    walking=None if np.isnan(row[11]) else bool(row[11] > 0.5))



class Signal:
    """A wake-up from one process to another: a semaphore posted by `set`, taken by `is_set` / `wait`, which remember
    it until `clear`. Not `multiprocessing.Event`: its `set` takes a lock shared with the waiter and then waits until
    a sleeping waiter has woken (its Condition's notify), so the plant loop's request waited for the solver process
    to be scheduled (g1 under load: 42 of 461 requests over 1 ms, up to 5 ms, the plant's late ticks). A semaphore's
    post never waits. One process sets, the other takes: a post is one request or one answer."""

    def __init__(self, context):
        self._semaphore = context.Semaphore(0)
        self._taken = False  # this process took a post it has not cleared yet

    def set(self) -> None:
        self._semaphore.release()

    def is_set(self) -> bool:
        if not self._taken:
            self._taken = self._semaphore.acquire(False)
        return self._taken

    def wait(self, timeout_s: float | None = None) -> bool:
        """Block until set (at most `timeout_s`); whether it was."""
        if not self._taken:
            self._taken = self._semaphore.acquire(True, timeout_s)
        return self._taken

    def clear(self) -> None:
        self._taken = False


@dataclass(frozen=True)
class ChannelLayout:
    """Shapes of the request and of the plan: picklable, sent once to the solver process."""

    nq: int
    nv: int
    command_width: int
    arrays: tuple[tuple[str, tuple[int, ...]], ...]

    @classmethod
    def from_solution(cls, solution: Solution, command_width: int) -> "ChannelLayout":
        arrays = tuple((name, tuple(np.shape(getattr(solution, name)))) for name in SOLUTION_ARRAYS)
        return cls(solution.q.shape[1], solution.v.shape[1], command_width, arrays)

    def fields(self) -> list[tuple[str, tuple[int, ...]]]:
        """(name, shape) of every float64 view, in the block's order."""
        out = [("req_q", (self.nq,)), ("req_v", (self.nv,)), ("req_command", (self.command_width,)),
               ("req_scalars", (len(REQUEST_SCALARS),)), ("req_inertial", (INERTIAL_WIDTH,))]
        out += [(f"sol_{name}", shape) for name, shape in self.arrays]
        out += [("sol_scalars", (len(STATS_SCALARS),)), ("sol_details", (len(DETAIL_KEYS),)),
                ("sol_stamps", (len(SOLVER_STAMPS),))]
        return out

    @property
    def n_bytes(self) -> int:
        return 8 * sum(int(np.prod(shape)) for _, shape in self.fields()) + STATUS_BYTES + 8


class SharedChannel:
    """The block and its views; `create` in the simulation process, `attach` in the solver process."""

    def __init__(self, layout: ChannelLayout, memory: shared_memory.SharedMemory, events, owner: bool):
        self.layout, self.memory, self.owner = layout, memory, owner
        self.request_ready, self.answer_ready = events
        self.views: dict[str, np.ndarray] = {}
        offset = 0
        for name, shape in layout.fields():
            size = int(np.prod(shape))
            self.views[name] = np.ndarray(shape, dtype=np.float64, buffer=memory.buf, offset=offset)
            offset += 8 * size
        self._status = np.ndarray((STATUS_BYTES + 8,), dtype=np.uint8, buffer=memory.buf, offset=offset)
        self._next_request_s = math.nan  # solver side: when the last request said the next one is due

    @staticmethod
    def events(context) -> tuple:
        """(request ready, answer ready) `Signal`s: made before the solver process starts, which inherits them
        (semaphores cannot be sent through a pipe)."""
        return Signal(context), Signal(context)

    @classmethod
    def create(cls, layout: ChannelLayout, events) -> "SharedChannel":
        memory = shared_memory.SharedMemory(create=True, size=layout.n_bytes)
        return cls(layout, memory, events, owner=True)

    @classmethod
    def attach(cls, layout: ChannelLayout, name: str, events) -> "SharedChannel":
        # the simulation process owns (and unlinks) the block; this process only maps it. (Before Python 3.13
        # attaching registers the block with the resource tracker too: spawned processes share the parent's
        # tracker, where it is the same entry, removed by the owner's unlink.)
        try:
            memory = shared_memory.SharedMemory(name=name, track=False)
        except TypeError:
            memory = shared_memory.SharedMemory(name=name)
        return cls(layout, memory, events, owner=False)

    @property
    def handle(self) -> tuple:
        """What the solver process needs to attach, sent through the pipe once: (layout, block name)."""
        return self.layout, self.memory.name

    def close(self) -> None:
        self.views.clear()
        self._status = None
        self.memory.close()
        if self.owner:
            self.memory.unlink()

    # ------------------------------------------------------------------ simulation side
    def send_request(self, q, v, command_row: np.ndarray, t_s: float, delay_s: float, budget_s: float | None,
                     inertial: np.ndarray | None = None, next_request_s: float | None = None) -> None:
        """A request; `next_request_s`: when (time.perf_counter) the one after it is due if this one's answer is on
        time (the solver process then waits for it awake, `receive_request`), None: not known."""
        views = self.views
        views["req_inertial"][:] = np.nan if inertial is None else inertial
        views["req_q"][:] = q
        views["req_v"][:] = v
        views["req_command"][:] = command_row
        views["req_scalars"][:] = (t_s, delay_s, np.nan if budget_s is None else budget_s, 0.0,
                                   np.nan if next_request_s is None else next_request_s)
        self.answer_ready.clear()  # the last answer was taken (`SolverProcess.receive`) before this request
        self.request_ready.set()

    def send_stop(self) -> None:
        self.views["req_scalars"][3] = 1.0
        self.request_ready.set()

    def receive_solution(self) -> Solution:
        """The plan the solver process wrote (copied out: the next answer reuses the block)."""
        views = self.views
        arrays = {name: views[f"sol_{name}"].copy() for name, _ in self.layout.arrays}
        scalars = dict(zip(STATS_SCALARS, views["sol_scalars"].tolist()))
        details = {key: value for key, value in zip(DETAIL_KEYS, views["sol_details"].tolist()) if np.isfinite(value)}
        length = int(self._status[:8].view(np.int64)[0])
        status = bytes(self._status[8 : 8 + length]).decode("utf-8", "replace")
        stats = SolverStats(status=status, success=bool(scalars["success"]), iterations=int(scalars["iterations"]),
                            solve_time_s=scalars["solve_time_s"], max_constraint_violation=scalars["max_constraint_violation"],
                            cost=scalars["cost"], cpu_time_s=scalars["cpu_time_s"], details=details)
        solution = Solution(t_s=scalars["t_s"], node_times_s=arrays["node_times_s"], q=arrays["q"], v=arrays["v"],
                            a=arrays["a"], forces=arrays["forces"], tau=arrays["tau"], contact=arrays["contact"] > 0.5,
                            stats=stats, success=bool(scalars["success"]), x=None, q_joints=arrays["q_joints"],
                            held_previous=bool(scalars["held_previous"]), wall_time_s=scalars["wall_time_s"],
                            process_cpu_s=scalars["process_cpu_s"], stamps=views["sol_stamps"].copy())
        return solution

    # ------------------------------------------------------------------ solver side
    def receive_request(self) -> tuple | None:
        """Block until a request (awake around when the last one said the next is due: `send_request`); None when
        asked to stop. Returns (q, v, command row, t, delay_s, budget_s, inertial parameters or None)."""
        self._await_request()
        self.request_ready.wait()
        self.request_ready.clear()
        views = self.views
        t, delay_s, budget_s, stop, self._next_request_s = views["req_scalars"].tolist()
        if stop:
            return None
        inertial = views["req_inertial"].copy()
        return (views["req_q"].copy(), views["req_v"].copy(), views["req_command"].copy(), t, delay_s,
                None if np.isnan(budget_s) else budget_s, None if np.isnan(inertial).any() else inertial)

    def idle_s(self) -> float:
        """Solver side: how long until the next request is due (0 where the last request did not say or it is due)."""
        due = self._next_request_s
        return max(due - time.perf_counter(), 0.0) if math.isfinite(due) else 0.0

    def _await_request(self) -> None:
        """Asleep until SPIN_LEAD_S before the next request is due, then polling for it until SPIN_AFTER_S after (a
        late answer's next request comes at once); nothing where no time was given."""
        due = self._next_request_s
        if not math.isfinite(due):
            return
        start = due - SPIN_LEAD_S
        if time.perf_counter() < start and self.request_ready.wait(start - time.perf_counter()):
            return
        end = max(due, time.perf_counter()) + SPIN_AFTER_S
        while time.perf_counter() < end:
            if self.request_ready.is_set():
                return

    def send_solution(self, solution: Solution) -> None:
        views = self.views
        for name, shape in self.layout.arrays:
            value = np.asarray(getattr(solution, name), dtype=float)
            if value.shape != shape:  # a plan of another shape cannot be one of this MPC's: refuse loudly
                raise ValueError(f"real-time channel: {name} has shape {value.shape}, the layout {shape}")
            views[f"sol_{name}"][:] = value
        stats = solution.stats
        views["sol_scalars"][:] = (solution.t_s, float(solution.success), float(solution.held_previous),
                                   stats.iterations, stats.solve_time_s, stats.cpu_time_s,
                                   stats.max_constraint_violation, stats.cost, solution.wall_time_s,
                                   solution.process_cpu_s)
        details = stats.details or {}
        views["sol_details"][:] = [np.nan if details.get(key) is None else float(details[key]) for key in DETAIL_KEYS]
        encoded = str(stats.status).encode("utf-8")[:STATUS_BYTES]
        self._status[:8].view(np.int64)[0] = len(encoded)
        self._status[8 : 8 + len(encoded)] = np.frombuffer(encoded, dtype=np.uint8)
        stamps = views["sol_stamps"]
        stamps[:] = np.nan if solution.stamps is None else solution.stamps
        stamps[INDEX["answered"]] = time.perf_counter()  # the step's anatomy (control/step_anatomy.py)
        self.answer_ready.set()
