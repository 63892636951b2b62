"""Real-time iteration (RTI): one SQP iteration per MPC step on a structured QP (`--solver rti`).

The paper names SQP as future work for speed. An RTI step linearises the OCP (eq. 1, same
formulation, constraints and bounds as the Fatrop mode) at the MPC's warm start — the previous
solution shifted in time with node 0 at the measured state — and takes the full step of one QP
(`solvers/qp.py`, HPIPM; on our own HPIPM binding `solvers/hpipm_direct.py` where it builds, casadi's
conic otherwise, `RtiConfig.hpipm_binding`):

    H = Hessian of the cost (eq. 3) + delta I,  gradient = grad f(x_lin),  J = dg/dx(x_lin).

For the [q, v] formulations (wb_inverse, wb_forward, centroidal_acc*) the cost is a diagonal
quadratic in the variables, so this Hessian is the Gauss-Newton one: positive definite, and the
constraint curvature (RNEA, kinematics, friction cone) is left out, so no multipliers are needed
to linearise and the QP stays convex. For the [h_com, q] formulations it is the exact cost Hessian
(positive definite on the go2 tests). Iterated at a fixed state the step converges (linearly) to
the KKT point Fatrop finds, on all six formulations (tests/solvers/test_rti.py). The Jacobian and cost gradient come from the same per-stage
derivatives as the compiled Fatrop solver (`solvers/codegen.py`: one compiled library, cached);
without `compiled` they are evaluated in CasADi's SX virtual machine.

`RtiSolver` has `NlpSolver`'s interface (`solve(p, lbx, ubx, lbg, ubg, x0) -> NlpResult`, stats,
failure reporting); its last step's time split is in `last_timing`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, fields, replace

import casadi as ca
import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers.buffered import BufferedFunction
from wbmpc.solvers.codegen import CompileError, CompileReport, compile_nlp
from wbmpc.solvers.hpipm_direct import HPIPM_BINDINGS, conic_config, make_qp
from wbmpc.solvers.nlp import (
    NlpResult,
    NlpSolver,
    SolverConfig,
    SolverStats,
    bound_violation,
    failed_result,
)
from wbmpc.solvers.qp import HPIPM_MODES, QpConfig, QpResult, StructuredQp

DIRECT_QP_BARRIER_INIT = 1e3  # HPIPM's mu0 on our binding (RtiConfig.qp_barrier_init)
# ... where the OCP has flat feet (6D wrenches, hard wrench cone): g1's walk keeps 10-50 of its wrench cone rows
# active (the CoP at a sole's edge). With the centre-of-pressure rows in units of the lever (hw f_z - tau_x) HPIPM
# took 8.3 iterations from 1e3, 7.3 from 100, 7.0 from 10 on the same 40 RTI QPs (b1_z1's trot: 3.3 from 1e3, 6.7
# from 10); with the rows divided by their lever (ocp/problem.py's wrench cone: f_z - tau_x / hw) g1's walk in place
# (RTI, 1.5 s, MuJoCo, uncompiled) took 8.1 from 1, 6.0 from 10 and 5.0 from 100 (5.5 before from 10), same drift
# and base velocity RMSE
FLAT_FOOT_QP_BARRIER_INIT = 100.0
QP_TOLERANCE = 1e-4  # RtiConfig.qp_tolerance
# ... of one real-time iteration on flat feet: g1 walking in place (RTI, 4 s, MuJoCo, delay none) took 6.75 HPIPM
# iterations per step with mu0 10 and 1e-3, 7.0 with mu0 100 and 1e-3, 7.8 with 100 and 1e-4, 10.0 with 1e3 and 1e-4,
# all with the same drift (0.72 cm/s) and velocity RMSE (0.174 m/s). 1e-2: 5.67 iterations against 6.64 with 1e-3
# (10 s, each step's CPU time as delay: 8.7 against 8.9-9.5 ms, 0 failed steps either way, base velocity RMSE 0.073
# both; at a fixed 16 ms delay 0 failed steps, RMSE 0.070): the real-time step is the CPU budget that matters
FLAT_FOOT_RTI_QP_TOLERANCE = 1e-2
FALLBACK_FIRST_CALLS = 20  # RtiConfig.fallback_first_calls on point feet
# ... on flat feet: g1's failed QPs fail in "balance" too (the state, not the mode: iteration cap in both), and its
# 20 balance-first QPs after each took 13.7 ms a step in real time against 8.2 with speed_abs first
FLAT_FOOT_FALLBACK_FIRST_CALLS = 0


@dataclass(frozen=True)
class RtiConfig:
    """Settings of the RTI step (pass them as `SolverConfig(name="rti", extra_options={...})`)."""

    sqp_iterations: int = 1  # 1 = real-time iteration; more iterate at the same data (tests, benchmarks)
    hessian_regularization: float = 1e-6  # delta of H + delta I: keeps HPIPM's Riccati recursion positive definite
    # HPIPM mode: speed_abs, speed, balance, robust. speed_abs (absolute tolerances): b1_z1's compiled closed-loop trot
    # 4.20 ms of CPU per RTI step against 4.65 with speed (3.74 QP iterations against 3.93, same run); after pushes it
    # solves QPs on which speed stops at its minimum step length (see solvers/anytime.py)
    qp_mode: str = "speed_abs"
    fallback_qp_mode: str | None = "balance"  # re-solves a QP the first mode failed (speed stalls on a few go2 QPs)
    # after a QP the first mode failed, the fallback mode goes first for this many calls: after a push
    # `speed` fails (minimum step length) on most QPs for a while, each failure a wasted ~20 iterations.
    # None: FALLBACK_FIRST_CALLS, 0 on an OCP with flat feet (FLAT_FOOT_FALLBACK_FIRST_CALLS)
    fallback_first_calls: int | None = None
    qp_options: dict = field(default_factory=dict)  # further HPIPM arguments (solvers/qp.py QpConfig.hpipm_options)
    # "direct": our HPIPM binding (solvers/hpipm_direct.py, compiled once into the cache), casadi's hpipm conic where it
    # cannot be built (a warning, the reason in `direct_error`); "casadi": the conic (qp_options are its options)
    hpipm_binding: str = "direct"
    step_tolerance: float = 1e-8  # sqp_iterations > 1 stop once max |step| is below this
    # HPIPM's residual tolerances (the NLP tolerance of SolverConfig is not the QP's): one inexact SQP step
    # per MPC step needs no tighter QP; 1e-4 against 1e-6: same closed loop (trot, arm-track), ~10 % fewer
    # QP iterations; iterate to Fatrop's KKT point (sqp_iterations > 1) with a tighter one. None: QP_TOLERANCE,
    # FLAT_FOOT_RTI_QP_TOLERANCE for one iteration per step (sqp_iterations 1) on an OCP with flat feet
    qp_tolerance: float | None = None
    # HPIPM's mu0 (QpConfig.barrier_init is casadi conic's best, 100): on our own HPIPM binding, b1_z1's compiled closed-loop
    # trot takes 3.17 QP iterations per RTI step with 1e3 against 4.36 with 100 (2.73 / 3.29 ms of CPU per step, same run)
    # None: 1e3 on our binding (DIRECT_QP_BARRIER_INIT; FLAT_FOOT_QP_BARRIER_INIT on an OCP with flat feet), casadi
    # conic's 100 on the conic (1e3 there: the anytime SQP's QPs stall at HPIPM's minimum step length on go2)
    qp_barrier_init: float | None = None
    # our HPIPM binding leaves the inputs with lb == ub (swing feet's forces, the arm's commanded force) and the initial
    # state out of the QP (QpConfig.eliminate_fixed, csrc/hpipm_reduce.c): the same QP on smaller Riccati blocks
    # (b1_z1's trot: 9 of 37 inputs a stage; 19 % fewer instructions per QP, callgrind); False keeps them
    qp_eliminate_fixed: bool = True
    # our binding tries "no inequality active" first (QpConfig.active_set_guess, csrc/hpipm_eqelim.c): the equality rows
    # eliminated, one Riccati factorisation instead of HPIPM's ~3 interior-point iterations; the interior point where an
    # inequality comes out violated (then for 8 calls directly). b1_z1's trot: right on 200 of 200 recorded QPs
    qp_active_set_guess: bool = True
    # a step whose QP fails is replaced by a converged Fatrop solve from the same guess with this initial
    # barrier (compiled when the RTI is); None: the failure is returned (the MPC's own fallback follows)
    recovery_barrier_init: float | None = 0.1
    # its iteration cap: a converged re-solve after a push can take 100+ iterations (~0.5 s); a run whose
    # plant does not wait for the solver caps it (the runner: RECOVERY_ITERATIONS_DELAYED) and holds the last plan
    recovery_max_iterations: int = 300

    def __post_init__(self):
        if self.sqp_iterations < 1:
            raise ConfigError(f"sqp_iterations must be >= 1, got {self.sqp_iterations}")
        for mode in (self.qp_mode, self.fallback_qp_mode):
            if mode is not None and mode not in HPIPM_MODES:
                raise ConfigError(f"unknown HPIPM mode '{mode}'; available modes: {', '.join(HPIPM_MODES)}")
        if self.hpipm_binding not in HPIPM_BINDINGS:
            raise ConfigError(f"unknown hpipm_binding '{self.hpipm_binding}'; available: {', '.join(HPIPM_BINDINGS)}")
        if self.fallback_first_calls is not None and self.fallback_first_calls < 0:
            raise ConfigError(f"fallback_first_calls must be >= 0, got {self.fallback_first_calls}")
        if self.recovery_max_iterations < 1:
            raise ConfigError(f"recovery_max_iterations must be >= 1, got {self.recovery_max_iterations}")
        if self.qp_tolerance is not None and not self.qp_tolerance > 0:
            raise ConfigError(f"qp_tolerance must be positive or None, got {self.qp_tolerance}")
        if not self.hessian_regularization >= 0:
            raise ConfigError(f"hessian_regularization must be >= 0, got {self.hessian_regularization}")

    @classmethod
    def from_options(cls, options: dict) -> "RtiConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            kind = "RTI" if cls is RtiConfig else "anytime SQP"
            raise ConfigError(f"unknown {kind} option(s) {', '.join(unknown)} (--solver-option); available: "
                              f"{', '.join(sorted(known))}")
        return cls(**options)


def qp_defaults(rti: RtiConfig, flat_feet: bool) -> tuple[float, float]:
    """HPIPM's (tolerance, mu0) on our binding: RtiConfig's where given, else by the kind of contacts (flat feet:
    an OCP with surface contacts) and, for the tolerance, one iteration per step or more."""
    tolerance = rti.qp_tolerance or (FLAT_FOOT_RTI_QP_TOLERANCE if flat_feet and rti.sqp_iterations == 1
                                     else QP_TOLERANCE)
    return tolerance, rti.qp_barrier_init or (FLAT_FOOT_QP_BARRIER_INIT if flat_feet else DIRECT_QP_BARRIER_INIT)


def fallback_first_calls(rti: RtiConfig, flat_feet: bool) -> int:
    """How many calls after a QP the first mode failed start in the fallback mode: RtiConfig's where given,
    else by the kind of contacts."""
    if rti.fallback_first_calls is not None:
        return rti.fallback_first_calls
    return FLAT_FOOT_FALLBACK_FIRST_CALLS if flat_feet else FALLBACK_FIRST_CALLS


class RtiSolver:
    """One SQP iteration with a Gauss-Newton Hessian per call, built once per OCP structure."""

    solver_name = "rti"

    def __init__(self, problem: OcpProblem, config: SolverConfig = SolverConfig(name="rti"), rti: RtiConfig | None = None):
        if config.name != self.solver_name:
            raise ConfigError(f"{type(self).__name__} needs SolverConfig(name='{self.solver_name}'), got '{config.name}'")
        self.problem = problem
        self.config = config
        self.rti = rti or RtiConfig.from_options(config.extra_options)
        self.compile_report: CompileReport | None = None
        self.compile_error: str | None = None
        self.last_timing: dict[str, float] = {}
        self._recovery: NlpSolver | None = None
        self._fallback_first = 0  # calls left that start with the fallback QP mode
        nlp = problem.nlp
        x, p = nlp["x"], nlp["p"]
        functions = self._compiled_functions() if config.compiled else None
        if functions is None:
            functions = {
                "nlp": ca.Function("nlp", [x, p], [nlp["f"], nlp["g"]]),
                "nlp_jac_g": ca.Function("nlp_jac_g", [x, p], [nlp["g"], ca.jacobian(nlp["g"], x)]),
                "nlp_grad_f": ca.Function("nlp_grad_f", [x, p], [ca.gradient(nlp["f"], x)]),
            }
        self._nlp = BufferedFunction(functions["nlp"])
        hessian = ca.hessian(nlp["f"], x)[0] + self.rti.hessian_regularization * ca.SX.eye(problem.n_variables)
        hessian_function = ca.Function("rti_hessian", [x, p], [hessian])
        # the Gauss-Newton Hessian of the [q, v] formulations depends on the weights (p) alone: once per call
        self.hessian_depends_on_x = bool(ca.depends_on(hessian, x))
        # ... and on few of the parameters (the weights): kept between calls while those stay (RTI: one call per step)
        self._hessian_p_index = None if self.hessian_depends_on_x else \
            np.unique(np.asarray(hessian_function.sparsity_jac(1, 0).get_col(), dtype=int))
        self._hessian_cache: tuple[np.ndarray, object] | None = None
        sparsity = (hessian_function.sparsity_out(0), functions["nlp_jac_g"].sparsity_out(1))
        self.jacobian_sparsity = sparsity[1]
        tolerance, barrier_init = qp_defaults(self.rti, bool(problem.surface_feet))
        self.fallback_first_calls = fallback_first_calls(self.rti, bool(problem.surface_feet))
        qp_config = QpConfig(mode=self.rti.qp_mode, tolerance=tolerance, max_iterations=config.max_iterations,
                             barrier_init=barrier_init, hpipm_options=dict(self.rti.qp_options),
                             eliminate_fixed=self.rti.qp_eliminate_fixed,
                             active_set_guess=self.rti.qp_active_set_guess)
        # HPIPM through our shim (solvers/hpipm_direct.py) where it builds: H, J and the gradient as NumPy nonzeros
        # from buffered calls (b1_z1: Jacobian 0.20 ms against 0.48 ms for a DM, whose nonzeros cost 0.6 ms more);
        # otherwise casadi's conic on DMs
        self._qp_sparsity = sparsity
        self.direct_qp = self.rti.hpipm_binding == "direct" and not self.rti.qp_options
        self.direct_error: str | None = None if self.direct_qp else (
            "qp_options are casadi conic options" if self.rti.qp_options else "hpipm_binding 'casadi' asked for")
        self.qp = self._new_qp(qp_config)
        fallback_mode = self.rti.fallback_qp_mode
        self.fallback_qp = (self._new_qp(replace(qp_config, mode=fallback_mode))
                            if fallback_mode not in (None, self.rti.qp_mode) else None)
        if self.direct_qp:
            self._jacobian = BufferedFunction(functions["nlp_jac_g"])
            self._gradient = _first_output(BufferedFunction(functions["nlp_grad_f"]))
            self._hessian = _first_output(BufferedFunction(hessian_function))
            sp = self.jacobian_sparsity  # row and column of each Jacobian nonzero: J' lam for the dual residual
            self._jacobian_rows_cols = (np.asarray(sp.row()), np.repeat(np.arange(sp.size2()), np.diff(sp.colind())))
        else:
            self._jacobian, self._gradient, self._hessian = functions["nlp_jac_g"], functions["nlp_grad_f"], hessian_function

    def _weights_hessian(self, x, p):
        """The QP Hessian; where it depends on the parameters alone, the last one while those entries of p stay."""
        index = self._hessian_p_index
        if index is None:
            return self._hessian(x, p)
        key = np.asarray(p, dtype=float).ravel()[index]
        if self._hessian_cache is None or not np.array_equal(self._hessian_cache[0], key):
            H = self._hessian(x, p)
            self._hessian_cache = (key, H.copy() if isinstance(H, np.ndarray) else H)  # buffered outputs are reused
        return self._hessian_cache[1]

    def _new_qp(self, config: QpConfig):
        """A QP of this problem's structure: on the direct binding while it builds, else casadi's conic (which
        runs HPIPM's "speed" for "speed_abs", see `hpipm_direct.conic_config`). The first failure to build the
        binding warns once and switches every later QP to the conic (the linearisation then returns DMs)."""
        if self.direct_qp:
            qp, error = make_qp(self.problem, *self._qp_sparsity, config, self.config.codegen)
            if error is None:
                return qp
            if getattr(self, "qp", None) is not None:  # a QP already built on the binding: keep one kind
                raise ConfigError(f"HPIPM's direct binding failed after a first QP was built on it: {error}")
            self.direct_qp, self.direct_error = False, error
            warnings.warn(f"HPIPM's direct binding is unavailable, using casadi's hpipm conic (slower): {error}",
                          RuntimeWarning, stacklevel=3)
        if self.rti.qp_barrier_init is None:
            config = replace(config, barrier_init=QpConfig.barrier_init)
        return StructuredQp(self.problem, *self._qp_sparsity, conic_config(config))

    def _regular(self, J) -> bool:
        """No NaN/inf in the Jacobian (a DM checks in C++)."""
        return bool(np.all(np.isfinite(J))) if isinstance(J, np.ndarray) else J.is_regular()

    def _jacobian_transpose_times(self, J, lam: np.ndarray) -> np.ndarray:
        """J' lam for a DM or the Jacobian's nonzero buffer."""
        if not isinstance(J, np.ndarray):
            return np.asarray(ca.mtimes(ca.DM(lam).T, J)).ravel()
        # a sum over J's nonzeros by column: 0.04 ms on b1_z1 (a scipy CSC view built per call: 0.6 ms)
        rows, cols = self._jacobian_rows_cols
        return np.bincount(cols, weights=J * lam[rows], minlength=self.jacobian_sparsity.size2())

    @property
    def is_compiled(self) -> bool:
        return self.compile_report is not None

    def _compiled_functions(self) -> dict[str, ca.Function] | None:
        """The compiled library the Fatrop solver uses (same code, same cache entry), or None."""
        try:
            self.compile_report = compile_nlp(self.problem, "fatrop", self.config.codegen)
        except CompileError as exc:
            self.compile_error = str(exc)
            warnings.warn(f"compiled RTI unavailable, using the non-compiled one: {exc}", RuntimeWarning, stacklevel=3)
            return None
        library = str(self.compile_report.library)
        return {name: ca.external(name, library) for name in ("nlp", "nlp_jac_g", "nlp_grad_f")}

    def _recovery_solver(self) -> NlpSolver:
        """Fatrop on the same problem (compiled on the RTI's library when the RTI is), built on first need.
        It keeps one nlpsol per row-count pattern, so its options hold after contact switches."""
        if self._recovery is None:
            config = SolverConfig(name="fatrop", barrier_init=self.rti.recovery_barrier_init,
                                  max_iterations=self.rti.recovery_max_iterations, warm_barrier_init=None,
                                  compiled=self.compile_report is not None, codegen=self.config.codegen)
            self._recovery = NlpSolver(self.problem, config, compile_report=self.compile_report)
        return self._recovery

    @property
    def recovery_solver(self) -> NlpSolver | None:
        """The Fatrop re-solve of failed QPs, once built (`prepare_recovery` or a first failure), else None."""
        return self._recovery

    def prepare_recovery(self) -> None:
        """Build the Fatrop re-solve of failed QPs now rather than at the first failure."""
        if self.rti.recovery_barrier_init is not None:
            self._recovery_solver()

    def _recover(self, failed: NlpResult, p, lbx, ubx, lbg, ubg, x0) -> NlpResult:
        result = self._recovery_solver().solve(p, lbx, ubx, lbg, ubg, x0)
        result.stats.status = f"{result.stats.status} (fatrop recovery after rti: {failed.stats.status})"
        result.stats.solve_time_s += failed.stats.solve_time_s
        result.stats.iterations += failed.stats.iterations
        self.last_timing["recovery_ms"] = 1e3 * (result.stats.solve_time_s - failed.stats.solve_time_s)
        return result

    def _solve_qp(self, qp_data) -> tuple[QpResult, float, int]:
        """The QP in the first HPIPM mode, re-solved in the fallback mode if that fails (which then goes first
        for `fallback_first_calls` calls). Returns the result, the time in HPIPM (without the binding's packing,
        which the step's split counts outside the solver) and the iterations of both attempts."""
        qps = [(qp, qp.config.mode if qp is not None else None) for qp in (self.qp, self.fallback_qp)]
        if self._fallback_first > 0:
            self._fallback_first -= 1
            qps.reverse()
        result = qps[0][0].solve(*qp_data)
        spent_s, iterations = result.solve_time_s - result.pack_s, max(result.iterations, 0)
        if not result.success and self.fallback_qp is not None:
            first = result.status
            result = qps[1][0].solve(*qp_data)
            spent_s, iterations = spent_s + result.solve_time_s - result.pack_s, iterations + max(result.iterations, 0)
            result.status = f"{result.status} ({qps[1][1]} after {qps[0][1]}: {first})"
            if qps[0][0] is self.qp:
                self._fallback_first = self.fallback_first_calls
        return result, spent_s, iterations

    def constraint_violation(self, x, p, lbx, ubx, lbg, ubg) -> float:
        return bound_violation(x, self._nlp(x, p)[1], lbx, ubx, lbg, ubg)

    def _failure(self, x0, status: str) -> NlpResult:
        return failed_result(self.problem, x0, status)

    def solve(self, p, lbx, ubx, lbg, ubg, x0, lam_g0=None, lam_x0=None, warm_start: bool = False) -> NlpResult:
        """Linearise at x0, solve the QP, take the full step (repeated `sqp_iterations` times).

        `stats.iterations` counts HPIPM's interior-point iterations of all QPs of the call.
        """
        x = np.asarray(x0, dtype=float).copy()
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(x))):
            return self._failure(x0, "invalid_input_nan")
        if np.any(np.asarray(lbx) > np.asarray(ubx)) or np.any(np.asarray(lbg) > np.asarray(ubg)):
            return self._failure(x0, "invalid_bounds")
        start, cpu_start = time.perf_counter(), time.process_time()
        timing = {"linearize": 0.0, "qp": 0.0}
        qp_iterations, lam_g, lam_x, status, success = 0, None, None, "not_started", False
        for _ in range(self.rti.sqp_iterations):
            tic = time.perf_counter()
            g, J = self._jacobian(x, p)
            g = np.asarray(g).ravel()
            if not (np.all(np.isfinite(g)) and self._regular(J)):
                return self._failure(x0, "invalid_input_nan_constraints")
            gradient = self._gradient(x, p)
            H = self._weights_hessian(x, p)
            timing["linearize"] += time.perf_counter() - tic
            result, spent_s, iterations = self._solve_qp((H, gradient, J, lbg - g, ubg - g, lbx - x, ubx - x))
            timing["qp"] += spent_s
            qp_iterations += iterations
            status, success = result.status, result.success
            if not success:
                break
            x = x + result.step
            lam_g, lam_x = result.lam_g, result.lam_x
            if self.rti.sqp_iterations > 1 and np.max(np.abs(result.step), initial=0.0) < self.rti.step_tolerance:
                break
        result = self._result(x, p, (lbx, ubx, lbg, ubg), lam_g, lam_x, status, success, qp_iterations, timing,
                              start, cpu_start)
        if not result.stats.success and self.rti.recovery_barrier_init is not None:
            result = self._recover(result, p, lbx, ubx, lbg, ubg, x0)
        return result

    def _result(self, x, p, bounds, lam_g, lam_x, status: str, success: bool, qp_iterations: int, timing: dict,
                start: float, cpu_start: float) -> NlpResult:
        """The step's result: cost and bound violation at the new iterate (NaN where the QP failed), timings."""
        tic = time.perf_counter()
        if success:
            f, g = self._nlp(x, p)
            cost = float(f[0])
            finite = bool(np.all(np.isfinite(g)))
            viol = bound_violation(x, g, *bounds) if finite else float("inf")
            success = finite
        else:
            x, cost, viol = np.full_like(x, np.nan), float("nan"), float("inf")
        evaluate_s = time.perf_counter() - tic
        elapsed = time.perf_counter() - start
        linearize_s, qp_s = timing["linearize"], timing["qp"]
        self.last_timing = {"linearize_ms": 1e3 * linearize_s, "qp_ms": 1e3 * qp_s, "evaluate_ms": 1e3 * evaluate_s,
                            "other_ms": 1e3 * (elapsed - linearize_s - qp_s - evaluate_s),
                            "cpu_ms": 1e3 * (time.process_time() - cpu_start)}  # this process's CPU time (load-independent)
        if success and self.config.time_limit_s and elapsed > self.config.time_limit_s:
            status = "time_limit_exceeded"  # as NlpSolver: flagged, the step itself is fine
        n = self.problem.n_constraints
        return NlpResult(
            x=x,
            lam_g=lam_g if lam_g is not None else np.zeros(n),
            lam_x=lam_x if lam_x is not None else np.zeros_like(x),
            stats=SolverStats(status=status, success=success, iterations=qp_iterations, solve_time_s=elapsed,
                              max_constraint_violation=viol, cost=cost, cpu_time_s=self.last_timing["cpu_ms"] / 1e3,
                              split_ms={"linearize": self.last_timing["linearize_ms"], "qp": self.last_timing["qp_ms"],
                                        "evaluate": self.last_timing["evaluate_ms"],
                                        "outside_solver": self.last_timing["other_ms"]}),
        )


def _first_output(function: BufferedFunction):
    """A buffered function returning its first output alone (as a plain call of a one-output Function does)."""
    return lambda *args: function(*args)[0]
