"""Fatrop without casadi's nlpsol (`--solver fatrop-direct`): our compiled stage functions called by Fatrop.

casadi's Fatrop plugin builds a new Fatrop instance in every solve, evaluates whole-NLP functions and
copies each stage block out of their sparse results (the `interface` and `outside_solver` parts of
a solve's time split). Here a C shim (`fatrop_shim.py`) answers Fatrop's callbacks from the problem's compiled
stage functions (`stage_library.py`), every stage's evaluation on a small thread pool (`SolverConfig.threads`;
the same iterates on any thread count), Fatrop instances are kept per row-count pattern (like `NlpSolver`) and
options such as mu_init and max_iter change between calls on the same instance.

Same problem, same row split and multiplier signs as casadi's plugin: the two solve to the same
KKT point (tests/solvers/test_fatrop_direct.py). `solve` has `NlpSolver.solve`'s contract, including its
small-barrier warm attempt. Two things casadi's Fatrop cannot do (see `csrc/fatrop_driver.cpp`):
a multiplier warm start (warm-started MPC calls start the equality multipliers from the Fatrop
instance's last converged solution instead of Fatrop's least-squares estimate, which costs one KKT
factorisation; `extra_options={"warm_duals": False}` turns it off; on flat feet the MPC hands the last plan's
multipliers moved by constraint identity instead, `takes_multipliers`) and a time limit per call
(`solve(..., max_iterations=, time_limit_s=)`, for anytime use: the last accepted iterate is returned).

Its own tolerances for MPC steps (`fatrop_settings`: `MPC_TOLERANCE` or on flat feet `FLAT_FEET_MPC_TOLERANCE`,
`MPC_CONSTRAINT_TOLERANCE`) apply while SolverConfig keeps its defaults. Fatrop's equality elimination runs on our AVX2 kernels (`csrc/fatrop_kernels.cpp`, same iterates;
`extra_options={"fatrop_kernels": False}` leaves Fatrop's own), and its Riccati products with the sparse dynamics and
inequality Jacobians on sparsity-aware ones (`csrc/fatrop_sparse.cpp`; `{"sparse_products": False}`: BLASFEO's).

When the shim cannot be built (no compiler, no Fatrop headers or library in the casadi wheel) the
solver falls back to casadi's nlpsol Fatrop with a RuntimeWarning; `direct_error` says why (None
when the direct binding runs).
"""

from __future__ import annotations

import ctypes
import time
import warnings
from dataclasses import replace

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers import stage_library
from wbmpc.solvers.codegen import CompileError, CompileReport
from wbmpc.solvers.fatrop_settings import (
    MPC_ITERATIVE_REFINEMENT,
    MPC_TOLERANCE,
    QUIET_ITERATIONS,
    REHEARSAL_ITERATIONS,
    default_threads,
    mpc_tolerances,
    multiplier_start,
)
from wbmpc.solvers.fatrop_shim import FatropUnavailable, ShimLibrary, build_shim
from wbmpc.solvers.nlp import (
    _FATROP_FLAGS,
    NlpResult,
    NlpSolver,
    SolverConfig,
    SolverStats,
    bound_violation,
    failed_result,
)

NAME = "fatrop-direct"
# Fatrop instances kept per solver, the least recently used freed beyond: one per row-count pattern (the contact
# schedule over the horizon) takes ~25 MB on g1 (BLASFEO blocks of every stage), its first build ~10 ms CPU, mostly
# page faults on fresh memory. g1 walking meets ~30 patterns in its first gait cycle and none after, which all
# stay; a bound below a cycle's patterns rebuilds one at every change (8: 135 rebuilds of 2.7 ms in 3 s against 30
# of 11 ms). The bound keeps gaits and terrains with ever new patterns from growing the process without limit
MAX_INSTANCES = 48
_N_STATS = 15
# wb_solve's codes of a call that did not solve (csrc/fatrop_shim.c), as statuses
_REFUSED = {-1: "solver_exception: Fatrop raised (see its output with print_level > 0)",
            -2: "solver_exception: row structure changed under the solver", -4: "invalid_input_nan_constraints",
            -5: "invalid_input_nan", -6: "invalid_bounds"}
