"""Anytime SQP (`--solver sqp`): as many SQP iterations as fit before the step's deadline.

Each iteration is the RTI's (`solvers/rti.py`): the OCP (eq. 1) linearised at the iterate, the
Gauss-Newton QP on HPIPM's structured interior point (`solvers/qp.py`). Unlike the RTI's full step,
the step is globalised by a backtracking line search on the l1 merit function

    phi(x) = f(x) + nu * (sum of the bound violations of g(x) and x),   nu >= 1.1 max |lambda|,

(Armijo condition on phi's directional derivative along the QP step, grad f' d - nu viol(x)). The
iterations stop when the KKT residuals are below the tolerances (primal: largest bound violation;
dual: |grad f + J' lam_g + lam_x|_inf with the last QP's multipliers, relative to max(1, |grad f|)),
when the step is negligible, or when the next iteration would not end before the deadline
(predicted from the iterations measured so far). The result is the iterate with the lowest merit
(the last one, since every accepted step lowers it), with its status and KKT residuals in
`stats.details` (primal of the returned iterate; dual of the last iterate linearised, which is the
returned one when it converged or with `kkt_at_exit`); the MPC warm-starts the next step from it.

The deadline is an absolute time on the solver's `clock` (wall time for real time, the thread's
CPU time to measure on a shared machine, or any callable in tests), passed per call by the MPC
(`MpcConfig.step_budget_s`: the step's budget less the MPC's own work after the solve) or set by
`budget_ms`. A cold call (`warm_start=False`: the run's first step, solved before the clock runs)
ignores the deadline and converges; a budget shorter than the shortest QP measured there is
refused (`DeadlineError`): such a solver could never keep its deadline. A warm step always makes
at least one iteration (a plan must come out of every step), late if it must.

A step with a deadline never waits for a converged re-solve. Its QPs get an HPIPM iteration cap that fits the
time left (`QP_ITERATION_CAPS`, at least `min_qp_iterations`); a QP HPIPM does not solve (iteration cap, minimum
step length: after hard pushes) still yields its last iterate, taken when the line search finds it lowers the
merit (`details["inexact_steps"]`), and the step ends there; otherwise the step fails at once
(`details["qp_failures"]`) and the MPC holds the last good plan shifted in time (`MpcConfig.recover_past_deadline`).
Only a call without a deadline (the cold first step, `--delay-mode none`) goes on to the capped Fatrop re-solve of
`RtiConfig.recovery_barrier_init`. On b1_z1 after 0.8 m/s pushes those re-solves and the MPC's IPOPT fallback took
50-150 ms per failed step, the real-time rate fell to 53-63 Hz and the robot fell on stale plans.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from wbmpc.errors import ConfigError, RunError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers.nlp import NlpResult, SolverConfig, SolverStats, bound_violation
from wbmpc.solvers.qp import QpResult
from wbmpc.solvers.rti import RtiConfig, RtiSolver

CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}
# HPIPM iteration caps of the QPs of steps with a deadline (a QP that cannot be solved otherwise takes the whole
# cap of SolverConfig.max_iterations; warm b1_z1 QPs take 3-4 iterations, 6-13 after a push, up to ~25)
QP_ITERATION_CAPS = (4, 6, 9, 12, 16, 20)
COLD_QP_SHARE = 0.5  # a warm QP's share of the shortest cold one, at least (the budget floor, see `solve`)


class DeadlineError(RunError):
    """The step's time budget is shorter than one SQP iteration."""


