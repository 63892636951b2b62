"""The MPC in its own process: what `wbmpc run --delay-mode realtime` and `wbmpc deploy` both solve with.

A process, not a thread: the 500 Hz loop beside it is Python and would starve a solver thread of the
GIL. `SolverProcess` starts `mpc_worker` (spawned, single-threaded BLAS, on the cores `cpu_plan` gives it and
at raised priority where allowed), waits for its MPC build, and then moves requests (measured q, v,
the command, t, the expected delay for the delay compensation and the step's budget) and plans. The
first request and plan go through a pipe; from the first plan on, both go through a shared-memory
block woken by events (`realtime_channel.py`): no pickles, no polling.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from dataclasses import dataclass

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.control.config import MpcConfig
from wbmpc.control.mpc import MPC
from wbmpc.control.realtime_channel import (
    INERTIAL_WIDTH,
    ChannelLayout,
    SharedChannel,
    command_from_row,
    command_row,
)
from wbmpc.control.solution import Solution
from wbmpc.control.step_anatomy import PROCESS_STAMPS, SOLVER_STAMPS
from wbmpc.errors import RunError, WbmpcError

REALTIME_NICE = -10  # asked for by both real-time processes; granted where the user may (root, CAP_SYS_NICE)
# the plant loop's real-time priority (SCHED_FIFO, low: below kernel threads and audio) where permitted. It sleeps
# between physics steps, so it takes only what it uses
LOOP_FIFO_PRIORITY = 10
# the solver's helper threads on the plant loop's core: SCHED_FIFO at the loop's own priority where permitted. Between
# equal FIFO priorities neither preempts the other: the loop's tick waits for the helper's tasks in hand (~0.1-0.4 ms
# on g1) and the helper for the loop's tick. Below the loop (nice 0) the loop preempted a helper in the middle of a
# stage's evaluation and the solver's main thread, which waits for every task taken, stalled until the loop slept
# (g1 walk-in-place: 0.5-0.6 ms a solve); other sessions' processes on that core did the same (run-queue wait of
# the helper 2.3-2.9 ms a solve at load 2.5)
HELPER_FIFO_PRIORITY = LOOP_FIFO_PRIORITY
HELPER_NICE = 0  # the helpers' priority where FIFO is refused: ordinary, below the loop's
# the solver process's main thread on its own core: SCHED_FIFO where permitted (below the loop, whose core it never
# shares). At nice -10 other sessions' processes still took turns on its core mid-solve (run-queue wait 0.4-0.8 ms a
# solve at load 2.5, and what they left in its caches); it sleeps between requests, so the others keep that time
SOLVER_FIFO_PRIORITY = LOOP_FIFO_PRIORITY - 1
BUILD_TIMEOUT_S = 300.0
# the garbage collector's young generations run after an answer where the next request is due later than this
GC_MIN_IDLE_S = 0.6e-3


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


def raise_loop_priority(fifo_priority: int = LOOP_FIFO_PRIORITY, nice: int = REALTIME_NICE) -> str:
    """The plant loop's priority: SCHED_FIFO `fifo_priority` where permitted (root, CAP_SYS_NICE, RLIMIT_RTPRIO;
    children started afterwards get the ordinary policy back: SCHED_RESET_ON_FORK), else `raise_priority(nice)`.
    Returns what was granted: "fifo 10", "nice -10" or "default"; `restore_scheduling` undoes it."""
    if hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_FIFO"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0),
                                  os.sched_param(fifo_priority))
            return f"fifo {fifo_priority}"
        except OSError:
            pass
    return raise_priority(nice)


AUTOGROUP_FILE = "/proc/self/autogroup"


def raise_session_priority(nice: int = REALTIME_NICE, path: str = AUTOGROUP_FILE) -> int | None:
    """This session's scheduling group at `nice` where Linux groups processes by session (autogroups,
    /proc/sys/kernel/sched_autogroup_enabled). There a process's nice weighs only against its own session's
    processes and each session's group gets an equal share of a core, so the solver process's nice -10 did not help
    against other sessions' load: at load 5 on 2 cores it got ~40 % of its core while solving (28 ms a solve for
    ~9 ms of CPU) and g1's session fell. The group holds the loop, the solver process and the rest of the session
    (its shell). Returns the group's nice before (`restore_session_priority`), None where there are no autogroups
    or raising is not permitted."""
    before = session_group_nice(path)
    if before is None:
        return None
    try:
        if before > nice:
            with open(path, "w") as f:
                f.write(str(nice))
        return before
    except OSError:
        return None


def session_group_nice(path: str = AUTOGROUP_FILE) -> int | None:
    """The nice of this session's scheduling group (Linux autogroups), None where there is none: no file, or an
    empty one (kernels and containers with autogroups disabled give an empty /proc/self/autogroup)."""
    try:
        with open(path) as f:
            return int(f.read().split()[-1])
    except (OSError, ValueError, IndexError):
        return None


def restore_session_priority(before: int | None, path: str = AUTOGROUP_FILE) -> None:
    """The session's group back at its nice of before `raise_session_priority` (None: nothing was changed)."""
    if before is None:
        return
    try:
        with open(path, "w") as f:
            f.write(str(before))
    except OSError:
        pass


