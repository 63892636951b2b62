"""The direct Fatrop binding's stage evaluations on several threads (SolverConfig.threads) against one thread:
the same derivatives and the same solves bit for bit, on a small go2 problem."""

import ctypes
from pathlib import Path

import numpy as np
import pytest

from tests.solvers.mpc_steps import capture_trot_steps
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.solvers import stage_library
from wbmpc.solvers.codegen import CodegenConfig
from wbmpc.solvers.fatrop_direct import FatropDirectSolver
from wbmpc.solvers.nlp import SolverConfig
from wbmpc.solvers.stage_library import stage_kind_functions

SMALL = OcpConfig(grid=TimeGrid(n_intervals=4, dt_first_s=0.01, dt_last_s=0.04))


@pytest.fixture(scope="module")
def problem(robot):
    return OcpProblem(robot, SMALL)


@pytest.fixture(scope="module")
def codegen(tmp_path_factory):
    return CodegenConfig(flags=("-O0", "-march=native"), cache_dir=tmp_path_factory.mktemp("wbmpc_cache"))


@pytest.fixture(scope="module")
def solvers(problem, codegen):
    one = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen, threads=1))
    assert one.is_direct, one.direct_error
    return {threads: one if threads == 1 else one.recreated(threads=threads) for threads in (1, 2, 3)}


@pytest.fixture(scope="module")
def steps(robot, problem, solvers):
    """p, bounds and guesses of a few trot steps (moving base, contact changes), as the MPC hands them over."""
    mpc = MPC(robot, MpcConfig(ocp=SMALL, recovery=RecoveryConfig(fallback_solver=None)), problem=problem, solver=solvers[1].recreated())
    return capture_trot_steps(mpc, robot)


def test_threads_are_used(solvers):
    assert [solvers[t].threads for t in (1, 2, 3)] == [1, 2, 3]
    assert [solvers[t].evaluation_threads for t in (1, 2, 3)] == [1, 2, 3]


def test_parallel_derivatives_equal_sequential_bitwise(problem, solvers, steps):
    rng = np.random.default_rng(1)
    for step in steps[:3]:
        x = step["x0"] + 1e-3 * rng.normal(size=problem.n_variables)
        lam_g = rng.normal(size=problem.n_constraints)
        sequential = solvers[1].stage_derivatives(x, step["p"], lam_g, sigma=0.7)
        for threads in (2, 3):
            parallel = solvers[threads].stage_derivatives(x, step["p"], lam_g, sigma=0.7)
            for a, b in zip(sequential, parallel):
                for name in a:
                    assert np.array_equal(a[name], b[name]), name


def test_stage_derivatives_are_the_stage_functions(problem, solvers, steps):
    """What the shim evaluates is CasADi's own derivative of each stage (independent evaluation in the SX VM)."""
    step = steps[0]
    rng = np.random.default_rng(2)
    lam_g = rng.normal(size=problem.n_constraints)
    blocks = solvers[2].stage_derivatives(step["x0"], step["p"], lam_g, sigma=0.7)
    stage_p = solvers[2].stage_parameters(step["p"])
    for k, block in enumerate(blocks):
        function, _ = problem.stage_function(k)
        hess, jac, _, grad, _ = stage_kind_functions(function, f"check{k}")
        state, inputs = problem.stage_slices[k]
        x_k, u_k = step["x0"][state], step["x0"][inputs]
        rows = slice(problem.stage_row_starts[k] + (problem.nx if k < problem.N else 0),
                     problem.stage_row_starts[k + 1] if k < problem.N else problem.n_constraints)
        lam_dyn = -lam_g[problem.stage_row_starts[k]:problem.stage_row_starts[k] + problem.nx] if k < problem.N \
            else np.zeros(hess.size1_in(4))
        expected_hess = np.asarray(hess(u_k, x_k, stage_p[k], 0.7, lam_dyn, lam_g[rows]))
        jac_next, jac_rows = (np.asarray(m) for m in jac(u_k, x_k, stage_p[k]))
        scale = max(1.0, np.abs(expected_hess).max())
        np.testing.assert_allclose(block["hess"], expected_hess, atol=1e-10 * scale)
        np.testing.assert_allclose(block["grad"], np.asarray(grad(u_k, x_k, stage_p[k])).ravel(), atol=1e-10)
        np.testing.assert_allclose(block["jac_next"], jac_next.T.reshape(block["jac_next"].shape), atol=1e-10)
        np.testing.assert_allclose(block["jac_rows"], jac_rows.T, atol=1e-10)


