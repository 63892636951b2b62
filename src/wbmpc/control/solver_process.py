"""The MPC in its own process: what `wbmpc run --delay-mode realtime` and `wbmpc deploy` both solve with.

A process, not a thread: the 500 Hz loop beside it is Python and would starve a solver thread of the
GIL. `SolverProcess` starts `mpc_worker` (spawned, single-threaded BLAS, pinned to its own cores and
at raised priority where allowed), waits for its MPC build, and then moves requests (measured q, v,
the command, t, the expected delay for the delay compensation and the step's budget) and plans. The
first request and plan go through a pipe; from the first plan on, both go through a shared-memory
block woken by events (`realtime_channel.py`): no pickles, no polling.
"""

from __future__ import annotations

import os
import time

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
from wbmpc.errors import RunError, WbmpcError

REALTIME_NICE = -10  # asked for by both real-time processes; granted where the user may (root, CAP_SYS_NICE)
BUILD_TIMEOUT_S = 300.0


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


def cpu_split() -> tuple[set[int], set[int]]:
    """(loop CPUs, MPC CPUs): one core each where there are two or more, so neither starves the other;
    empty sets (no pinning) on a single core or where affinity is not supported."""
    try:
        available = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(), set()
    if len(available) < 2:
        return set(), set()
    return {available[0]}, set(available[1:])


class SolverProcess:
    """`request` a plan, `ready`/`wait` for it, `receive` it; `close` at the end (also on errors)."""

    def __init__(self, spec, mpc_config: MpcConfig, cpus: set[int] | None = None, stop=None,
                 build_timeout_s: float = BUILD_TIMEOUT_S):
        """Start the process and wait for its MPC build (Ctrl-C honoured through `stop()`): `interrupted`
        says whether `stop` ended the wait; a process that did not start is a RunError."""
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._events = SharedChannel.events(context)
        self.channel: SharedChannel | None = None
        self.cpu_start_s = 0.0  # the process's CPU time when the channel opened (its share is measured from there)
        self._process = context.Process(target=mpc_worker, args=(spec, mpc_config, child, cpus, self._events),
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
        if not self._conn.poll(0) or self._conn.recv() != "ready":
            self.close()
            raise RunError("the real-time MPC process did not start (see its error above)")

    def is_alive(self) -> bool:
        return self._process.is_alive()

    def request(self, q, v, command: Commands, t_s: float, delay_s: float = 0.0, budget_s: float | None = None,
                inertial=None) -> None:
        """A plan from (q, v) at MPC time t; `delay_s`: when it will apply (delay compensation), `budget_s`:
        the step's deadline for a solver that has one; `inertial`: an identified (base CoM offset x, y, z (m),
        hand payload, base payload (kg)) the plan uses (`MPC.set_inertial_parameters`), None: the last ones."""
        inertial = None if inertial is None else np.asarray(inertial, dtype=float).reshape(INERTIAL_WIDTH)
        if self.channel is None:
            self._conn.send((q, v, command, t_s, delay_s, budget_s, inertial))
        else:
            self.channel.send_request(q, v, command_row(command), t_s, delay_s, budget_s, inertial)

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


def mpc_worker(spec, mpc_config, conn, cpus: set[int] | None = None, events=None) -> None:
    """The solver process: build the MPC, then answer requests: through the pipe ("cpu" asks for the
    process's CPU time so far; (q, v, commands, t, delay_s, budget_s) a plan) until ("channel", layout,
    name) moves them to the shared-memory channel (`realtime_channel.py`, with `events`)."""
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
           inertial=None) -> Solution:
    if inertial is not None:
        mpc.set_inertial_parameters(inertial[:3], inertial[3], inertial[4])
    start = time.perf_counter()
    # the step's budget reaches a solver with a deadline (the anytime SQP) only when the MPC has none of its own
    budget = budget_s if mpc.config.step_budget_s is not None else None
    solution = mpc.solve(q, v, command, t_s, delay_s=delay_s, budget_s=budget)
    solution.wall_time_s = time.perf_counter() - start
    solution.process_cpu_s = time.process_time()
    return solution


def _serve_channel(mpc: MPC, channel: SharedChannel) -> None:
    """The solver process's loop on the shared-memory channel: wait for a request, solve, write the plan."""
    try:
        while True:
            request = channel.receive_request()
            if request is None:
                return
            q, v, row, t, delay_s, budget_s, inertial = request
            channel.send_solution(_solve(mpc, q, v, command_from_row(row), t, delay_s, budget_s, inertial))
    finally:
        channel.close()