def restore_scheduling(granted: str, nice: int | None) -> None:
    """Back to the ordinary policy and the caller's `nice` after `raise_loop_priority` granted `granted`."""
    try:
        if granted.startswith("fifo"):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        if granted != "default" and nice is not None:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
    except OSError:
        pass


@dataclass(frozen=True)
class CpuPlan:
    """Where a real-time run's threads run (empty sets: not pinned). `loop`: the plant loop (500 Hz joint loop and
    physics); `solver`: the solver process's main thread (the Riccati recursion, Python); `helpers`: the solver's
    helper threads (the stage evaluations' pool, `fatrop_settings.default_threads`). On two CPUs the helpers share the
    loop's core at a lower priority than the loop (`shares_loop_core`): the loop takes ~a fifth of its core, the
    evaluations take its idle time and the loop preempts them."""

    loop: frozenset[int] = frozenset()
    solver: frozenset[int] = frozenset()
    helpers: frozenset[int] = frozenset()

    @property
    def shares_loop_core(self) -> bool:
        return bool(self.helpers & self.loop)

    @property
    def solver_process(self) -> frozenset[int]:
        """The solver process's CPUs while it builds (its pool sized from them)."""
        return self.solver | self.helpers


def available_cpus() -> list[int]:
    """The CPUs this thread may run on (empty where affinity is not supported)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return []


def cpu_plan(cpus=None, share_loop_core: bool = True) -> CpuPlan:
    """The real-time run's `CpuPlan` on `cpus` (default: this thread's): no pinning on a single CPU; one core for the
    plant loop and the others for the solver, its helper threads on the solver's cores where it has two or more, else
    (two CPUs) on the loop's core when `share_loop_core` (the loop then needs a higher priority than the helpers)."""
    cpus = sorted(available_cpus() if cpus is None else cpus)
    if len(cpus) < 2:
        return CpuPlan()
    loop, solver = frozenset(cpus[:1]), frozenset(cpus[1:])
    return CpuPlan(loop, solver, loop if share_loop_core and len(solver) < 2 else solver)


def cpu_split() -> tuple[set[int], set[int]]:
    """(loop CPUs, MPC CPUs): one core each where there are two or more, so neither starves the other;
    empty sets (no pinning) on a single core or where affinity is not supported."""
    plan = cpu_plan(share_loop_core=False)
    return set(plan.loop), set(plan.solver)


def thread_ids() -> list[int]:
    """The kernel thread ids of this process (Linux; [] elsewhere)."""
    try:
        return sorted(int(name) for name in os.listdir("/proc/self/task"))
    except OSError:
        return []