@dataclass(frozen=True)
class AnytimeConfig(RtiConfig):
    """Settings of the anytime SQP (`SolverConfig(name="sqp", extra_options={...})`); the RTI's QP settings apply."""

    sqp_iterations: int = 20  # cap of SQP iterations per call (the deadline usually stops it first)
    budget_ms: float | None = None  # per-call budget when the caller passes no deadline; None: none
    clock: str = "wall"  # "wall": time.perf_counter (real time); "cpu": the thread's CPU time
    primal_tolerance: float = 1e-5  # converged: largest bound violation of g and x below this
    dual_tolerance: float = 1e-3  # and |grad L|_inf / max(1, |grad f|_inf) below this
    armijo: float = 1e-4  # sufficient decrease of the merit function per unit of its directional derivative
    backtrack: float = 0.5
    min_step: float = 0.05  # smallest step length tried; below it the iterate is kept (first iteration: full step)
    merit_margin: float = 1.1  # nu = margin * max |lambda| (never decreased within a call)
    safety: float = 1.2  # the next iteration starts if now + safety * (its predicted time) is before the deadline
    # linearise at the iterate returned to report its dual residual too (~0.8 ms on b1_z1); off: the dual
    # residual is that of the last iterate linearised anyway (None after a single iteration)
    kkt_at_exit: bool = False
    # a QP HPIPM did not solve (iteration cap, minimum step length: after hard pushes) still yields its last
    # iterate: taken when the line search finds it lowers the merit function, counted in details["inexact_steps"];
    # with a deadline the step then ends (that QP took its whole iteration cap). False: a failed QP ends the call
    inexact_qp_steps: bool = True
    # HPIPM's "speed_abs" (absolute tolerances) against the RTI's "speed": on 60 QPs of b1_z1's 0.8 m/s push at 315 deg
    # it solved 53 (speed 25, balance 53, robust 53) in 10.9 iterations of 0.55 ms (speed 0.59, balance 0.83 ms) with
    # the same steps; where it fails balance and robust fail too, so there is no fallback mode
    qp_mode: str = "speed_abs"
    # the lowest HPIPM iteration cap a step's deadline may impose (see QP_ITERATION_CAPS)
    min_qp_iterations: int = 16
    fallback_qp_mode: str | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.clock not in CLOCKS:
            raise ConfigError(f"anytime SQP clock must be one of {', '.join(CLOCKS)}, got {self.clock!r}")
        if self.budget_ms is not None and not self.budget_ms > 0:
            raise ConfigError(f"budget_ms must be positive or None, got {self.budget_ms}")
        if not (0 < self.backtrack < 1 and 0 < self.min_step <= 1 and 0 < self.armijo < 0.5):
            raise ConfigError("line search needs 0 < backtrack < 1, 0 < min_step <= 1, 0 < armijo < 0.5")


@dataclass
class _SqpRun:
    """The state of one `AnytimeSqpSolver.solve` call: the iterate, the merit penalty, counters and timings."""

    x: np.ndarray
    f: float
    g: np.ndarray
    deadline: float | None
    nu: float = 0.0
    lam_g: np.ndarray | None = None
    lam_x: np.ndarray | None = None
    H: object = None
    status: str = "not_started"
    success: bool = False
    iterations: int = 0
    qp_iterations: int = 0
    qp_failures: int = 0
    inexact_steps: int = 0
    failure: str | None = None  # this iteration's QP failed: its description
    primal: float = float("nan")
    dual: float = float("nan")
    alphas: list = field(default_factory=list)
    linearize_s: float = 0.0
    qp_s: float = 0.0
    search_s: float = 0.0

    def end(self, status: str, success: bool) -> bool:
        """The call ends with this status; False (the iteration loop's stop)."""
        self.status, self.success = status, success
        return False


