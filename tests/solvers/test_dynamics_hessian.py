"""fatrop-direct's approximations of the RNEA rows' curvature (CodegenConfig.dynamics_hessian,
stage_library.lagrangian_hessian) on a small go2 problem: what each keeps is the exact Hessian, what each drops is
the RNEA rows' second derivative (finite differences of their Jacobian), and the solver reaches the exact Hessian's
KKT point."""

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from tests.solvers.mpc_steps import TINY, capture_step_data
from wbmpc.errors import ConfigError
from wbmpc.solvers.codegen import CodegenConfig
from wbmpc.solvers.fatrop_direct import FatropDirectSolver
from wbmpc.solvers.nlp import NlpSolver, SolverConfig
from wbmpc.solvers.stage_library import DYNAMICS_TAGS, stage_kind_functions


def _rnea_rows(tags):
    index, start = [], 0
    for name, size in tags:
        if name in DYNAMICS_TAGS:
            index += range(start, start + size)
        start += size
    return np.array(index, dtype=int)


@pytest.mark.parametrize("k", [0, 1])
def test_kept_blocks_are_exact_and_dropped_ones_are_the_rnea_curvature(problem, step_data, k):
    function, tags = problem.stage_function(k)
    rnea = _rnea_rows(tags)
    assert rnea.size >= 6  # the base rows at least (eq. 5)
    exact, jac = stage_kind_functions(function, "exact", tags, "exact")[:2]
    cross, gauss_newton = (stage_kind_functions(function, mode.replace("-", "_"), tags, mode)[0]
                           for mode in ("cross", "gauss-newton"))
    n_u, n_x = function.size1_in(1), function.size1_in(0)
    rng = np.random.default_rng(k)
    state, inputs = problem.stage_slices[k]
    x = step_data["x0"][state] + 0.05 * rng.normal(size=n_x)
    u = step_data["x0"][inputs] + 0.3 * rng.normal(size=n_u)
    p = np.asarray(ca.evalf(problem.stage_parameters(ca.DM(step_data["p"]), k))).ravel()
    sigma, lam_dyn, lam_rows = 0.7, rng.normal(size=exact.size1_in(4)), rng.normal(size=exact.size1_in(5))
    h_exact, h_cross, h_gn = (np.asarray(h(u, x, p, sigma, lam_dyn, lam_rows))
                              for h in (exact, cross, gauss_newton))
    scale = max(1.0, np.abs(h_exact).max())
    # the RNEA rows' Hessian lam' d^2 r / dz^2 by central differences of their Jacobian (z = (u, x))
    lam = np.zeros_like(lam_rows)
    lam[rnea] = lam_rows[rnea]

    def gradient(z):
        return np.asarray(jac(z[:n_u], z[n_u:], p)[1]) @ lam

    z, step = np.concatenate([u, x]), 1e-6
    rnea_hessian = np.column_stack([(gradient(z + step * e) - gradient(z - step * e)) / (2 * step)
                                    for e in np.eye(n_u + n_x)])
    assert np.abs(rnea_hessian).max() > 1e-3  # the rows have curvature to drop
    np.testing.assert_allclose(h_exact - h_gn, rnea_hessian, atol=1e-6 * scale)
    # cross keeps every block with an input exactly, drops the RNEA rows' (x, x) block
    np.testing.assert_allclose(h_cross[:n_u], h_exact[:n_u], atol=1e-9 * scale)
    np.testing.assert_allclose(h_cross[:, :n_u], h_exact[:, :n_u], atol=1e-9 * scale)
    np.testing.assert_allclose(h_exact[n_u:, n_u:] - h_cross[n_u:, n_u:], rnea_hessian[n_u:, n_u:], atol=1e-6 * scale)
    # RNEA is linear in (a, F): the rows' (u, u) block is zero, so gauss-newton keeps it too
    np.testing.assert_allclose(rnea_hessian[:n_u, :n_u], 0, atol=1e-6 * scale)


def test_exact_is_the_default_and_names_are_checked():
    assert CodegenConfig().dynamics_hessian == "exact"
    with pytest.raises(ConfigError, match="gauss-newton"):
        CodegenConfig(dynamics_hessian="newton")


@pytest.fixture(scope="module")
def step_data(robot, problem):
    """p, bounds and initial guess of one trot MPC step from a moving base."""
    return capture_step_data(robot, problem, TINY)


@pytest.fixture(scope="module")
def codegen(tmp_path_factory):
    return CodegenConfig(flags=("-O0", "-march=native"), cache_dir=tmp_path_factory.mktemp("wbmpc_cache"))


@pytest.mark.parametrize("mode", ["cross", "gauss-newton"])
def test_inexact_hessians_reach_the_exact_kkt_point(problem, step_data, codegen, mode):
    """Same constraints and stationarity conditions: the solve converges to the exact Hessian's solution, its
    constraints met (checked on casadi's own NLP constraint function)."""
    config = SolverConfig(name="fatrop-direct", tolerance=1e-9, warm_barrier_init=None, codegen=codegen)
    expected = FatropDirectSolver(problem, config).solve(**step_data)
    solver = FatropDirectSolver(problem, replace(config, codegen=replace(codegen, dynamics_hessian=mode)))
    assert solver.is_direct, solver.direct_error
    got = solver.solve(**step_data)
    assert expected.stats.success and got.stats.success, (expected.stats, got.stats)
    np.testing.assert_allclose(got.x, expected.x, atol=1e-6)
    g = NlpSolver(problem).constraints(got.x, step_data["p"])
    tolerance = config.constraint_tolerance
    assert np.all(g >= step_data["lbg"] - tolerance) and np.all(g <= step_data["ubg"] + tolerance)
    assert np.all(got.x >= step_data["lbx"] - tolerance) and np.all(got.x <= step_data["ubx"] + tolerance)
