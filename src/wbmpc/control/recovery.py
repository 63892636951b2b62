"""A failed MPC step re-solved within a bounded effort (docs/design/push-recovery.md).

The ladder: for a hard step with soft rows, the same solver with their slacks free; then a fresh Fatrop
from a larger barrier parameter (it copes with degenerate problems right after pushes where the
warm-started small barrier stalls); then the fallback solver (IPOPT's regularised factorisation). Each
attempt is capped in iterations and no attempt starts once the step's solves have spent
`RecoveryConfig.budget_s` of CPU time, unless there is no plan to hold yet.
"""

from __future__ import annotations

from dataclasses import dataclass

from wbmpc.control.config import RecoveryConfig
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers.nlp import FATROP_SOLVERS, NlpSolver, SolverConfig

COLD_FALLBACK_ITERATIONS = 300  # the fallback's cap on a run's first step (no plan to hold while it solves)
# IPOPT as fallback: after a push a nearly converged plan (violation <= 1e-4) beats holding an old one
IPOPT_FALLBACK_OPTIONS = {"acceptable_iter": 2, "acceptable_tol": 1e-3, "acceptable_constr_viol_tol": 1e-4}


@dataclass
class Rescue:
    """The outcome of `Recovery.recover`: the last attempt's result (its stats summed over the attempts) and
    whether the soft rows' re-solve succeeded (the step then enters push recovery mode)."""

    result: object
    soft_rows_succeeded: bool = False


class Recovery:
    """The recovery solvers of one MPC (built on first need, or by `prepare`) and the ladder over them."""

    def __init__(self, problem: OcpProblem, solver: NlpSolver, config: RecoveryConfig):
        self.problem = problem
        self.solver = solver
        self.config = config
        self._fallback: NlpSolver | None = None
        self._fallback_cold: NlpSolver | None = None
        self._fatrop: NlpSolver | None = None
        self.fallback_until_t_s: float | None = None  # the fallback solver is tried first until this time

    def reset(self) -> None:
        self.fallback_until_t_s = None

    def fallback_first(self, t_s: float) -> bool:
        """Whether the step at `t_s` goes to the fallback solver first (`fallback_first_s` after its last rescue)."""
        return self.fallback_until_t_s is not None and t_s < self.fallback_until_t_s and bool(self.config.fallback_solver)

    def prepare(self) -> None:
        """Build the recovery solvers now (they are otherwise built at the first failed step, which then
        takes the build time: campaigns and real-time use want them before the clock runs)."""
        if self.config.fallback_solver:
            self.fallback_solver()
        if self.config.barrier_init and self.solver.config.name in FATROP_SOLVERS:
            self.recovery_fatrop()
        prepare_recovery = getattr(self.solver, "prepare_recovery", None)  # RTI: its Fatrop re-solve
        if prepare_recovery is not None:
            prepare_recovery()

    def built(self) -> dict[str, NlpSolver]:
        """The recovery solvers built so far, by role: "fallback", "fallback_cold" (a run's first step), "fatrop"."""
        solvers = {"fallback": self._fallback, "fallback_cold": self._fallback_cold, "fatrop": self._fatrop}
        return {role: solver for role, solver in solvers.items() if solver is not None}

    def fallback_solver(self, cold: bool = False) -> NlpSolver:
        """The fallback solver, compiled like the main one. `cold`: for a step with no plan to hold yet (the
        first of a run), whose recovery may take up to COLD_FALLBACK_ITERATIONS: nothing runs on the robot
        before it succeeds."""
        if (self._fallback_cold if cold else self._fallback) is None:
            cfg = self.config
            solver = NlpSolver(self.problem, SolverConfig(
                name=cfg.fallback_solver,
                max_iterations=max(cfg.fallback_max_iterations, COLD_FALLBACK_ITERATIONS) if cold else cfg.fallback_max_iterations,
                time_limit_s=None if cold else cfg.budget_s, compiled=self.solver.is_compiled,
                codegen=self.solver.config.codegen,
                extra_options={"ipopt": dict(IPOPT_FALLBACK_OPTIONS)} if cfg.fallback_solver == "ipopt" else {}))
            if cold:
                self._fallback_cold = solver
            else:
                self._fallback = solver
        return self._fallback_cold if cold else self._fallback

    def recovery_fatrop(self) -> NlpSolver:
        """A Fatrop starting from a larger barrier, built once (it keeps one nlpsol per row-count pattern,
        so its options hold: no new solver per failure)."""
        if self._fatrop is None:
            cfg = self.config
            self._fatrop = self.solver.recreated(barrier_init=cfg.barrier_init, max_iterations=cfg.fatrop_max_iterations,
                                                 warm_barrier_init=None)
        return self._fatrop

    def recover(self, failed, p, bounds, x0, t_s: float, has_plan: bool, fallback_tried: bool = False,
                soft_bounds=None) -> Rescue:
        """Re-solve the failed step at `t_s` (module docstring). `has_plan`: a last good plan exists to hold (the
        budget applies); `fallback_tried`: the fallback solver already failed this step; `soft_bounds`: the
        step's bounds with the soft rows' slacks free (a hard step with soft rows). A rescue by the fallback
        makes it the first choice for `fallback_first_s`."""
        cfg = self.config
        result, attempts, soft_succeeded = failed, [failed.stats.status], False
        spent_s, iterations = failed.stats.cpu_time_s, failed.stats.iterations
        wall_s = failed.stats.solve_time_s

        def budget_left() -> bool:
            return cfg.budget_s is None or not has_plan or spent_s < cfg.budget_s

        def attempt(solver, bounds_now, label: str):
            nonlocal spent_s, iterations, wall_s
            outcome = solver.solve(p, *bounds_now, x0)
            spent_s, iterations = spent_s + outcome.stats.cpu_time_s, iterations + outcome.stats.iterations
            wall_s += outcome.stats.solve_time_s
            attempts.append(f"{label}: {outcome.stats.status}")
            return outcome

        if soft_bounds is not None and budget_left():
            bounds = soft_bounds
            result = attempt(self.fallback_solver() if fallback_tried else self.solver, bounds, "soft rows")
            soft_succeeded = bool(result.stats.success)
        if not result.stats.success and cfg.barrier_init and self.solver.config.name in FATROP_SOLVERS and budget_left():
            result = attempt(self.recovery_fatrop(), bounds, f"fatrop mu_init {cfg.barrier_init:g}")
        if not result.stats.success and cfg.fallback_solver and not fallback_tried and budget_left():
            result = attempt(self.fallback_solver(cold=not has_plan), bounds, cfg.fallback_solver)
            if result.stats.success and cfg.fallback_first_s > 0:
                self.fallback_until_t_s = t_s + cfg.fallback_first_s
        if len(attempts) > 1:
            result.stats.status = f"{attempts[-1]} (recovery after {'; '.join(attempts[:-1])})"
        result.stats.solve_time_s, result.stats.cpu_time_s, result.stats.iterations = wall_s, spent_s, iterations
        return Rescue(result, soft_succeeded)
