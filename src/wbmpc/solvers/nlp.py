"""NLP solvers on the stage-wise OCP: Fatrop (structure-exploiting) and IPOPT, built once.

Fatrop detects the stage structure from the variable order (x0, u0, x1, ...) and the
gap-closing rows, which `OcpProblem` marks in `equality`. Whether another row is an equality
or an inequality is read from lbg/ubg at every call, so contact switches need no rebuild.
A failed solve never raises: its status is returned.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.interrupt import deliver_after
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers import blasfeo
from wbmpc.solvers.buffered import BufferedFunction
from wbmpc.solvers.codegen import (
    CodegenConfig,
    CompileError,
    CompileReport,
    compile_nlp,
)

# rti: solvers/rti.py, sqp: the anytime SQP (solvers/anytime.py), fatrop-direct: solvers/fatrop_direct.py;
# all three built by wbmpc.solvers.make_solver
SOLVERS = ("fatrop", "ipopt", "rti", "sqp", "fatrop-direct")
FATROP_SOLVERS = ("fatrop", "fatrop-direct")  # the same Fatrop: casadi's nlpsol or our direct binding


@dataclass(frozen=True)
class SolverConfig:
    name: str = "fatrop"
    # overall KKT tolerance: 1e-4 stops a warm-started trot step after 4.0 instead of 5.0 Fatrop iterations
    # with the same closed-loop trajectory (base position equal to 0.1 mm after 1 s); constraint violations
    # keep their own, tight tolerance
    tolerance: float = 1e-4
    constraint_tolerance: float = 1e-6
    max_iterations: int = 100
    time_limit_s: float | None = None  # IPOPT and fatrop-direct stop themselves; casadi's Fatrop is flagged afterwards
    barrier_init: float = 1e-3  # initial barrier parameter mu: small suits warm-started MPC
    # Fatrop, warm-started MPC steps (`solve(..., warm_start=True)`): first an attempt from this much smaller
    # barrier, capped at `warm_max_iterations`; if it does not converge, the step is solved from
    # `barrier_init` as usual and warm attempts pause for `warm_backoff_steps` calls, doubled after each
    # further failure up to 8x (pushes, walking with changing targets), reset by a success.
    # Trot in place: 3.1 instead of 4.0 iterations per step, same closed loop. None: off.
    warm_barrier_init: float | None = 1e-5
    warm_max_iterations: int = 4
    warm_backoff_steps: int = 8
    print_level: int = 0
    extra_options: dict = field(default_factory=dict)
    compiled: bool = False  # generate C, compile (cached) and load it; falls back to the VM on failure
    solver_per_structure: bool = True  # Fatrop: one nlpsol per row-count pattern keeps our options (see NlpSolver)
    codegen: CodegenConfig = field(default_factory=CodegenConfig)
    # fatrop-direct: threads evaluating the stage functions (the caller and threads - 1 workers; the same iterates on
    # any count); None: two where the process may use two cores (fatrop_settings.default_threads)
    threads: int | None = None

    def __post_init__(self):
        if self.name not in SOLVERS:
            raise ConfigError(f"unknown solver '{self.name}'; available solvers: {', '.join(SOLVERS)}")
        if not self.tolerance > 0:
            raise ConfigError(f"solver tolerance must be positive, got {self.tolerance}")
        if not self.constraint_tolerance > 0:
            raise ConfigError(f"solver constraint_tolerance must be positive, got {self.constraint_tolerance}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.warm_barrier_init is not None and not self.warm_barrier_init > 0:
            raise ConfigError(f"warm_barrier_init must be positive or None, got {self.warm_barrier_init}")
        if self.threads is not None and (isinstance(self.threads, bool) or not isinstance(self.threads, int)
                                         or not 1 <= self.threads <= 64):
            raise ConfigError(f"threads must be an integer from 1 to 64 or None, got {self.threads!r}")
        if self.warm_max_iterations < 1 or self.warm_backoff_steps < 0:
            raise ConfigError(f"warm_max_iterations must be >= 1 and warm_backoff_steps >= 0, got "
                              f"{self.warm_max_iterations} and {self.warm_backoff_steps}")


@dataclass
class SolverStats:
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    max_constraint_violation: float
    cost: float
    cpu_time_s: float = 0.0  # CPU time of the solve (its thread, fatrop-direct: its process with the pool threads)
    split_ms: dict = field(default_factory=dict)  # where the solve time went (see `time_split_ms`)
    details: dict = field(default_factory=dict)  # solver-specific (anytime SQP: iterations, KKT residuals, budget)


def time_split_ms(name: str, stats: dict, elapsed_s: float) -> dict:
    """Where one solve's wall time went, in ms.

    `functions`: CasADi's NLP function evaluations (what code generation speeds up);
    Fatrop only: `linear_algebra` (search directions: the Riccati recursion on BLASFEO),
    `initialization` (first evaluations and the initial dual estimate), `interface` (Fatrop's
    evaluation callbacks beyond the functions themselves: casadi copying blocks into BLASFEO
    matrices), `line_search_and_rest` (the remainder inside Fatrop); every solver: `outside_solver`
    (casadi's nlpsol around the solver: argument checks, copies, statistics).
    """
    functions = 1e3 * sum(float(v) for k, v in stats.items() if k.startswith("t_wall_nlp_"))
    split = {"functions": functions}
    fatrop = stats.get("fatrop") if isinstance(stats.get("fatrop"), dict) else None
    if name == "fatrop" and fatrop:
        inside = 1e3 * float(fatrop.get("time_total", 0.0))
        callbacks = 1e3 * sum(float(fatrop.get(f"eval_{k}_time", 0.0)) for k in ("hess", "jac", "cv", "grad", "obj"))
        split.update(linear_algebra=1e3 * float(fatrop.get("compute_sd_time", 0.0)),
                     initialization=1e3 * float(fatrop.get("initialization_time", 0.0)),
                     interface=max(callbacks - functions, 0.0))
        split["line_search_and_rest"] = max(inside - split["linear_algebra"] - split["initialization"] - callbacks, 0.0)
        split["outside_solver"] = max(1e3 * elapsed_s - inside, 0.0)
    else:
        split["solver"] = max(1e3 * elapsed_s - functions, 0.0)
    return split


@dataclass
class NlpResult:
    x: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    stats: SolverStats


_FATROP_FLAGS = {0: "Solve_Succeeded", 1: "Maximum_Iterations_Exceeded", 2: "Solved_To_Acceptable_Level",
                 4: "Line_Search_Failed", 5: "Step_Computation_Failed"}


def _status(name: str, stats: dict) -> tuple[str, bool]:
    """Readable status and success flag; an acceptable-level stop counts as converged."""
    if name == "fatrop":
        flag = stats.get("fatrop", {}).get("return_flag", None) if isinstance(stats.get("fatrop"), dict) else None
        status = _FATROP_FLAGS.get(flag, f"fatrop_flag_{flag}") if flag is not None else str(stats.get("return_status"))
        return status, bool(stats.get("success", False)) or flag == 2
    status = str(stats.get("return_status", "unknown"))
    return status, bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level"


def solver_options(problem: OcpProblem, config: SolverConfig) -> dict:
    # calc_lam_p: the parameters' multipliers cost an extra derivative evaluation per solve and nothing reads them
    common = {"expand": True, "print_time": False, "error_on_fail": False, "calc_lam_p": False}
    if config.name == "fatrop":
        opts = {
            **common,
            "structure_detection": "auto",
            "equality": [bool(e) for e in problem.equality],
            "fatrop": {
                "print_level": config.print_level,
                "tol": config.tolerance,
                "constr_viol_tol": config.constraint_tolerance,
                "max_iter": config.max_iterations,
                "mu_init": config.barrier_init,
            },
        }
    else:
        opts = {
            **common,
            "ipopt": {
                "print_level": config.print_level,
                "sb": "yes",
                "tol": config.tolerance,
                "constr_viol_tol": config.constraint_tolerance,
                "max_iter": config.max_iterations,
                "mu_init": config.barrier_init,
                **({"max_wall_time": config.time_limit_s} if config.time_limit_s else {}),
            },
        }
    for key, value in config.extra_options.items():
        if isinstance(value, dict) and isinstance(opts.get(key), dict):
            opts[key] = {**opts[key], **value}
        else:
            opts[key] = value
    return opts


def bound_violation(x, g, lbx, ubx, lbg, ubg) -> float:
    """Largest violation of the variable and constraint bounds at (x, g)."""
    viol_g = np.maximum(lbg - g, 0) + np.maximum(g - ubg, 0)
    viol_x = np.maximum(lbx - x, 0) + np.maximum(x - ubx, 0)
    return float(max(viol_g.max(initial=0), viol_x.max(initial=0)))


def failed_result(problem: OcpProblem, x0, status: str) -> NlpResult:
    """A solve that did not run or did not finish: NaN variables, the status says why."""
    nan = np.full_like(np.asarray(x0, dtype=float), np.nan)
    return NlpResult(nan, np.zeros(problem.n_constraints), np.zeros_like(nan),
                     SolverStats(status, False, 0, 0.0, float("inf"), float("nan")))


class NlpSolver:
    """A casadi nlpsol for one OCP structure; `solve` takes numeric p, bounds and an initial guess.

    Fatrop: casadi 3.8's plugin rebuilds its Fatrop instance whenever the per-stage numbers of
    equality and inequality rows change (every contact switch) and the rebuilt instance ignores
    our options (tol, mu_init, max_iter: Fatrop's defaults 1e-8, 0.1, 1000 apply instead). So one
    nlpsol is kept per row-count pattern (`structure_key`): each keeps its Fatrop instance and our
    options, and no step pays for a rebuild. Trot and walk keep the counts constant; starting or
    stopping a gait and custom schedules change them (a new pattern costs about 0.1 s once, compiled).

    `compile_report`: a library compiled before for this problem (no code generation, no compiler).
    """

    def __init__(self, problem: OcpProblem, config: SolverConfig = SolverConfig(), solver: ca.Function | None = None,
                 compile_report: CompileReport | None = None):
        if config.name in ("rti", "sqp", "fatrop-direct"):
            raise ConfigError(f"the '{config.name}' solver is not an nlpsol: build it with "
                              "wbmpc.solvers.make_solver(problem, config)")
        self.problem = problem
        self.config = config
        self.compile_report: CompileReport | None = compile_report
        self.compile_error: str | None = None
        self._source: dict | str = str(compile_report.library) if compile_report else problem.nlp
        if solver is None and config.compiled and compile_report is None:
            solver = self._compiled_solver()
        self.solver = solver or self._new_nlpsol()
        self._by_structure: dict[bytes, ca.Function] = {}
        self._unclaimed: ca.Function | None = self.solver  # the first solver serves the first pattern seen
        # constraint values for the input checks and the violation report: compiled when the solver is
        self._g = BufferedFunction(
            ca.external("nlp_g", self._source) if isinstance(self._source, str) else
            ca.Function("g", [problem.nlp["x"], problem.nlp["p"]], [problem.nlp["g"]], {"allow_free": False}))
        self._stage_x_starts = np.array([state.start for state, _ in problem.stage_slices])
        # the small-barrier attempt (Fatrop), built now: a build inside a step would count as its solve time
        self._warm: NlpSolver | None = (
            self.recreated(barrier_init=config.warm_barrier_init, max_iterations=config.warm_max_iterations,
                           warm_barrier_init=None)
            if config.name == "fatrop" and config.warm_barrier_init is not None else None)
        self._warm_pause = 0  # calls left before the next warm attempt
        self._warm_failures = 0  # consecutive failed warm attempts

    def _new_nlpsol(self) -> ca.Function:
        options = solver_options(self.problem, self.config)
        if isinstance(self._source, str):  # a compiled library: its functions are already expanded
            options.pop("expand")
        suffix = "_compiled" if isinstance(self._source, str) else ""
        blasfeo.activate()  # before casadi loads the Fatrop plugin (and its BLASFEO)
        return ca.nlpsol(f"ocp_{self.config.name}{suffix}", self.config.name, self._source, options)

    def structure_key(self, lbx, ubx, lbg, ubg) -> bytes:
        """Per-stage numbers of equality and inequality rows (bounds included), as casadi's Fatrop
        plugin counts them: lb == ub is an equality, a row with both bounds infinite is skipped."""
        def counts(lower, upper, starts):
            lower, upper = np.asarray(lower), np.asarray(upper)
            equal = lower == upper
            bounded = ~equal & ~(np.isneginf(lower) & np.isposinf(upper))
            ends = np.append(starts[1:], lower.size)  # a stage may have no rows (e.g. the terminal one)

            def per_stage(mask):
                total = np.concatenate([[0], np.cumsum(mask)])
                return total[ends] - total[starts]

            return per_stage(equal), per_stage(bounded)

        eq_g, ineq_g = counts(lbg, ubg, self.problem.stage_row_starts)
        eq_x, ineq_x = counts(lbx, ubx, self._stage_x_starts)
        return np.stack([eq_g + eq_x, ineq_g + ineq_x]).astype(np.int32).tobytes()

    def _solver_for(self, lbx, ubx, lbg, ubg) -> ca.Function:
        if self.config.name != "fatrop" or not self.config.solver_per_structure:
            return self.solver
        key = self.structure_key(lbx, ubx, lbg, ubg)
        solver = self._by_structure.get(key)
        if solver is None:
            solver, self._unclaimed = (self._unclaimed or self._new_nlpsol()), None
            self._by_structure[key] = solver
        return solver

    @property
    def is_compiled(self) -> bool:
        return self.compile_report is not None

    def recreated(self, **changes) -> "NlpSolver":
        """A fresh solver on the same problem (and compiled library) with some settings changed."""
        config = replace(self.config, **changes)
        if self.compile_report is None:
            return NlpSolver(self.problem, replace(config, compiled=False))
        return NlpSolver(self.problem, replace(config, compiled=True), compile_report=self.compile_report)

    def _compiled_solver(self) -> ca.Function | None:
        """nlpsol on the compiled library, or None (with a warning) when compiling is impossible."""
        try:
            self.compile_report = compile_nlp(self.problem, self.config.name, self.config.codegen)
        except CompileError as exc:
            self.compile_error = str(exc)
            warnings.warn(f"compiled solver unavailable, using the non-compiled one: {exc}", RuntimeWarning, stacklevel=3)
            return None
        self._source = str(self.compile_report.library)
        return self._new_nlpsol()

    def constraints(self, x, p) -> np.ndarray:
        """g(x) of the NLP (a copy)."""
        return np.array(self._g(x, p)[0], dtype=float)

    def constraint_violation(self, x, p, lbx, ubx, lbg, ubg) -> float:
        return bound_violation(x, self._g(x, p)[0], lbx, ubx, lbg, ubg)

    @property
    def structure_keys(self) -> tuple[bytes, ...]:
        """The row-count patterns (`structure_key`) a casadi nlpsol, each with its own Fatrop, was built for so far."""
        return tuple(self._by_structure)

    def _failure(self, x0, status: str) -> NlpResult:
        return failed_result(self.problem, x0, status)

    def solve(self, p, lbx, ubx, lbg, ubg, x0, lam_g0=None, lam_x0=None, warm_start: bool = False) -> NlpResult:
        """Solve from x0. `warm_start`: x0 is the previous solution shifted (MPC), so the small-barrier
        attempt is tried first (see `SolverConfig.warm_barrier_init`)."""
        cfg = self.config
        if not warm_start or self._warm is None:
            return self._solve(p, lbx, ubx, lbg, ubg, x0, lam_g0, lam_x0)
        if self._warm_pause > 0:
            self._warm_pause -= 1
            return self._solve(p, lbx, ubx, lbg, ubg, x0, lam_g0, lam_x0)
        attempt = self._warm.solve(p, lbx, ubx, lbg, ubg, x0, lam_g0, lam_x0)
        if attempt.stats.success:
            self._warm_failures = 0
            return attempt
        self._warm_pause = cfg.warm_backoff_steps * 2 ** min(self._warm_failures, 3)
        self._warm_failures += 1
        result = self._solve(p, lbx, ubx, lbg, ubg, x0, lam_g0, lam_x0)
        stats = result.stats
        stats.iterations += max(attempt.stats.iterations, 0)
        stats.solve_time_s += attempt.stats.solve_time_s
        stats.cpu_time_s += attempt.stats.cpu_time_s
        stats.split_ms = {k: stats.split_ms.get(k, 0.0) + attempt.stats.split_ms.get(k, 0.0)
                          for k in {**stats.split_ms, **attempt.stats.split_ms}}
        stats.status = f"{stats.status} (after mu_init {cfg.warm_barrier_init:g}: {attempt.stats.status})"
        return result

    def _solve(self, p, lbx, ubx, lbg, ubg, x0, lam_g0=None, lam_x0=None) -> NlpResult:
        # Fatrop can hang on a NaN at the initial guess: refuse such calls and say why.
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(x0))):
            return self._failure(x0, "invalid_input_nan")
        if not np.all(np.isfinite(self._g(x0, p)[0])):
            return self._failure(x0, "invalid_input_nan_constraints")
        if np.any(np.asarray(lbx) > np.asarray(ubx)) or np.any(np.asarray(lbg) > np.asarray(ubg)):
            return self._failure(x0, "invalid_bounds")
        args = {"p": p, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg, "x0": x0}
        if lam_g0 is not None:
            args["lam_g0"] = lam_g0
        if lam_x0 is not None:
            args["lam_x0"] = lam_x0
        self.solver = self._solver_for(lbx, ubx, lbg, ubg)
        start, start_cpu = time.perf_counter(), time.thread_time()
        try:
            with deliver_after():  # CasADi's Fatrop swallows Ctrl-C, its IPOPT turns it into a failed solve
                out = self.solver(**args)
        except RuntimeError as exc:  # errors inside the solver are reported, not raised
            return self._failure(x0, f"solver_exception: {str(exc).splitlines()[-1][:200]}")
        elapsed, cpu = time.perf_counter() - start, time.thread_time() - start_cpu
        stats = self.solver.stats()
        x = np.asarray(out["x"]).ravel()
        status, success = _status(self.config.name, stats)
        success = success and bool(np.all(np.isfinite(x)))
        if self.config.time_limit_s and elapsed > self.config.time_limit_s and success:
            status = "time_limit_exceeded"
        viol = self.constraint_violation(x, p, lbx, ubx, lbg, ubg) if np.all(np.isfinite(x)) else float("inf")
        return NlpResult(
            x=x,
            lam_g=np.asarray(out["lam_g"]).ravel(),
            lam_x=np.asarray(out["lam_x"]).ravel(),
            stats=SolverStats(
                status=status,
                success=success,
                iterations=int(stats.get("iter_count", -1)),
                solve_time_s=float(stats.get("t_wall_total", elapsed)) if "t_wall_total" in stats else elapsed,
                max_constraint_violation=viol,
                cost=float(out["f"]),
                cpu_time_s=cpu,
                split_ms=time_split_ms(self.config.name, stats, elapsed),
            ),
        )