def place_helper_threads(plan: CpuPlan, main_thread: int) -> int:
    """Pin this process's threads other than `main_thread` (the stage pool's workers, started by the solver's build)
    to `plan.helpers`; where they share the loop's core, at the loop's FIFO priority (`HELPER_FIFO_PRIORITY`) or,
    where that is refused, below the loop (`HELPER_NICE`). Returns how many; `helper_priority` says what they got."""
    placed = 0
    for tid in thread_ids():
        if tid == main_thread:
            continue
        try:
            if plan.helpers:
                os.sched_setaffinity(tid, plan.helpers)
            if plan.shares_loop_core and not _set_fifo(tid, HELPER_FIFO_PRIORITY):
                os.setpriority(os.PRIO_PROCESS, tid, max(HELPER_NICE, os.getpriority(os.PRIO_PROCESS, tid)))
            placed += 1
        except OSError:  # the thread ended meanwhile, or affinity/priority not permitted
            continue
    return placed


def _set_fifo(tid: int, priority: int) -> bool:
    """Thread `tid` (0: this one) at SCHED_FIFO `priority` (its children start at the ordinary policy); whether that
    was permitted."""
    if not (hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_FIFO")):
        return False
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(priority))
        return True
    except OSError:
        return False


def fifo_competitors(proc: str = "/proc") -> list[int]:
    """Other user processes with a thread at a real-time policy (SCHED_FIFO / SCHED_RR; kernel threads, which have no
    command line, left out): another real-time run shares the cores and the kernel's cap on FIFO time
    (`sched_rt_runtime_us` per `sched_rt_period_us`), past which every FIFO thread of a core waits up to 50 ms.
    Linux only ([] elsewhere)."""
    found = []
    try:
        pids = [int(name) for name in os.listdir(proc) if name.isdigit()]
    except OSError:
        return []
    for pid in pids:
        if pid == os.getpid():
            continue
        try:
            with open(f"{proc}/{pid}/cmdline", "rb") as f:
                if not f.read(1):
                    continue
            for tid in os.listdir(f"{proc}/{pid}/task"):
                with open(f"{proc}/{pid}/task/{tid}/stat") as f:
                    policy = int(f.read().rsplit(")", 1)[1].split()[38])
                if policy in (1, 2):  # SCHED_FIFO, SCHED_RR
                    found.append(pid)
                    break
        except (OSError, ValueError, IndexError):
            continue
    return sorted(found)


def thread_priority(tid: int = 0) -> str:
    """What the kernel says thread `tid` (0: this one) runs at: "fifo N" or "nice N" ("default" where it cannot
    tell)."""
    try:
        policy = os.sched_getscheduler(tid) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        if hasattr(os, "SCHED_FIFO") and policy == os.SCHED_FIFO:
            return f"fifo {os.sched_getparam(tid).sched_priority}"
        return f"nice {os.getpriority(os.PRIO_PROCESS, tid)}"
    except (AttributeError, OSError):
        return "default"


def raise_solver_thread(plan: CpuPlan) -> str:
    """The solver process's main thread, pinned to `plan.solver`: at SCHED_FIFO `SOLVER_FIFO_PRIORITY` where the plan
    gives it a core of its own beside a FIFO loop (`shares_loop_core`: its helpers are on the loop's core), else at
    what it has (nice -10 where permitted). Returns what it runs at (`thread_priority`)."""
    if plan.shares_loop_core and not plan.solver & plan.helpers:
        _set_fifo(0, SOLVER_FIFO_PRIORITY)
    return thread_priority(0)


def helper_priority(main_thread: int) -> str | None:
    """What this process's threads other than `main_thread` run at (the first one's), None: there are none."""
    others = [tid for tid in thread_ids() if tid != main_thread]
    return thread_priority(others[0]) if others else None


