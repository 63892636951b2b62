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
from dataclasses import dataclass, replace
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
        lbx, ubx, lbg, ubg = (np.asarray(b, dtype=float) for b in (lbx, ubx, lbg, ubg))
        x = np.asarray(x0, dtype=float).copy()
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(x))):
            return self._failure(x0, "invalid_input_nan")
        if np.any(lbx > ubx) or np.any(lbg > ubg):
            return self._failure(x0, "invalid_bounds")
        f_out, g = self._nlp(x, p)
        f, g = float(f_out[0]), g.copy()
        nu, lam_g, lam_x = 0.0, None, None
        status, success, qp_iterations, iterations, alphas = "not_started", False, 0, 0, []
        qp_failures = inexact_steps = 0
        primal = dual = float("nan")
        H = None
        linearize_s = qp_s = search_s = 0.0
        while True:
            tic = clock()
            stop = None  # checked before linearising: a step that ends here skips the next linearisation
            if iterations >= cfg.sqp_iterations:
                stop = "Maximum_Iterations_Exceeded"
            elif iterations > 0 and deadline is not None and \
                    clock() + cfg.safety * self._predicted_iteration_s() > deadline:
                stop = "Deadline"
            if stop is not None and not cfg.kkt_at_exit:
                status, success = stop, iterations > 0
                break
            g_lin, J = self._jacobian(x, p)
            if not (np.all(np.isfinite(np.asarray(g_lin))) and self._regular(J)):
                status = "invalid_input_nan_constraints"
                break
            gradient = self._gradient(x, p)
            grad = np.asarray(gradient).ravel()
            if lam_g is not None:
                primal = bound_violation(x, g, lbx, ubx, lbg, ubg)
                residual = grad + self._jacobian_transpose_times(J, lam_g) + lam_x
                dual = float(np.max(np.abs(residual), initial=0.0) / max(1.0, np.max(np.abs(grad), initial=0.0)))
                if primal < cfg.primal_tolerance and dual < cfg.dual_tolerance:
                    status, success = "Converged", True
                    break
            if stop is not None:
                status, success = stop, iterations > 0
                break
            if H is None or self.hessian_depends_on_x:
                H = self._hessian(x, p)
            linearize_s += clock() - tic
            qp_tic, qp_cpu = clock(), time.thread_time()
            result, _, n_qp = self._solve_qp((H, gradient, J, lbg - g, ubg - g, lbx - x, ubx - x), deadline)
            qp_s += clock() - qp_tic
            if result.success:  # on CPU time: the floor of any budget, whatever else the machine runs
                one_qp_s = time.thread_time() - qp_cpu
                self.min_qp_s = one_qp_s if self.min_qp_s is None else min(self.min_qp_s, one_qp_s)
            qp_iterations += n_qp
            inexact = not result.success
            if inexact:
                qp_failures += 1
                failure = f"{result.status} at SQP iteration {iterations + 1}"
                if not (cfg.inexact_qp_steps and np.all(np.isfinite(result.step))
                        and np.all(np.isfinite(result.lam_g)) and np.all(np.isfinite(result.lam_x))):
                    status = failure
                    success = iterations > 0  # an earlier iterate is kept; none yet: the step failed
                    break
            step_tic = clock()
            d = result.step
            nu = max(nu, cfg.merit_margin * max(np.max(np.abs(result.lam_g), initial=0.0),
                                                np.max(np.abs(result.lam_x), initial=0.0)))
            phi0, violation = self._merit(f, g, x, lbx, ubx, lbg, ubg, nu)
            slope = float(grad @ d) - nu * violation
            alpha, accepted = 1.0, False
            while True:
                trial = x + alpha * d
                f_out, g_trial = self._nlp(trial, p)
                f_trial = float(f_out[0])
                phi, _ = self._merit(f_trial, g_trial, trial, lbx, ubx, lbg, ubg, nu)
                # (a roundoff allowance: near the solution phi changes below its last digits)
                if np.isfinite(phi) and phi <= phi0 + cfg.armijo * alpha * min(slope, 0.0) + 1e-13 * max(1.0, abs(phi0)):
                    accepted = True
                    break
                if alpha * cfg.backtrack < cfg.min_step:
                    break
                alpha *= cfg.backtrack
            if not accepted and iterations == 0 and not inexact:  # the RTI's full step: a plan must come out of every step
                alpha = 1.0
                trial = x + d
                f_out, g_trial = self._nlp(trial, p)
                f_trial, accepted = float(f_out[0]), bool(np.all(np.isfinite(g_trial)))
            search_s += clock() - step_tic
            if not accepted:
                if inexact:  # the failed QP's iterate does not lower the merit either
                    status, success = f"{failure}; its inexact step rejected by the line search", iterations > 0
                else:
                    status, success = "Line_Search_Failed", True  # the iterate before this step is kept
                break
            x, f, g = trial, f_trial, g_trial.copy()
            lam_g, lam_x = result.lam_g, result.lam_x
            alphas.append(alpha)
            iterations += 1
            self._record_iteration(clock() - tic)
            if inexact:
                inexact_steps += 1
                if deadline is not None:  # a QP that failed took its whole iteration cap: no time for another
                    status, success = f"{failure}; its inexact step taken (merit lowered)", True
                    break
            if np.max(np.abs(alpha * d), initial=0.0) < cfg.step_tolerance:
                status, success = "Converged_Step", True
                break
        finite = bool(np.all(np.isfinite(g)) and np.isfinite(f))
        primal = bound_violation(x, g, lbx, ubx, lbg, ubg) if finite else float("inf")  # of the iterate returned
        success = success and finite and iterations > 0
        viol = bound_violation(x, g, lbx, ubx, lbg, ubg) if finite else float("inf")
        if not success:
            x, f, viol = np.full_like(x, np.nan), float("nan"), float("inf")
        elapsed = time.perf_counter() - start
        # the cold call's QPs start far from the solution and take up to ~2.7x a warm step's (b1_z1: 8.1 ms of CPU
        # against 3.0): a budget is refused only below half the shortest of them, where no warm QP fits either
        if budget_s is not None and not warm_start and self.min_qp_s is not None and budget_s < COLD_QP_SHARE * self.min_qp_s:
            raise DeadlineError(f"the solver's share of the MPC step's budget (the step budget less the MPC's own "
                                f"work) is {1e3 * budget_s:.2f} ms, shorter than one QP of "
                                f"the SQP (at least {1e3 * COLD_QP_SHARE * self.min_qp_s:.2f} ms of CPU, half the shortest "
                                "on the cold first step): "
                                "raise the budget (--step-budget or MpcConfig.step_budget_s, the anytime solver's budget_ms), lower "
                                "the MPC rate, compile the solver (--compiled) or use a smaller horizon (--nodes)")
        late = deadline is not None and clock() > deadline
        self.last_timing = {"linearize_ms": 1e3 * linearize_s, "qp_ms": 1e3 * qp_s, "line_search_ms": 1e3 * search_s,
                            "cpu_ms": 1e3 * (time.process_time() - cpu_start)}
        n = self.problem.n_constraints
        stats = SolverStats(status=status, success=success, iterations=qp_iterations, solve_time_s=elapsed,
                            max_constraint_violation=viol, cost=f, cpu_time_s=self.last_timing["cpu_ms"] / 1e3,
                            split_ms={"linearize": 1e3 * linearize_s, "qp": 1e3 * qp_s, "line_search": 1e3 * search_s})
        stats.details = {"sqp_iterations": iterations, "primal_residual": primal, "dual_residual": dual,
                         "step_lengths": alphas, "budget_ms": None if budget_s is None else 1e3 * budget_s,
                         "late": bool(late), "merit_penalty": nu, "qp_failures": qp_failures,
                         "inexact_steps": inexact_steps}
        result = NlpResult(x=x, lam_g=lam_g if lam_g is not None else np.zeros(n),
                           lam_x=lam_x if lam_x is not None else np.zeros_like(x), stats=stats)
        # a converged Fatrop re-solve takes up to ~150 ms after a push on b1_z1: never for a step with a deadline
        # (the MPC holds the last good plan instead and the next step tries again within its own deadline)
        if not success and iterations == 0 and self.rti.recovery_barrier_init is not None and deadline is None:
            result = self._recover(result, p, lbx, ubx, lbg, ubg, x0)
            result.stats.details = {**stats.details, "primal_residual": result.stats.max_constraint_violation,
                                    "dual_residual": None, "late": deadline is not None and clock() > deadline}
        return result

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
