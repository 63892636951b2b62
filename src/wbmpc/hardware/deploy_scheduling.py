"""Where `wbmpc deploy`'s controller loop and its solver process run: the CPU plan of the simulated real-time loop.

The same plan as `wbmpc run --delay-mode realtime` (`control/solver_process.CpuPlan`): the controller loop (the
thread answering every LowState) at SCHED_FIFO where permitted, pinned to one core; the solver process on the
other (its main thread at SCHED_FIFO there where permitted), its helper threads (the stage evaluations' pool) on
the loop's core at the loop's FIFO priority (neither preempts the other's work mid-task:
`solver_process.HELPER_FIFO_PRIORITY`), below the loop where that is refused; the run's session group at nice -10
where Linux groups processes by session (`raise_session_priority`). Where FIFO is refused the loop asks for nice -10 and the old one-core-each split stays (at nice -10 against
0 the helpers delayed g1's simulated loop by up to 100 ms); where neither is permitted, the default priority. The
deploy report says what was granted (`summary`). Lock-step deploys solve in the loop's own thread: nothing is
changed for them.
"""

from __future__ import annotations

import os

from wbmpc.control.solver_process import (
    REALTIME_NICE,
    CpuPlan,
    SolverProcess,
    available_cpus,
    cpu_plan,
    raise_loop_priority,
    raise_session_priority,
    restore_scheduling,
    restore_session_priority,
)


class DeployScheduling:
    """`raise_loop()` from the controller's thread before the solver process starts, `solver_process(robot,
    mpc_config)` to start it with the plan, `pin_loop()` once it runs, `restore()` at the end (whatever ended it)."""

    def __init__(self, realtime: bool = True):
        self.realtime = realtime
        self.priority: str | None = None  # "fifo 10", "nice -10", "default"; None: not raised (lock-step, not yet)
        self.plan = CpuPlan()
        self.helper_threads = 0
        self.solver_scheduling: dict = {}  # the solver's threads' priorities (`SolverProcess.scheduling`)
        self.session_nice: int | None = None  # the session group's nice while raised (Linux autogroups), None: none
        self._own_cpus: list[int] = []
        self._own_nice: int | None = None
        self._session_before: int | None = None  # the session group's nice before (Linux autogroups)
        self._pinned = False

    def raise_loop(self) -> None:
        """This thread (the controller loop) at the loop's priority, and the plan that follows from what was granted."""
        if not self.realtime or self.priority is not None:
            return
        self._own_cpus = available_cpus()
        self._own_nice = os.getpriority(os.PRIO_PROCESS, 0) if hasattr(os, "getpriority") else None
        self.priority = raise_loop_priority()
        self._session_before = raise_session_priority()
        self.session_nice = None if self._session_before is None else min(self._session_before, REALTIME_NICE)
        self.plan = cpu_plan(self._own_cpus, share_loop_core=self.priority.startswith("fifo"))

    def solver_process(self, robot, mpc_config) -> SolverProcess:
        """The solver process on the plan's cores (its helper threads placed by it)."""
        worker = SolverProcess(robot.spec, mpc_config, self.plan)
        self.helper_threads, self.solver_scheduling = worker.helper_threads, worker.scheduling
        return worker

    def pin_loop(self) -> None:
        """This thread on the plan's loop core (after the solver process's build, which the plan gives its own)."""
        if self.plan.loop:
            os.sched_setaffinity(0, self.plan.loop)
            self._pinned = True

    def restore(self) -> None:
        """Back to the caller's CPUs, policy and priority."""
        if self._pinned:
            os.sched_setaffinity(0, self._own_cpus)
            self._pinned = False
        if self.priority is not None:
            restore_scheduling(self.priority, self._own_nice)
            restore_session_priority(self._session_before)
            self._session_before = None

    def summary(self) -> dict | None:
        """The report's `scheduling`: priority granted and the CPUs of the loop, the solver and its helpers."""
        if self.priority is None:
            return None
        plan = self.plan
        cpus = {"loop": sorted(plan.loop), "solver": sorted(plan.solver), "helpers": sorted(plan.helpers),
                "helper_threads": int(self.helper_threads), **self.solver_scheduling}
        return {"realtime_priority": self.priority, "session_nice": self.session_nice, "cpu_plan": cpus}