class SolverProcess:
    """`request` a plan, `ready`/`wait` for it, `receive` it; `close` at the end (also on errors)."""

    def __init__(self, spec, mpc_config: MpcConfig, cpus: CpuPlan | set[int] | None = None, stop=None,
                 build_timeout_s: float = BUILD_TIMEOUT_S):
        """Start the process and wait for its MPC build (Ctrl-C honoured through `stop()`): `interrupted`
        says whether `stop` ended the wait; a process that did not start is a RunError. `cpus`: a `CpuPlan`, or
        the CPUs of all its threads."""
        import multiprocessing

        if cpus is not None and not isinstance(cpus, CpuPlan):
            cpus = CpuPlan(solver=frozenset(cpus), helpers=frozenset(cpus))
        self.cpus = cpus or CpuPlan()
        self.helper_threads = 0  # the solver's helper threads placed by `cpus` (told by the process when built)
        self.scheduling: dict = {}

        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._events = SharedChannel.events(context)
        self.channel: SharedChannel | None = None
        self.cpu_start_s = 0.0  # the process's CPU time when the channel opened (its share is measured from there)
        self._process = context.Process(target=mpc_worker, args=(spec, mpc_config, child, self.cpus, self._events),
                                        daemon=True)
        single_threaded = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
        saved = {name: os.environ.get(name) for name in single_threaded}
        os.environ.update(single_threaded)  # the process inherits it: no BLAS threads competing with the solver
        try:
            self._process.start()
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
        self.interrupted = False
        deadline = time.monotonic() + build_timeout_s
        while time.monotonic() < deadline:
            if self._conn.poll(0.2) or not self._process.is_alive():
                break
            if stop is not None and stop():
                self.interrupted = True
                return
        answer = self._conn.recv() if self._conn.poll(0) else None
        if not (isinstance(answer, tuple) and answer[0] == "ready"):
            self.close()
            raise RunError("the real-time MPC process did not start (see its error above)")
        self.helper_threads = answer[1]
        self.scheduling = answer[2]  # what its threads were granted: solver_priority, helper_priority ("fifo 9", ...)

    def is_alive(self) -> bool:
        return self._process.is_alive()

    def request(self, q, v, command: Commands, t_s: float, delay_s: float = 0.0, budget_s: float | None = None,
                inertial=None, next_request_s: float | None = None) -> None:
        """A plan from (q, v) at MPC time t; `delay_s`: when it will apply (delay compensation), `budget_s`:
        the step's deadline for a solver that has one; `inertial`: an identified (base CoM offset x, y, z (m),
        hand payload, base payload (kg)) the plan uses (`MPC.set_inertial_parameters`), None: the last ones;
        `next_request_s`: when (time.perf_counter) the next request is due if this answer is on time (the solver
        process waits for it awake: `realtime_channel.SPIN_LEAD_S`)."""
        inertial = None if inertial is None else np.asarray(inertial, dtype=float).reshape(INERTIAL_WIDTH)
        if self.channel is None:
            self._conn.send((q, v, command, t_s, delay_s, budget_s, inertial))
        else:
            self.channel.send_request(q, v, command_row(command), t_s, delay_s, budget_s, inertial, next_request_s)

    def ready(self) -> bool:
        return self.channel.answer_ready.is_set() if self.channel is not None else self._conn.poll()

    def wait(self, timeout_s: float) -> bool:
        """Block until the plan is ready or `timeout_s` passed."""
        return self.channel.answer_ready.wait(timeout_s) if self.channel is not None else self._conn.poll(timeout_s)

    def receive(self) -> Solution:
        """The requested plan (blocks until it is ready). The first one also opens the shared-memory
        channel, laid out from it, for every later request."""
        if self.channel is not None:
            self.channel.answer_ready.wait()
            solution = self.channel.receive_solution()
            self.channel.answer_ready.clear()
            return solution
        solution = self._conn.recv()
        if isinstance(solution, BaseException):  # the first solve refused (its message says why)
            raise solution
        self._conn.send("cpu")
        self.cpu_start_s = self._conn.recv()
        self.channel = SharedChannel.create(ChannelLayout.from_solution(solution, len(command_row(Commands()))),
                                            self._events)
        self._conn.send(("channel", *self.channel.handle))
        return solution

    def close(self) -> None:
        try:
            if self.channel is not None:
                self.channel.send_stop()
            else:
                self._conn.send(None)
        except (BrokenPipeError, OSError):
            pass
        self._process.join(timeout=5)
        if self._process.is_alive():
            self._process.terminate()
        if self.channel is not None:
            self.channel.close()


