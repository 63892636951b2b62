"""C code generation of the NLP: compile, load, same solution as the virtual machine, cache reuse."""

import warnings

import numpy as np
import pytest

from tests.solvers.mpc_steps import TINY
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.solvers.codegen import CodegenConfig, cache_key, nlp_functions
from wbmpc.solvers.nlp import NlpSolver, SolverConfig


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("wbmpc_cache")


def test_stage_derivatives_equal_the_expanded_nlp(problem):
    """Jacobian, Lagrangian gradient and Hessian assembled from stage derivatives vs casadi's on the SX NLP."""
    import casadi as ca

    functions = {f.name(): f for f in nlp_functions(problem, "fatrop")}
    nlp = problem.nlp
    rng = np.random.default_rng(0)
    x = 0.1 * rng.normal(size=problem.n_variables)
    p = rng.normal(size=problem.params.size)
    lam_g = rng.normal(size=problem.n_constraints)
    lagrangian = 0.7 * nlp["f"] + ca.dot(ca.DM(lam_g), nlp["g"])
    hessian, gradient = ca.hessian(lagrangian, nlp["x"])
    reference = ca.Function("ref", [nlp["x"], nlp["p"]], [ca.jacobian(nlp["g"], nlp["x"]), gradient, hessian])
    jac_ref, grad_ref, hess_ref = (np.array(m) for m in reference(x, p))
    jac = np.array(functions["nlp_jac_g"](x, p)[1])
    grad, hess = (np.array(m) for m in functions["nlp_hess_l"](x, p, 0.7, lam_g))
    np.testing.assert_allclose(jac, jac_ref, atol=1e-10)
    np.testing.assert_allclose(grad.ravel(), grad_ref.ravel(), atol=1e-9)
    np.testing.assert_allclose(hess, hess_ref, atol=1e-8 * max(1.0, np.abs(hess_ref).max()))


@pytest.fixture(scope="module")
def compiled_solver(problem, cache_dir):
    config = SolverConfig(compiled=True, codegen=CodegenConfig(flags=("-O0",), cache_dir=cache_dir))
    return NlpSolver(problem, config)


def test_compiled_solver_gives_the_same_solution(robot, problem, compiled_solver):
    assert compiled_solver.is_compiled and not compiled_solver.compile_report.cached
    assert compiled_solver.compile_report.library.exists()
    reference = MPC(robot, MpcConfig(ocp=TINY, recovery=RecoveryConfig(fallback_solver=None)), problem=problem)
    compiled = MPC(robot, MpcConfig(ocp=TINY, recovery=RecoveryConfig(fallback_solver=None)), problem=problem, solver=compiled_solver)
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.1, 0.05]
    for t in (0.1, 0.1125):
        expected = reference.solve(robot.q_nominal, v0, t_s=t)
        got = compiled.solve(robot.q_nominal, v0, t_s=t)
        assert expected.success and got.success, (expected.stats, got.stats)
        assert got.stats.iterations == expected.stats.iterations
        np.testing.assert_allclose(got.x, expected.x, atol=1e-8)
        np.testing.assert_allclose(got.tau, expected.tau, atol=1e-6)


def test_second_build_loads_the_cached_library(problem, compiled_solver, cache_dir):
    again = NlpSolver(problem, SolverConfig(compiled=True, codegen=CodegenConfig(flags=("-O0",), cache_dir=cache_dir)))
    assert again.compile_report.cached
    assert again.compile_report.library == compiled_solver.compile_report.library
    assert again.compile_report.compile_s == 0.0


def test_missing_compiler_falls_back_to_the_virtual_machine(problem, tmp_path):
    config = SolverConfig(compiled=True, codegen=CodegenConfig(compiler="no-such-cc", cache_dir=tmp_path))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver = NlpSolver(problem, config)
    assert not solver.is_compiled
    assert "no-such-cc" in solver.compile_error
    assert any("non-compiled" in str(w.message) for w in caught)
    assert list(tmp_path.iterdir()) == []  # nothing half-written left in the cache


def test_native_code_is_cached_per_cpu(monkeypatch):
    from wbmpc.solvers import codegen

    native, portable = CodegenConfig(flags=("-O1", "-march=native")), CodegenConfig(flags=("-O1",))
    monkeypatch.setattr(codegen, "cpu_identity", lambda: "cpu A")
    key_a, key_portable_a = codegen.cache_key("code", native), codegen.cache_key("code", portable)
    monkeypatch.setattr(codegen, "cpu_identity", lambda: "cpu B")
    assert codegen.cache_key("code", native) != key_a
    assert codegen.cache_key("code", portable) == key_portable_a
    assert codegen.cache_key("other code", portable) != key_portable_a


def test_large_sources_compile_at_a_lower_optimisation_level():
    """TALOS-sized generated C (23.6 MB) at -O0: gcc's -O1 on its 200k-line stage Hessians ran past 30 minutes."""
    from wbmpc.solvers.codegen import for_source

    config = CodegenConfig(flags=("-O1", "-march=native"))
    assert for_source(config, 17.5) is config  # g1 keeps -O1
    large = for_source(config, 23.6)
    assert large.flags == ("-march=native", "-O0") and large.large_source_mb == config.large_source_mb
    assert cache_key("code", large) != cache_key("code", config)  # the cache follows the flags used
    assert for_source(CodegenConfig(flags=("-O2",), large_source_mb=None), 1e3).flags == ("-O2",)


def test_stage_library_optimisation_by_source_size():
    """-O2 up to `stage_o2_max_source_mb` (none by default: b1_z1's 4.4 MB compiled 7x longer at -O2 for 3.7 % per
    iteration; asked for, e.g. 10 for b1_z1 or 20 for g1's 10.6 MB), -O1 above it, the large-source level above
    `stage_large_source_mb` (TALOS's 13.9 MB), which is the stage library's own (the NLP library keeps
    `large_source_mb`)."""
    from wbmpc.solvers.codegen import for_source
    from wbmpc.solvers.stage_library import compile_flags

    assert compile_flags(CodegenConfig(), 4.4)[1] == ("-O1", "-march=native")
    assert compile_flags(CodegenConfig(stage_o2_max_source_mb=10.0), 4.4)[1] == ("-O2", "-march=native")
    assert compile_flags(CodegenConfig(stage_o2_max_source_mb=10.0), 10.6)[1] == ("-O1", "-march=native")
    assert compile_flags(CodegenConfig(stage_o2_max_source_mb=20.0), 10.6)[1] == ("-O2", "-march=native")
    assert compile_flags(CodegenConfig(), 13.9)[1] == ("-march=native", "-O0")
    assert compile_flags(CodegenConfig(stage_large_source_mb=None), 13.9)[1] == ("-O1", "-march=native")
    assert for_source(CodegenConfig(), 13.9).flags == CodegenConfig().flags  # the NLP library: -O1 up to 20 MB
