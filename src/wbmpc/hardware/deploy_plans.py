"""The MPC's plans in the deploy loop: when a step is due, who solves it, and the plan in use.

Lock-step: each step is solved in the controller's process before that tick's LowCmd goes out. Real time: the
step is requested from the solver process (`control/solver_process.py`) and taken when it is ready, while the
loop keeps answering LowState with the plan in use; the delay a plan meets (request to receipt) is measured
for the next request's compensation, and its transport (the delay less the solver's own time) sets the next
request's budget as in the simulated real-time loop: the period less the transport, so that a solver with a
deadline answers before the next step is due. Steps are due every MPC period (`DeployConfig.mpc_rate_hz`).
"""

from __future__ import annotations

import time

from wbmpc.control.loop import REALTIME_MARGIN_S, REALTIME_TRANSPORT_GUESS_S
from wbmpc.hardware.deploy_report import DeployReport


class DeployPlans:
    """The plan in use (`active`) and the MPC steps that replace it, lock-step (`mpc`) or real time (`worker`)."""

    def __init__(self, mpc, worker, period_s: float, report: DeployReport, inertial=None):
        """`inertial()`: the identified inertial parameters each real-time request carries (None: none)."""
        self.mpc, self.worker, self.period_s, self.report = mpc, worker, period_s, report
        self.inertial = inertial
        self.active = None  # the plan in use
        self.next_s = 0.0  # MPC time of the next step
        self._busy = False  # a request is out to the solver process
        self._delay_s = 0.0  # running mean of the delay a plan meets (request to receipt)
        self._transport_s = REALTIME_TRANSPORT_GUESS_S  # running mean of that delay less the solver's wall time
        self._requested_at = 0.0

    def first(self, q, v, commands) -> tuple[object | None, float]:
        """The first plan (MPC time 0), asked for while the robot holds its pose and no plan is in use: (the
        solution when one came this tick, else None; this tick's solve time in ms, lock-step only)."""
        if self.worker is None:
            return self._solve(q, v, commands(0.0, q, v), 0.0)
        if not self._busy:
            self._request(q, v, commands(0.0, q, v), 0.0, 0.0, budget_s=None)  # a cold solve: it converges
        return (self._receive() if self.worker.ready() else None), 0.0

    def start(self) -> None:
        """The MPC phase starts (MPC time 0 = now): the next step is one period later."""
        self.next_s = self.period_s

    def step(self, t_mpc: float, q, v, commands) -> float:
        """The MPC step due at `t_mpc`, if any (lock-step: solved now; real time: the last answer taken, a new
        request sent); returns this tick's solve time in ms (lock-step only)."""
        solve_ms = 0.0
        if self.worker is None:
            if t_mpc >= self.next_s - 1e-9:
                solution, solve_ms = self._solve(q, v, commands(t_mpc, q, v), t_mpc)
                if solution.success:
                    self.active = solution
                self._advance(t_mpc)
            return solve_ms
        if self._busy and self.worker.ready():
            solution = self._receive()
            # the delay a plan meets (request to receipt), for the next request's compensation and budget
            delay_s = time.perf_counter() - self._requested_at
            self._delay_s = 0.8 * self._delay_s + 0.2 * delay_s
            self._transport_s = 0.8 * self._transport_s + 0.2 * max(delay_s - solution.wall_time_s, 0.0)
            if solution.success or solution.held_previous:
                self.active = solution
        if not self._busy and t_mpc >= self.next_s - 1e-9:
            self._request(q, v, commands(t_mpc, q, v), t_mpc, self._delay_s, self.budget_s)
            self._advance(t_mpc)
        return solve_ms

    @property
    def budget_s(self) -> float:
        """The next real-time request's budget: the period less the measured transport and a margin for its jitter
        (reaches solvers with a deadline where the MPC config sets a step budget, `solver_process._solve`)."""
        return max(self.period_s - self._transport_s - REALTIME_MARGIN_S, REALTIME_MARGIN_S)

    def _advance(self, t_mpc: float) -> None:
        while self.next_s <= t_mpc + 1e-9:
            self.next_s += self.period_s

    def _solve(self, q, v, command, t_mpc: float):
        tic = time.perf_counter()
        solution = self.mpc.solve(q, v, command, t_mpc)
        solve_ms = 1e3 * (time.perf_counter() - tic)
        self._count(solution, solve_ms)
        return solution, solve_ms

    def _request(self, q, v, command, t_mpc: float, delay_s: float, budget_s: float | None) -> None:
        inertial = self.inertial() if self.inertial is not None else None
        extra = {} if inertial is None else {"inertial": inertial}
        self.worker.request(q, v, command, t_mpc, delay_s, budget_s=budget_s, **extra)
        self._requested_at = time.perf_counter()
        self._busy = True

    def _receive(self):
        solution = self.worker.receive()
        self._busy = False
        self._count(solution, 1e3 * solution.wall_time_s)
        return solution

    def _count(self, solution, solve_ms: float) -> None:
        self.report.mpc_solves += 1
        self.report.solve_ms.add(solve_ms)
        if not solution.success:
            self.report.mpc_failures += 1