def mpc_worker(spec, mpc_config, conn, cpus: CpuPlan | None = None, events=None) -> None:
    """The solver process: build the MPC on the CPUs of `cpus` (its stage pool sized from them), move its threads to
    their places and priorities (`place_helper_threads`, `raise_solver_thread`), then answer requests: through the pipe ("cpu" asks for the
    process's CPU time so far; (q, v, commands, t, delay_s, budget_s) a plan) until ("channel", layout,
    name) moves them to the shared-memory channel (`realtime_channel.py`, with `events`)."""
    import signal

    from wbmpc.robots import RobotModel

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent decides
    cpus = cpus or CpuPlan()
    if cpus.solver_process:
        os.sched_setaffinity(0, cpus.solver_process)
    raise_priority()
    mpc = MPC(RobotModel(spec), mpc_config)
    mpc.prepare_fallback()  # a failed step must not pay for building its recovery solvers
    # the build's objects out of the garbage collector's reach: a full collection walked them all mid-run (g1: 14-100
    # ms in one step); the steps' own short-lived objects are still collected
    gc.collect()
    gc.freeze()
    helpers, scheduling = 0, {}
    if cpus.solver:
        main_thread = threading.get_native_id()
        os.sched_setaffinity(0, cpus.solver)
        helpers = place_helper_threads(cpus, main_thread)
        scheduling = {"solver_priority": raise_solver_thread(cpus), "helper_priority": helper_priority(main_thread)}
    conn.send(("ready", helpers, scheduling))
    while True:
        message = conn.recv()
        if message is None:
            return
        if isinstance(message, str) and message == "cpu":
            conn.send(time.process_time())
            continue
        if isinstance(message[0], str) and message[0] == "channel":
            _serve_channel(mpc, SharedChannel.attach(message[1], message[2], events))
            return
        q, v, command, t, delay_s, budget_s, inertial = message
        try:
            conn.send(_solve(mpc, q, v, command, t, delay_s, budget_s, inertial))
        except WbmpcError as exc:  # e.g. a budget below one QP: the parent raises it with its message
            conn.send(exc)
            return


def _solve(mpc: MPC, q, v, command: Commands, t_s: float, delay_s: float, budget_s: float | None,
           inertial=None, received_s: float = np.nan) -> Solution:
    """One plan; its `stamps` (control/step_anatomy.SOLVER_STAMPS) from `received_s` (the request read) and the
    MPC's own (`MPC.step_stamps`); the channel adds `answered`."""
    if inertial is not None:
        mpc.set_inertial_parameters(inertial[:3], inertial[3], inertial[4])
    start = time.perf_counter()
    # the step's budget reaches a solver with a deadline (the anytime SQP) only when the MPC has none of its own
    budget = budget_s if mpc.config.step_budget_s is not None else None
    solution = mpc.solve(q, v, command, t_s, delay_s=delay_s, budget_s=budget)
    solution.wall_time_s = time.perf_counter() - start
    solution.process_cpu_s = time.process_time()
    stamps = getattr(mpc, "step_stamps", None)
    solution.stamps = np.full(len(SOLVER_STAMPS), np.nan)
    solution.stamps[0] = received_s
    if stamps is not None:
        solution.stamps[len(PROCESS_STAMPS):] = stamps.values
    return solution


def _serve_channel(mpc: MPC, channel: SharedChannel) -> None:
    """The solver process's loop on the shared-memory channel: wait for a request, solve, write the plan."""
    row_before, command = None, None
    try:
        while True:
            request = channel.receive_request()
            received = time.perf_counter()
            if request is None:
                return
            q, v, row, t, delay_s, budget_s, inertial = request
            if row_before is None or not np.array_equal(row, row_before, equal_nan=True):  # (commands change rarely)
                row_before, command = row, command_from_row(row)
            channel.send_solution(_solve(mpc, q, v, command, t, delay_s, budget_s, inertial, received))
            if channel.idle_s() > GC_MIN_IDLE_S:  # time to spare before the next request
                gc.collect(1)  # the steps' garbage now rather than in the middle of a step (gen. 1: 0.5-0.9 ms)
    finally:
        channel.close()