_INVALID_INPUTS = (_REFUSED[-5], _REFUSED[-6])
_C_DOUBLE = ctypes.c_double
_F64 = np.dtype(np.float64)
_DOUBLE_P = ctypes.POINTER(_C_DOUBLE)


def _ptr(array: np.ndarray):
    return array.ctypes.data_as(_DOUBLE_P)


def _refs(arrays) -> list:
    """float64 arrays' data as ctypes arguments for double* (c_doubles over their buffers: ~3x cheaper than
    `array.ctypes.data`, whose object NumPy builds at every access; read-only arrays go that way)."""
    try:
        return [_C_DOUBLE.from_buffer(array) for array in arrays]
    except (TypeError, ValueError):  # a read-only (or empty) array
        return [array.ctypes.data_as(_DOUBLE_P) for array in arrays]


def _f64(values) -> np.ndarray:
    """values as a 1-D C-contiguous float64 array: itself when it is one (the MPC's), else a converted copy."""
    if type(values) is np.ndarray and values.dtype is _F64 and values.ndim == 1 and values.flags.c_contiguous:
        return values
    return np.ascontiguousarray(values, dtype=_F64).ravel()


class FatropDirectSolver:
    """Fatrop through its OCP C interface on our compiled stage functions (see the module docstring)."""

    def __init__(self, problem: OcpProblem, config: SolverConfig = SolverConfig(name=NAME),
                 library: ShimLibrary | None = None):
        if config.name != NAME:
            raise ConfigError(f"FatropDirectSolver needs SolverConfig(name='{NAME}'), got '{config.name}'")
        self.problem, self.config = problem, config
        self.direct_error: str | None = None
        self.compile_error: str | None = None
        self._fallback: NlpSolver | None = None
        self._library = library
        if library is None:
            try:
                self._library = ShimLibrary(build_shim(config.codegen), stage_library.build(problem, config.codegen))
            except (CompileError, FatropUnavailable, OSError) as exc:
                self.direct_error = self.compile_error = str(exc)
                warnings.warn(f"the direct Fatrop binding is unavailable, using casadi's Fatrop: {exc}",
                              RuntimeWarning, stacklevel=2)
                self._fallback = NlpSolver(problem, replace(config, name="fatrop"))
                return
        lib = self._library
        self.threads = default_threads() if config.threads is None else config.threads
        self._ctx = lib.context(self.threads)
        # inputs with lb == ub eliminated (csrc/stage_layout.c); False: equality rows, as in casadi's plugin
        self.eliminate_fixed_inputs = bool(config.extra_options.get("eliminate_fixed_inputs", True))
        lib.lib.wb_ctx_eliminate_fixed(self._ctx, int(self.eliminate_fixed_inputs))
        n_stages, _, n_variables, n_constraints = lib.sizes(self._ctx)
        if (n_variables, n_constraints) != (problem.n_variables, problem.n_constraints):
            raise ConfigError("the compiled stage library belongs to another problem structure")
        self._by_structure: dict[bytes, ctypes.c_void_p] = {}
        self._last_solver: ctypes.c_void_p | None = None
        self._stage_x_starts = np.array([state.start for state, _ in problem.stage_slices])
        self._input_vars = np.concatenate([np.arange(inputs.start, inputs.stop) for _, inputs in problem.stage_slices])
        self._input_starts = np.concatenate([[0], np.cumsum([i.stop - i.start for _, i in problem.stage_slices])])
        self._warm_pause = 0
        self._quiet = False  # the last warm attempt converged within QUIET_ITERATIONS
        self.last_start = "cold"  # the last call's first attempt: "cold", "instance" or "given" multipliers
        self._warm_failures = 0
        self._options: dict[int, tuple] = {}  # per Fatrop instance: the (mu_init, max_iter, print_level) set
        self._bind_buffers(problem)
        # MPC warm starts (the small-barrier attempt) start the equality multipliers from the instance's last
        # converged solution instead of Fatrop's least-squares estimate (one KKT factorisation less)
        self.warm_duals = bool(config.extra_options.get("warm_duals", True))
        # warm attempts from the multipliers the MPC moves by constraint identity (ocp/multipliers.py) instead of this
        # instance's by position (a stage's rows change places with the contacts): on flat feet by default
        self.takes_multipliers, self.multiplier_barrier_init, self.multiplier_max_iterations = \
            multiplier_start(config, bool(problem.surface_feet))
        self.tolerance, self.constraint_tolerance = mpc_tolerances(config, bool(problem.surface_feet))
        # Fatrop's equality elimination on our AVX2 kernels (csrc/fatrop_kernels.cpp) and its products with the sparse
        # dynamics and inequality Jacobians on ours (csrc/fatrop_sparse.cpp); process-wide, same iterates
        self.kernels = self.set_elimination_kernels(True, bool(config.extra_options.get("sparse_products", True))) \
            if config.extra_options.get("fatrop_kernels", True) else False
        # the first step's one-off costs now, before any clock runs (b1_z1, fresh processes on a loaded machine: first
        # closed-loop solve 24.0 -> 20.5 ms on average over 3 pairs; it stays the cold one: 5 iterations, least-squares duals)
        if self.threads not in lib.warmed_up:
            lib.lib.wb_warm_up(self._ctx)
            lib.warmed_up.add(self.threads)

    def _bind_buffers(self, problem: OcpProblem) -> None:
        """The buffers wb_solve writes (stage parameters; x, lam_g, lam_x and the stats of the last call, results
        being copies of them), their addresses given to the shim once, and the positions of the stages' parameters
        in the NLP's p: the shim gathers them and checks p, x0 and the bounds itself."""
        lib = self._library
        self._stage_p = np.zeros(lib.p_index.shape)
        self._out = (np.zeros(problem.n_variables), np.zeros(problem.n_constraints), np.zeros(problem.n_variables))
        self._g = np.zeros(problem.n_constraints)
        self._stats = np.zeros(_N_STATS)
        lib.lib.wb_ctx_outputs(self._ctx, *(a.ctypes.data for a in (self._stage_p, *self._out, self._stats)))
        n_x, n_g = problem.n_variables, problem.n_constraints
        self._input_sizes = (problem.params.size, n_x, n_x, n_g, n_g, n_x)  # p, lbx, ubx, lbg, ubg, x0
        p_index = np.ascontiguousarray(lib.p_index, dtype=np.int64)
        if lib.lib.wb_ctx_parameters(self._ctx, p_index.ctypes.data, problem.params.size) != 0:
            raise ConfigError("the compiled stage library's parameter positions do not fit this problem's p")

    # ---------------------------------------------------------------- NlpSolver's interface
    @property
    def compile_report(self) -> CompileReport | None:
        return self._fallback.compile_report if self._fallback else self._library.report

    @property
    def is_compiled(self) -> bool:
        return self._fallback.is_compiled if self._fallback else True

    @property
    def is_direct(self) -> bool:
        return self._fallback is None

    @property
    def structure_keys(self) -> tuple[bytes, ...]:
        """The row-count patterns (`structure_key`) a Fatrop instance was built for so far."""
        return tuple(self._by_structure) if self._fallback is None else self._fallback.structure_keys

    def set_elimination_kernels(self, enabled: bool, sparse_products: bool = True) -> bool:
        """Fatrop's equality elimination on our AVX2 kernels (True; with `sparse_products` also its products with the
        sparse dynamics and inequality Jacobians) or its own and BLASFEO's (False), process-wide; whether ours are in
        place afterwards (False where they cannot be: no AVX2/FMA build, BLASFEO panels not 4 rows)."""
        if self._fallback is not None:
            return False
        mode = (1 if sparse_products else 2) if enabled else 0
        return self._library.lib.wbd_fatrop_kernels(mode) > 0

    @property
    def evaluation_threads(self) -> int:
        """Threads the shim's context evaluates the stages on (the caller and its pool)."""
        return 1 if self._fallback is not None else int(self._library.lib.wb_ctx_threads(self._ctx))

    def recreated(self, **changes) -> "FatropDirectSolver | NlpSolver":
        """A fresh solver on the same problem and compiled shim with some settings changed."""
        if self._fallback is not None:
            return self._fallback.recreated(**changes)
        return FatropDirectSolver(self.problem, replace(self.config, **changes), library=self._library)

    def __del__(self):
        lib = getattr(self, "_library", None)
        if lib is None or getattr(self, "_ctx", None) is None:
            return
        for solver in self._by_structure.values():
            lib.lib.wb_solver_free(solver)
        lib.lib.wb_ctx_free(self._ctx)

    def stage_parameters(self, p) -> np.ndarray:
        """(N+1, n_p) stage parameters, row k = `problem.stage_parameters(p, k)` (a buffer the next call reuses)."""
        return np.take(np.asarray(p, dtype=float).ravel(), self._library.p_index, out=self._stage_p)

    def constraints(self, x, p) -> np.ndarray:
        """g(x) of the NLP, evaluated by the shim's compiled stage functions."""
        if self._fallback is not None:
            return np.asarray(self._fallback._g(x, p)[0]).ravel()
        stage_p, x = self.stage_parameters(p), _f64(x)
        self._library.lib.wb_eval_g(self._ctx, _ptr(stage_p), _ptr(x), _ptr(self._g))
        return self._g.copy()

    def stage_derivatives(self, x, p, lam_g, sigma: float = 1.0) -> list[dict[str, np.ndarray]]:
        """Per stage, in Fatrop's (u_k, x_k) order: the cost gradient `grad`, the Hessian `hess` of the stage's
        Lagrangian (sigma l and its rows' terms, lam_g with the NLP's signs) and the Jacobians `jac_next` (of f, the
        next state) and `jac_rows` (of the path rows), evaluated by the shim on its threads."""
        if self._fallback is not None:
            raise ConfigError(f"the direct binding is unavailable ({self.direct_error}): no stage derivatives")
        stage_p, x, lam_g = self.stage_parameters(p), _f64(x), _f64(lam_g)
        problem = self.problem
        shapes = []
        for k, (state, inputs) in enumerate(problem.stage_slices):
            n = inputs.stop - state.start
            n_next = problem.nx if k < problem.N else 0
            n_rows = (problem.stage_row_starts[k + 1] if k < problem.N else problem.n_constraints) - \
                problem.stage_row_starts[k] - n_next
            shapes.append({"grad": (n,), "hess": (n, n), "jac_next": (n_next, n), "jac_rows": (int(n_rows), n)})
        out = np.empty(sum(int(np.prod(shape)) for block in shapes for shape in block.values()))
        self._library.lib.wb_eval_derivatives(self._ctx, _ptr(stage_p), _ptr(x), float(sigma), _ptr(lam_g), _ptr(out))
        blocks, offset = [], 0
        for block in shapes:
            stage = {}
            for name, shape in block.items():  # the shim's column-major transposed blocks are row-major J
                size = int(np.prod(shape))
                stage[name] = out[offset:offset + size].reshape(shape).copy()
                offset += size
            blocks.append(stage)
        return blocks

    def constraint_violation(self, x, p, lbx, ubx, lbg, ubg) -> float:
        return bound_violation(x, self.constraints(x, p), lbx, ubx, lbg, ubg)

    def structure_key(self, lbx, ubx, lbg, ubg) -> bytes:
        """NlpSolver's per-stage row counts and, per stage, the inputs with lb == ub: the shim eliminates them
        (Fatrop's input dimension)."""
        rows = NlpSolver.structure_key(self, lbx, ubx, lbg, ubg)  # same counting, same attributes
        if not self.eliminate_fixed_inputs:
            return rows
        inputs = self._input_vars
        fixed = np.concatenate([[0], np.cumsum(np.asarray(lbx)[inputs] == np.asarray(ubx)[inputs])])
        return rows + (fixed[self._input_starts[1:]] - fixed[self._input_starts[:-1]]).astype(np.int32).tobytes()

    def prepare_structure(self, lbx, ubx, lbg, ubg) -> None:
        """Build the Fatrop instance of these bounds' row pattern now, not at the first step that meets it (a first
        build costs ~11 ms of CPU on g1: allocation and first-touch page faults). The same instance as built then."""
        if self._fallback is None:
            self._solver_for(*(_f64(a) for a in (lbx, ubx, lbg, ubg)))

    def prepare_structures(self, steps) -> None:
        """`prepare_structure` for each of `steps` (lbx, ubx, lbg, ubg, p, x0: the first steps of a run), then each
        instance built here rehearsed: solved from its first step's p and x0, capped at REHEARSAL_ITERATIONS, its
        solution forgotten (no later warm start sees it), the first step's instance last, right before the clock."""
        if self._fallback is not None:
            return
        new = {}
        for lbx, ubx, lbg, ubg, p, x0 in steps:
            bounds = tuple(_f64(a) for a in (lbx, ubx, lbg, ubg))
            key = self.structure_key(*bounds)
            if key not in self._by_structure and key not in new:
                new[key] = (p, *bounds, x0)
            self._solver_for(*bounds)
        for key, (p, *bounds, x0) in reversed(new.items()):
            if key in self._by_structure:  # (not freed meanwhile: more patterns than MAX_INSTANCES)
                self._solve(p, *bounds, x0, self.config.barrier_init, REHEARSAL_ITERATIONS)
                self._library.lib.wb_solver_forget(self._by_structure[key])

    def solve(self, p, lbx, ubx, lbg, ubg, x0, lam_g0=None, lam_x0=None, warm_start: bool = False,
              max_iterations: int | None = None, time_limit_s: float | None = None) -> NlpResult:
        """Solve from x0. `warm_start`: first the small-barrier attempt (`SolverConfig.warm_barrier_init`), or with
        `takes_multipliers` one from lam_g0 / lam_x0 (the last plan's, moved by the MPC; not used otherwise). `max_iterations` caps this call;
        `time_limit_s` (default `SolverConfig.time_limit_s`) stops it at the first evaluation after that
        long, returning the last accepted iterate with status `time_limit_reached` (not a success)."""
        if self._fallback is not None:
            return self._fallback.solve(p, lbx, ubx, lbg, ubg, x0, lam_g0, lam_x0, warm_start=warm_start)
        cfg = self.config
        cap = cfg.max_iterations if max_iterations is None else max_iterations
        limit = cfg.time_limit_s if time_limit_s is None else time_limit_s
        deadline = time.perf_counter() + limit if limit else None
        self.last_start = "cold"
        if not warm_start or cfg.warm_barrier_init is None:
            return self._solve(p, lbx, ubx, lbg, ubg, x0, cfg.barrier_init, cap, deadline)
        if self._warm_pause > 0:
            self._warm_pause -= 1
            return self._solve(p, lbx, ubx, lbg, ubg, x0, cfg.barrier_init, cap, deadline)
        offered = self.takes_multipliers and lam_g0 is not None and lam_x0 is not None
        # after a step that converged within QUIET_ITERATIONS (standing) the instance's multipliers, else the given
        given = (lam_g0, lam_x0) if offered and not self._quiet else None
        self.last_start = "instance" if given is None else "given"
        mu_warm, cap_warm = (cfg.warm_barrier_init, cfg.warm_max_iterations) if given is None else \
            (self.multiplier_barrier_init, self.multiplier_max_iterations)
        attempt = self._solve(p, lbx, ubx, lbg, ubg, x0, mu_warm, min(cap_warm, cap), deadline, warm_duals=True,
                              given=given)
        self._quiet = attempt.stats.success and attempt.stats.iterations <= QUIET_ITERATIONS
        if attempt.stats.success or attempt.stats.status == "time_limit_reached":
            self._warm_failures = 0 if attempt.stats.success else self._warm_failures
            return attempt
        if attempt.stats.status in _INVALID_INPUTS:  # refused before any work: a cold attempt would be refused too
            return attempt
        if given is not None or not offered:  # (a quiet step's failed attempt: the given multipliers next step)
            self._warm_pause = cfg.warm_backoff_steps * 2 ** min(self._warm_failures, 3)
            self._warm_failures += 1
        result = self._solve(p, lbx, ubx, lbg, ubg, x0, cfg.barrier_init, cap, deadline)
        stats = result.stats
        stats.iterations += max(attempt.stats.iterations, 0)
        stats.solve_time_s += attempt.stats.solve_time_s
        stats.cpu_time_s += attempt.stats.cpu_time_s
        stats.split_ms = {k: stats.split_ms.get(k, 0.0) + attempt.stats.split_ms.get(k, 0.0)
                          for k in {**stats.split_ms, **attempt.stats.split_ms}}
        stats.status = f"{stats.status} (after mu_init {mu_warm:g}: {attempt.stats.status})"
        return result

    # ---------------------------------------------------------------- internals
    @staticmethod
    def _cpu_s() -> float:
        """CPU time of the process (s): this thread's and the pool's (time.thread_time and the pool's thread clocks
        cost ~13 us each here, a system call; the process clock is read without one)."""
        return time.process_time()

    def _solver_for(self, lbx, ubx, lbg, ubg) -> ctypes.c_void_p:
        key = self.structure_key(lbx, ubx, lbg, ubg)
        solver = self._by_structure.pop(key, None)
        if solver is None:
            lib = self._library.lib
            self._free_least_recent(MAX_INSTANCES - 1)
            solver = ctypes.c_void_p(lib.wb_solver_new(self._ctx, _ptr(lbx), _ptr(ubx), _ptr(lbg), _ptr(ubg),
                                                       int(self.config.print_level > 0)))
            if not solver.value:
                raise RuntimeError("Fatrop could not create a solver for this structure")
            self._set_options(solver)
        self._by_structure[key] = solver  # most recently used last
        return solver

    def _free_least_recent(self, keep: int) -> None:
        """Free the least recently used Fatrop instances beyond `keep` (MAX_INSTANCES)."""
        while len(self._by_structure) > keep:
            solver = self._by_structure.pop(next(iter(self._by_structure)))
            self._options.pop(solver.value, None)  # a new instance may get its address
            if self._last_solver is not None and self._last_solver.value == solver.value:
                self._last_solver = None
            self._library.lib.wb_solver_free(solver)

    def _set_options(self, solver: ctypes.c_void_p) -> None:
        """The tolerances and `extra_options["fatrop"]` on a new Fatrop instance; an option Fatrop does not know
        (or of another type) is refused by name rather than ignored."""
        lib = self._library.lib
        refine = {"max_iterative_refinement": MPC_ITERATIVE_REFINEMENT} if self.tolerance >= MPC_TOLERANCE else {}
        options = {"tolerance": self.tolerance, "constr_viol_tol": self.constraint_tolerance, **refine,
                   **self.config.extra_options.get("fatrop", {})}
        for name, value in options.items():
            setter = {float: lib.wb_option_double, int: lib.wb_option_int, bool: lib.wb_option_bool}.get(type(value))
            if setter is None or setter(solver, name.encode(), value) != 0:
                lib.wb_solver_free(solver)
                raise ConfigError(f"Fatrop has no {type(value).__name__} option {name!r} (SolverConfig.extra_options"
                                  "['fatrop']): check its name and type, e.g. 1e-2 rather than 1 for a real")

    def _solve(self, p, lbx, ubx, lbg, ubg, x0, mu_init: float, max_iterations: int,
               deadline: float | None = None, warm_duals: bool = False, given=None) -> NlpResult:
        """One wb_solve: the shim checks the inputs (finite p and x0, bounds in order: Fatrop can hang on a NaN
        start), gathers the stages' parameters, classifies the rows, solves and unpacks into the preallocated
        outputs; the result holds copies of them."""
        inputs = (_f64(p), _f64(lbx), _f64(ubx), _f64(lbg), _f64(ubg), _f64(x0))
        if (inputs[0].size, inputs[1].size, inputs[2].size, inputs[3].size, inputs[4].size, inputs[5].size) != \
                self._input_sizes:
            self._refuse_sizes(inputs)
        start, start_cpu = time.perf_counter(), self._cpu_s()
        # the driver maps the stored multipliers position by position within each stage: where a gait switch
        # swapped rows between two feet the start is off for those rows only (measured on the b1_z1 trot:
        # requiring the same rows halved the warm starts used and cost 0.5-1 ms CPU per step on average)
        warm = 2 if given is not None else int(warm_duals and self.warm_duals)
        budget_s = 0.0 if deadline is None else max(deadline - time.perf_counter(), 1e-9)
        code = self._call(inputs, mu_init, int(max_iterations), budget_s, warm, given)
        elapsed, cpu = time.perf_counter() - start, self._cpu_s() - start_cpu
        if code < 0:
            return failed_result(self.problem, inputs[5], _REFUSED.get(code, f"solver_exception: shim code {code}"))
        stats = self._stats.tolist()  # Python floats: no NumPy scalars below (every MPC step)
        flag, finite = int(stats[1]), stats[14] > 0  # stats[14]: every entry of x finite (the shim's check)
        status = "time_limit_reached" if code == 3 else _FATROP_FLAGS.get(flag, f"fatrop_flag_{flag}")
        out = self._out
        return NlpResult(x=out[0].copy(), lam_g=out[1].copy(), lam_x=out[2].copy(), stats=SolverStats(
            status=status, success=finite and flag in (0, 2), iterations=int(stats[0]), solve_time_s=elapsed,
            max_constraint_violation=stats[12] if finite else float("inf"), cost=stats[11], cpu_time_s=cpu,
            split_ms=_time_split_ms(stats, elapsed)))

    def _refuse_sizes(self, inputs) -> None:
        names = ("p", "lbx", "ubx", "lbg", "ubg", "x0")
        wrong = [f"{name} has {array.size} entries, the problem {size}"
                 for name, array, size in zip(names, inputs, self._input_sizes) if array.size != size]
        raise ConfigError(f"fatrop-direct's solve got inputs of another problem: {'; '.join(wrong)}")

    def _call(self, inputs, mu_init: float, max_iterations: int, budget_s: float, warm: int, given=None) -> int:
        """wb_solve on the last step's Fatrop instance first (the shim checks the inputs, classifies the rows and
        refuses, -2, another structure without solving, so the row-count key is computed only then: 0.08 ms a step
        otherwise), else on the instance of this structure; results into the preallocated outputs."""
        lib = self._library.lib
        solver = self._last_solver
        p, lbx, ubx, lbg, ubg, x0 = _refs(inputs)
        multipliers = (None, None)
        if given is not None:
            given = _f64(given[0]), _f64(given[1])
            if (given[0].size, given[1].size) != (self.problem.n_constraints, self.problem.n_variables):
                raise ConfigError(f"fatrop-direct's given multipliers have {given[0].size} and {given[1].size} "
                                  f"entries, the problem's lam_g {self.problem.n_constraints} and lam_x "
                                  f"{self.problem.n_variables}")
            multipliers = _refs(given)
        for attempt in range(2):
            if solver is not None:
                options = (mu_init, max_iterations, self.config.print_level)
                if self._options.get(solver.value) != options:  # options hold between calls on an instance
                    lib.wb_option_double(solver, b"mu_init", mu_init)
                    lib.wb_option_int(solver, b"max_iter", max_iterations)
                    lib.wb_option_int(solver, b"print_level", int(options[2]))
                    self._options[solver.value] = options
            # a Ctrl-C meanwhile raises KeyboardInterrupt when the call returns (Fatrop installs no handler);
            # no instance yet: the shim checks the inputs and returns -2 before any work
            code = lib.wb_solve(self._ctx, solver, p, lbx, ubx, lbg, ubg, x0, budget_s, warm, *multipliers, mu_init)
            if code != -2 or attempt:
                break
            solver = self._solver_for(*inputs[1:5])
        self._last_solver = solver if code != -2 else None
        return code


def _time_split_ms(stats: list, elapsed_s: float) -> dict:
    """The solve's time split in `nlp.time_split_ms`'s parts: functions (the generated code, timed by the
    shim), linear algebra, initialization, interface (the shim's C between the NLP's layout and Fatrop's: Fatrop's
    evaluation timers beyond the functions, i.e. packing into BLASFEO, and the shim's work around Fatrop's solve:
    input checks, row classification, unpacking the solution), the rest inside Fatrop, and outside the solver
    (Python, ctypes)."""
    total, search_dir, init, functions = 1e3 * stats[2], 1e3 * stats[3], 1e3 * stats[4], 1e3 * stats[10]
    callbacks, around = 1e3 * (stats[5] + stats[6] + stats[7] + stats[8] + stats[9]), 1e3 * stats[13]
    return {"functions": functions, "linear_algebra": search_dir, "initialization": init,
            "interface": max(callbacks - functions, 0.0) + around,
            "line_search_and_rest": max(total - search_dir - init - max(callbacks, functions), 0.0),
            "outside_solver": max(1e3 * elapsed_s - total - around, 0.0)}