def test_solves_are_identical_on_any_thread_count(solvers, steps):
    """Same iterations, same primal and dual solution, same cost and violation, bit for bit, warm-started steps
    included (each solver keeps its own multiplier warm start)."""
    runs = {t: [solvers[t].recreated().solve(**step, warm_start=True) for step in steps] for t in (1, 2, 3)}
    for threads in (2, 3):
        for a, b in zip(runs[1], runs[threads]):
            assert a.stats.success and b.stats.success
            assert (a.stats.iterations, a.stats.status) == (b.stats.iterations, b.stats.status)
            for name in ("x", "lam_g", "lam_x"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), name
            assert a.stats.cost == b.stats.cost
            assert a.stats.max_constraint_violation == b.stats.max_constraint_violation


def test_constraints_are_identical_on_any_thread_count(problem, solvers, steps):
    x = steps[1]["x0"] + 1e-3 * np.random.default_rng(3).normal(size=problem.n_variables)
    expected = solvers[1].constraints(x, steps[1]["p"])
    for threads in (2, 3):
        assert np.array_equal(solvers[threads].constraints(x, steps[1]["p"]), expected)


def test_threads_is_checked():
    with pytest.raises(Exception, match="threads"):
        SolverConfig(name="fatrop-direct", threads=0)


def test_another_horizon_reuses_the_compiled_stages(robot, solvers, codegen):
    """The stage library holds the stage kinds only: a longer horizon of the same formulation loads it from the
    cache (the layout of its stages comes from Python) and solves."""
    longer = OcpProblem(robot, OcpConfig(grid=TimeGrid(n_intervals=7, dt_first_s=0.01, dt_last_s=0.06)))
    solver = FatropDirectSolver(longer, SolverConfig(name="fatrop-direct", codegen=codegen, threads=2))
    assert solver.compile_report.cached and solver.compile_report.library == solvers[1].compile_report.library
    mpc = MPC(robot, MpcConfig(ocp=longer.config, recovery=RecoveryConfig(fallback_solver=None)), problem=longer, solver=solver)
    assert mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.1).success


class _Kinds(ctypes.Structure):  # csrc/wbmpc_stages.h's wb_kinds
    _fields_ = [("version", ctypes.c_int), ("n_kinds", ctypes.c_int), ("functions", ctypes.POINTER(ctypes.c_void_p)),
                ("sz", ctypes.c_int * 4), ("code", ctypes.POINTER(ctypes.c_void_p)), ("lanes", ctypes.c_int),
                ("lane_functions", ctypes.POINTER(ctypes.c_void_p))]


class _DlInfo(ctypes.Structure):
    _fields_ = [("dli_fname", ctypes.c_char_p), ("dli_fbase", ctypes.c_void_p), ("dli_sname", ctypes.c_char_p),
                ("dli_saddr", ctypes.c_void_p)]


def test_each_stage_function_knows_its_code_range(solvers):
    """The shim prefetches a kind's machine code from the library's table: every function has a range of its own
    inside the stage library, apart from the others (a covered kind's Hessian and Jacobian: its cover's, the code
    they run, stage_covers), the derivatives' the longest of their kind."""
    library = solvers[1].compile_report.library
    lib = ctypes.CDLL(str(library))
    lib.wbmpc_stage_kinds.restype = ctypes.POINTER(_Kinds)
    kinds = lib.wbmpc_stage_kinds().contents
    assert kinds.version == stage_library.KINDS_VERSION
    n = kinds.n_kinds * len(stage_library.FUNCTION_KINDS)
    ranges = [(kinds.code[2 * i], kinds.code[2 * i + 1]) for i in range(n)]
    libc = ctypes.CDLL(None)
    info = _DlInfo()
    for start, end in ranges:
        assert start and end and end > start
        for address in (start, end - 1):
            assert libc.dladdr(ctypes.c_void_p(address), ctypes.byref(info))
            assert Path(info.dli_fname.decode()).resolve() == Path(library).resolve()
    shared = [i for i, r in enumerate(ranges) if ranges.index(r) != i]
    assert all(i % len(stage_library.FUNCTION_KINDS) < 2 for i in shared)  # only derivatives run another's code
    ordered = sorted(set(ranges))
    assert all(a[1] <= b[0] for a, b in zip(ordered, ordered[1:]))
    wrappers = [kinds.functions[i] for i in range(n)]
    assert not any(start <= w < end for w in wrappers for start, end in ranges)
    sizes = np.array([end - start for start, end in ranges]).reshape(kinds.n_kinds, -1)
    assert stage_library.FUNCTION_KINDS[:2] == ("hess", "jac")
    assert (sizes[:, :2].min(axis=1) > sizes[:, 2:].max(axis=1)).all()  # the derivatives' code is the longest


def test_code_ranges_fall_back_to_none_on_unknown_text():
    code, ranges = stage_library.code_sections("int f(void) { return 0; }\n", ["wbk0_hess"])
    assert code == "int f(void) { return 0; }\n" and ranges == ["0", "0"]