class AnytimeSqpSolver(RtiSolver):
    """SQP with a merit line search, stopped by convergence or its deadline; `NlpSolver`'s interface
    plus `solve(..., deadline=t)` on `self.clock`."""

    supports_deadline = True
    solver_name = "sqp"

    def __init__(self, problem: OcpProblem, config: SolverConfig = SolverConfig(name="sqp"),
                 clock: Callable[[], float] | None = None):
        if config.name != "sqp":
            raise ConfigError(f"AnytimeSqpSolver needs SolverConfig(name='sqp'), got '{config.name}'")
        self.anytime = AnytimeConfig.from_options(config.extra_options)
        super().__init__(problem, config, rti=self.anytime)
        self.clock = clock or CLOCKS[self.anytime.clock]
        self._iteration_s: float | None = None  # running estimate of one iteration's time on `clock`
        self.min_iteration_s: float | None = None  # shortest whole SQP iteration seen
        self.min_qp_s: float | None = None  # shortest QP seen, CPU time (the floor of any budget)
        self._qp_s: float | None = None  # running estimate of a successful QP's time on `clock`
        self._qp_iteration_s: float | None = None  # ... and of one of its HPIPM iterations
        self._qp_sums = [0.0] * 5  # decayed sums of 1, n, t, n^2, n t over successful QPs (see _record_qp)
        # the first mode's QP with lower iteration caps, for steps whose deadline leaves no room for the full cap
        self._capped = {cap: self._new_qp(replace(self.qp.config, max_iterations=cap))
                        for cap in QP_ITERATION_CAPS if cap < self.qp.config.max_iterations}

    @property
    def capped_qps(self) -> dict:
        """{HPIPM iteration cap: QP} of steps with a deadline (`QP_ITERATION_CAPS` below the full cap); the dict
        itself: clearing it leaves every QP its full cap."""
        return self._capped

    @property
    def qp_iteration_s(self) -> float | None:
        """The estimated time of one HPIPM iteration on `clock` (None until a QP was measured)."""
        return self._qp_iteration_s

    def qp_for(self, remaining_s: float):
        """The QP a step with `remaining_s` left on `clock` solves (see `_capped_qp`)."""
        return self._capped_qp(remaining_s)

    def record_qp(self, seconds: float, iterations: int) -> None:
        """Count a solved QP of `iterations` HPIPM iterations that took `seconds` into the estimates."""
        self._record_qp(seconds, iterations)

    def _merit(self, f: float, g: np.ndarray, x: np.ndarray, lbx, ubx, lbg, ubg, nu: float) -> tuple[float, float]:
        violation = float(np.sum(np.maximum(lbg - g, 0) + np.maximum(g - ubg, 0))
                          + np.sum(np.maximum(lbx - x, 0) + np.maximum(x - ubx, 0)))
        return f + nu * violation, violation

    def solve(self, p, lbx, ubx, lbg, ubg, x0, lam_g0=None, lam_x0=None, warm_start: bool = False,
              deadline: float | None = None) -> NlpResult:
        clock, cfg = self.clock, self.anytime
        clock_start, start, cpu_start = clock(), time.perf_counter(), time.process_time()
        if deadline is None and cfg.budget_ms is not None:
            deadline = clock_start + cfg.budget_ms / 1e3
        budget_s = None if deadline is None else deadline - clock_start
        if not warm_start:
            deadline = None  # a cold step (before the clock runs) converges and measures the iterations
        bounds = tuple(np.asarray(b, dtype=float) for b in (lbx, ubx, lbg, ubg))
        x = np.asarray(x0, dtype=float).copy()
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(x))):
            return self._failure(x0, "invalid_input_nan")
        if np.any(bounds[0] > bounds[1]) or np.any(bounds[2] > bounds[3]):
            return self._failure(x0, "invalid_bounds")
        f_out, g = self._nlp(x, p)
        run = _SqpRun(x=x, f=float(f_out[0]), g=g.copy(), deadline=deadline)
        while self._iterate(run, p, bounds):
            pass
        result = self._finish(run, bounds, start, cpu_start, budget_s, warm_start)
        # a converged Fatrop re-solve takes up to ~150 ms after a push on b1_z1: never for a step with a deadline
        # (the MPC holds the last good plan instead and the next step tries again within its own deadline)
        if not result.stats.success and run.iterations == 0 and self.rti.recovery_barrier_init is not None \
                and deadline is None:
            details = result.stats.details
            result = self._recover(result, p, *bounds, x0)
            result.stats.details = {**details, "primal_residual": result.stats.max_constraint_violation,
                                    "dual_residual": None, "late": False}
        return result

    def _stop_reason(self, run: "_SqpRun") -> str | None:
        """Why no further iteration starts (checked before linearising), or None."""
        if run.iterations >= self.anytime.sqp_iterations:
            return "Maximum_Iterations_Exceeded"
        if run.iterations > 0 and run.deadline is not None and \
                self.clock() + self.anytime.safety * self._predicted_iteration_s() > run.deadline:
            return "Deadline"
        return None

    def _iterate(self, run: "_SqpRun", p, bounds) -> bool:
        """One SQP iteration: linearise (and check convergence), solve the QP, search along its step; False when
        the call ends (`run.status`, `run.success` say how)."""
        cfg, lbx, ubx, lbg, ubg = self.anytime, *bounds
        tic = self.clock()
        stop = self._stop_reason(run)  # a step that ends here skips the next linearisation
        if stop is not None and not cfg.kkt_at_exit:
            return run.end(stop, run.iterations > 0)
        linearization = self._linearize(run, p, bounds)
        if linearization is None:
            return False
        if stop is not None:
            return run.end(stop, run.iterations > 0)
        gradient, grad, J = linearization
        if run.H is None or self.hessian_depends_on_x:
            run.H = self._hessian(run.x, p)
        run.linearize_s += self.clock() - tic
        result = self._qp_step(run, (run.H, gradient, J, lbg - run.g, ubg - run.g, lbx - run.x, ubx - run.x))
        if result is None:
            return False
        step_tic = self.clock()
        accepted, alpha, trial, f_trial, g_trial = self._line_search(run, result, grad, p, bounds)
        run.search_s += self.clock() - step_tic
        if not accepted:
            if run.failure is not None:  # the failed QP's iterate does not lower the merit either
                return run.end(f"{run.failure}; its inexact step rejected by the line search", run.iterations > 0)
            return run.end("Line_Search_Failed", True)  # the iterate before this step is kept
        return self._accept(run, result, alpha, trial, f_trial, g_trial, tic)

    def _linearize(self, run: "_SqpRun", p, bounds):
        """The Jacobian and cost gradient at the iterate, and the convergence check with the last QP's multipliers;
        None when the call ends (non-finite values, converged)."""
        cfg = self.anytime
        g_lin, J = self._jacobian(run.x, p)
        if not (np.all(np.isfinite(np.asarray(g_lin))) and self._regular(J)):
            return run.end("invalid_input_nan_constraints", False) or None
        gradient = self._gradient(run.x, p)
        grad = np.asarray(gradient).ravel()
        if run.lam_g is not None:
            run.primal = bound_violation(run.x, run.g, *bounds)
            residual = grad + self._jacobian_transpose_times(J, run.lam_g) + run.lam_x
            run.dual = float(np.max(np.abs(residual), initial=0.0) / max(1.0, np.max(np.abs(grad), initial=0.0)))
            if run.primal < cfg.primal_tolerance and run.dual < cfg.dual_tolerance:
                return run.end("Converged", True) or None
        return gradient, grad, J

    def _qp_step(self, run: "_SqpRun", qp_data) -> QpResult | None:
        """The QP's step; a QP HPIPM did not solve yields its last iterate where allowed (else None: the call ends)."""
        qp_tic, qp_cpu = self.clock(), time.thread_time()
        result, _, n_qp = self._solve_qp(qp_data, run.deadline)
        run.qp_s += self.clock() - qp_tic
        if result.success:  # on CPU time: the floor of any budget, whatever else the machine runs
            one_qp_s = time.thread_time() - qp_cpu
            self.min_qp_s = one_qp_s if self.min_qp_s is None else min(self.min_qp_s, one_qp_s)
        run.qp_iterations += n_qp
        run.failure = None
        if not result.success:
            run.qp_failures += 1
            run.failure = f"{result.status} at SQP iteration {run.iterations + 1}"
            if not (self.anytime.inexact_qp_steps and np.all(np.isfinite(result.step))
                    and np.all(np.isfinite(result.lam_g)) and np.all(np.isfinite(result.lam_x))):
                # an earlier iterate is kept; none yet: the step failed
                return run.end(run.failure, run.iterations > 0) or None
        return result

    def _line_search(self, run: "_SqpRun", result: QpResult, grad: np.ndarray, p, bounds):
        """Backtracking on the l1 merit function along the QP step (Armijo); the RTI's full step on a first
        iteration whose search fails (a plan must come out of every step). (accepted, alpha, trial, f, g)."""
        cfg, d = self.anytime, result.step
        run.nu = max(run.nu, cfg.merit_margin * max(np.max(np.abs(result.lam_g), initial=0.0),
                                                    np.max(np.abs(result.lam_x), initial=0.0)))
        phi0, violation = self._merit(run.f, run.g, run.x, *bounds, run.nu)
        slope = float(grad @ d) - run.nu * violation
        alpha = 1.0
        while True:
            trial = run.x + alpha * d
            f_out, g_trial = self._nlp(trial, p)
            f_trial = float(f_out[0])
            phi, _ = self._merit(f_trial, g_trial, trial, *bounds, run.nu)
            # (a roundoff allowance: near the solution phi changes below its last digits)
            if np.isfinite(phi) and phi <= phi0 + cfg.armijo * alpha * min(slope, 0.0) + 1e-13 * max(1.0, abs(phi0)):
                return True, alpha, trial, f_trial, g_trial
            if alpha * cfg.backtrack < cfg.min_step:
                break
            alpha *= cfg.backtrack
        if run.iterations == 0 and run.failure is None:
            trial = run.x + d
            f_out, g_trial = self._nlp(trial, p)
            return bool(np.all(np.isfinite(g_trial))), 1.0, trial, float(f_out[0]), g_trial
        return False, alpha, trial, f_trial, g_trial

    def _accept(self, run: "_SqpRun", result: QpResult, alpha: float, trial, f_trial, g_trial, tic: float) -> bool:
        run.x, run.f, run.g = trial, f_trial, g_trial.copy()
        run.lam_g, run.lam_x = result.lam_g, result.lam_x
        run.alphas.append(alpha)
        run.iterations += 1
        self._record_iteration(self.clock() - tic)
        if run.failure is not None:
            run.inexact_steps += 1
            if run.deadline is not None:  # a QP that failed took its whole iteration cap: no time for another
                return run.end(f"{run.failure}; its inexact step taken (merit lowered)", True)
        if np.max(np.abs(alpha * result.step), initial=0.0) < self.anytime.step_tolerance:
            return run.end("Converged_Step", True)
        return True

    def _check_budget(self, budget_s: float | None, warm_start: bool) -> None:
        """The cold call's QPs start far from the solution and take up to ~2.7x a warm step's (b1_z1: 8.1 ms of CPU
        against 3.0): a budget is refused only below half the shortest of them, where no warm QP fits either."""
        if budget_s is None or warm_start or self.min_qp_s is None or budget_s >= COLD_QP_SHARE * self.min_qp_s:
            return
        raise DeadlineError(f"the solver's share of the MPC step's budget (the step budget less the MPC's own "
                            f"work) is {1e3 * budget_s:.2f} ms, shorter than one QP of "
                            f"the SQP (at least {1e3 * COLD_QP_SHARE * self.min_qp_s:.2f} ms of CPU, half the shortest "
                            "on the cold first step): "
                            "raise the budget (--step-budget or MpcConfig.step_budget_s, the anytime solver's budget_ms), "
                            "lower the MPC rate, compile the solver (--compiled) or use a smaller horizon (--nodes)")

    def _finish(self, run: "_SqpRun", bounds, start: float, cpu_start: float, budget_s: float | None,
                warm_start: bool) -> NlpResult:
        """The iterate returned (NaN where the call failed), its statistics and KKT residuals."""
        x, f, g = run.x, run.f, run.g
        finite = bool(np.all(np.isfinite(g)) and np.isfinite(f))
        primal = bound_violation(x, g, *bounds) if finite else float("inf")  # of the iterate returned
        success = run.success and finite and run.iterations > 0
        viol = primal
        if not success:
            x, f, viol = np.full_like(x, np.nan), float("nan"), float("inf")
        elapsed = time.perf_counter() - start
        self._check_budget(budget_s, warm_start)
        late = run.deadline is not None and self.clock() > run.deadline
        self.last_timing = {"linearize_ms": 1e3 * run.linearize_s, "qp_ms": 1e3 * run.qp_s,
                            "line_search_ms": 1e3 * run.search_s, "cpu_ms": 1e3 * (time.process_time() - cpu_start)}
        stats = SolverStats(status=run.status, success=success, iterations=run.qp_iterations, solve_time_s=elapsed,
                            max_constraint_violation=viol, cost=f, cpu_time_s=self.last_timing["cpu_ms"] / 1e3,
                            split_ms={"linearize": 1e3 * run.linearize_s, "qp": 1e3 * run.qp_s,
                                      "line_search": 1e3 * run.search_s})
        stats.details = {"sqp_iterations": run.iterations, "primal_residual": primal, "dual_residual": run.dual,
                         "step_lengths": run.alphas, "budget_ms": None if budget_s is None else 1e3 * budget_s,
                         "late": bool(late), "merit_penalty": run.nu, "qp_failures": run.qp_failures,
                         "inexact_steps": run.inexact_steps}
        n = self.problem.n_constraints
        return NlpResult(x=x, lam_g=run.lam_g if run.lam_g is not None else np.zeros(n),
                         lam_x=run.lam_x if run.lam_x is not None else np.zeros_like(x), stats=stats)

    def _solve_qp(self, qp_data, deadline: float | None = None) -> tuple[QpResult, float, int]:
        """The QP in the first HPIPM mode, its iteration cap lowered to what fits before `deadline` (on
        `self.clock`, from the time per HPIPM iteration measured so far; a QP that cannot be solved, after
        hard pushes, otherwise takes its whole cap, ~17 ms on b1_z1); a fallback mode re-solves a failed
        QP only if a QP is predicted to end before the deadline. None: as the RTI."""
        if deadline is None:
            tic = self.clock()
            result, spent_s, iterations = super()._solve_qp(qp_data)
            if result.success:
                self._record_qp(self.clock() - tic, result.iterations)
            return result, spent_s, iterations
        qps = [(qp, qp.config.mode if qp is not None else None)
               for qp in (self._capped_qp(deadline - self.clock()), self.fallback_qp)]
        if self._fallback_first > 0 and self.fallback_qp is not None:
            self._fallback_first -= 1
            qps.reverse()
        tic = self.clock()
        result = qps[0][0].solve(*qp_data)
        spent_s, iterations = result.solve_time_s, max(result.iterations, 0)
        if result.success:
            self._record_qp(self.clock() - tic, result.iterations)
        elif qps[1][0] is not None:
            if self.clock() + (self._qp_s or 0.0) <= deadline:
                first = result.status
                tic = self.clock()
                result = qps[1][0].solve(*qp_data)
                spent_s, iterations = spent_s + result.solve_time_s, iterations + max(result.iterations, 0)
                result.status = f"{result.status} ({qps[1][1]} after {qps[0][1]}: {first})"
                if result.success:
                    self._record_qp(self.clock() - tic, result.iterations)
                if qps[0][0] is not self.fallback_qp:
                    self._fallback_first = self.fallback_first_calls
            else:
                result.status = f"{result.status} ({qps[0][1]}; no time for {qps[1][1]} before the deadline)"
        return result, spent_s, iterations

    def _capped_qp(self, remaining_s: float):
        """The first mode's QP with the largest iteration cap (QP_ITERATION_CAPS, or the full one) whose
        iterations are predicted to fit in `remaining_s`; the smallest cap when none does."""
        if self._qp_iteration_s is None or not self._capped:
            return self.qp
        fits = remaining_s / (self.anytime.safety * self._qp_iteration_s)
        caps = sorted(cap for cap in self._capped if cap >= self.anytime.min_qp_iterations)
        if not caps or fits >= self.qp.config.max_iterations:
            return self.qp
        return self._capped[max([cap for cap in caps if cap <= fits], default=caps[0])]

    def _record_qp(self, seconds: float, iterations: int) -> None:
        """Running estimates of a QP's time and, by a least-squares fit of time = overhead + iterations x
        per-iteration time over the recent QPs (exponential forgetting), of one HPIPM iteration's time."""
        self._qp_s = seconds if self._qp_s is None else 0.7 * self._qp_s + 0.3 * seconds
        if iterations <= 0:
            return
        sums = self._qp_sums = [0.95 * total for total in self._qp_sums]
        for i, value in enumerate((1.0, iterations, seconds, iterations * iterations, iterations * seconds)):
            sums[i] += value
        weight, n, t, nn, nt = sums
        spread = nn - n * n / weight
        slope = (nt - n * t / weight) / spread if spread > 1.0 else 0.0  # some QPs with other iteration counts
        fallback = t / n  # all QPs alike: their whole time per iteration (overestimates it, on the safe side)
        self._qp_iteration_s = slope if 0.2 * fallback < slope <= fallback else fallback

    def _predicted_iteration_s(self) -> float:
        return self._iteration_s if self._iteration_s is not None else 0.0

    def _record_iteration(self, seconds: float) -> None:
        self._iteration_s = seconds if self._iteration_s is None else 0.7 * self._iteration_s + 0.3 * seconds
        self.min_iteration_s = seconds if self.min_iteration_s is None else min(self.min_iteration_s, seconds)
