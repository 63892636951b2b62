"""The direct Fatrop binding (solvers/fatrop_direct.py) against casadi's Fatrop on a small go2 problem."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from tests.solvers.mpc_steps import TINY, capture_step_data
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.errors import ConfigError
from wbmpc.solvers import fatrop_direct, fatrop_settings, make_solver
from wbmpc.solvers.blasfeo import cpu_has_avx2_fma
from wbmpc.solvers.codegen import CodegenConfig
from wbmpc.solvers.fatrop_direct import FatropDirectSolver
from wbmpc.solvers.fatrop_settings import mpc_tolerances, multiplier_start
from wbmpc.solvers.nlp import NlpSolver, SolverConfig, bound_violation


@pytest.fixture(scope="module")
def codegen(tmp_path_factory):
    # -march=native: the AVX2 kernels of fatrop_kernels.py are compiled in where the CPU has AVX2/FMA
    return CodegenConfig(flags=("-O0", "-march=native"), cache_dir=tmp_path_factory.mktemp("wbmpc_cache"))


@pytest.fixture(scope="module")
def direct(problem, codegen):
    solver = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen))
    assert solver.is_direct, solver.direct_error
    return solver


@pytest.fixture(scope="module")
def step_data(robot, problem):
    """p, bounds and initial guess of one MPC step (trot, moving base), as the MPC hands them to its solver."""
    return capture_step_data(robot, problem, TINY)


def test_same_solution_as_casadis_fatrop(problem, direct, step_data):
    """Tight tolerance: both follow the same iterates (up to rounding: the direct binding eliminates fixed inputs
    instead of passing them as equality rows) to the same KKT point; residuals below tolerance. casadi's Fatrop runs
    on Fatrop's own elimination kernels, the direct binding on ours (csrc/fatrop_kernels.cpp)."""
    config = SolverConfig(tolerance=1e-10, warm_barrier_init=None)
    direct.set_elimination_kernels(False)
    try:
        expected = NlpSolver(problem, config).solve(**step_data)
    finally:
        assert direct.set_elimination_kernels(True) == direct.kernels
    got = direct.recreated(tolerance=1e-10, warm_barrier_init=None).solve(**step_data)
    assert expected.stats.success and got.stats.success, (expected.stats, got.stats)
    # at 1e-10 both end at Fatrop's acceptable level, after a count of iterations that rounding can change
    assert abs(got.stats.iterations - expected.stats.iterations) <= 2
    np.testing.assert_allclose(got.x, expected.x, atol=1e-8)
    np.testing.assert_allclose(got.stats.cost, expected.stats.cost, rtol=1e-10)
    scale = max(1.0, np.abs(expected.lam_g).max())
    np.testing.assert_allclose(got.lam_g, expected.lam_g, atol=1e-6 * scale)
    np.testing.assert_allclose(got.lam_x, expected.lam_x, atol=1e-6 * scale)
    # residuals from casadi's own NLP constraint function, not the shim's
    g = NlpSolver(problem).constraints(got.x, step_data["p"])
    lbx, ubx, lbg, ubg = (step_data[k] for k in ("lbx", "ubx", "lbg", "ubg"))
    assert np.all(g >= lbg - config.constraint_tolerance) and np.all(g <= ubg + config.constraint_tolerance)
    assert np.all(got.x >= lbx - config.constraint_tolerance) and np.all(got.x <= ubx + config.constraint_tolerance)
    assert got.stats.max_constraint_violation <= config.constraint_tolerance
    # the shim's violation (computed in C) is nlp.bound_violation's on casadi's g
    assert got.stats.max_constraint_violation == pytest.approx(bound_violation(got.x, g, lbx, ubx, lbg, ubg), abs=1e-12)


def test_elimination_kernels_follow_fatrops_iterates(direct, step_data):
    """Our AVX2 LU and triangular solve (csrc/fatrop_kernels.cpp) and sparse products (csrc/fatrop_sparse.cpp)
    against Fatrop's and BLASFEO's own: same iterations, same point bit for bit."""
    if not cpu_has_avx2_fma():
        pytest.skip("the kernels need AVX2/FMA")
    assert direct.kernels
    solver = direct.recreated(tolerance=1e-10, warm_barrier_init=None)
    ours = solver.solve(**step_data)
    assert not solver.set_elimination_kernels(False)
    try:
        fatrops = solver.solve(**step_data)
    finally:
        assert solver.set_elimination_kernels(True)
    assert ours.stats.success and fatrops.stats.success
    assert ours.stats.iterations == fatrops.stats.iterations
    # the same operations in the same order: the same bits
    np.testing.assert_array_equal(ours.x, fatrops.x)
    np.testing.assert_array_equal(ours.lam_g, fatrops.lam_g)


def test_sparse_products_give_blasfeos_iterates_bit_for_bit(direct, step_data):
    """Fatrop's Riccati products with the sparse dynamics and inequality Jacobians on ours (csrc/fatrop_sparse.cpp)
    against BLASFEO's dense ones: the same iterations and the same bits (the products sum the nonzero terms in
    BLASFEO's order; a changed rounding anywhere would show in x and the multipliers)."""
    if not cpu_has_avx2_fma():
        pytest.skip("the kernels need AVX2/FMA")
    solver = direct.recreated(tolerance=1e-10, warm_barrier_init=None)
    try:
        assert solver.set_elimination_kernels(True, sparse_products=False)
        dense = solver.solve(**step_data)
        assert solver.set_elimination_kernels(True, sparse_products=True)
        sparse = solver.solve(**step_data)
    finally:
        assert solver.set_elimination_kernels(True) == direct.kernels
    assert dense.stats.success and sparse.stats.success
    assert sparse.stats.iterations == dense.stats.iterations
    np.testing.assert_array_equal(sparse.x, dense.x)
    np.testing.assert_array_equal(sparse.lam_g, dense.lam_g)
    np.testing.assert_array_equal(sparse.lam_x, dense.lam_x)


def test_mpc_solves_skip_iterative_refinement_at_the_same_iterations(direct, step_data):
    """At the MPC tolerances the binding asks Fatrop for no iterative refinement (MPC_ITERATIVE_REFINEMENT): the
    same iterations and the same point to rounding as with Fatrop's default (which refines here, so the bits
    differ: the option reaches Fatrop); a negative count is refused by name."""
    assert fatrop_settings.MPC_ITERATIVE_REFINEMENT == 0 and direct.tolerance >= fatrop_settings.MPC_TOLERANCE
    default = direct.recreated().solve(**step_data)
    none = direct.recreated(extra_options={"fatrop": {"max_iterative_refinement": 0}}).solve(**step_data)
    refined = direct.recreated(extra_options={"fatrop": {"max_iterative_refinement": 5}}).solve(**step_data)
    assert default.stats.success and refined.stats.success
    np.testing.assert_array_equal(default.x, none.x)
    assert default.stats.iterations == refined.stats.iterations
    np.testing.assert_allclose(default.x, refined.x, atol=1e-9)
    assert not np.array_equal(default.x, refined.x)
    with pytest.raises(ConfigError, match="max_iterative_refinement"):
        direct.recreated(extra_options={"fatrop": {"max_iterative_refinement": -1}}).solve(**step_data)


def test_shim_constraints_equal_the_nlp(problem, direct, step_data):
    rng = np.random.default_rng(0)
    x = step_data["x0"] + 0.01 * rng.normal(size=problem.n_variables)
    expected = NlpSolver(problem).constraints(x, step_data["p"])
    np.testing.assert_allclose(direct.constraints(x, step_data["p"]), expected, atol=1e-10)


def _trot_steps(robot, problem, solver_config, times=(0.1, 0.1125, 0.125, 0.2)):
    mpc = MPC(robot, MpcConfig(ocp=TINY, recovery=RecoveryConfig(fallback_solver=None), solver=solver_config), problem=problem)
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.1, 0.05]
    return mpc, [mpc.solve(robot.q_nominal, v0, t_s=t) for t in times]


def test_mpc_steps_match_casadis_fatrop(robot, problem, codegen):
    """Through make_solver and the MPC (warm start, small-barrier attempts, contact changes between steps);
    without the multiplier warm start and with casadi's row split (fixed inputs as equality rows) both follow the
    same iterates."""
    _, expected = _trot_steps(robot, problem, SolverConfig())
    mpc, got = _trot_steps(robot, problem, SolverConfig(name="fatrop-direct", codegen=codegen, extra_options={
        "warm_duals": False, "mpc_tolerances": False, "eliminate_fixed_inputs": False}))
    assert isinstance(mpc.solver, FatropDirectSolver) and mpc.solver.is_compiled
    for e, g in zip(expected, got):
        assert e.success and g.success, (e.stats, g.stats)
        assert g.stats.iterations == e.stats.iterations
        np.testing.assert_allclose(g.x, e.x, atol=1e-8)


def test_eliminated_fixed_inputs_give_the_same_steps(robot, problem, codegen, step_data):
    """Inputs with lb == ub (swing feet's forces, the arm's) eliminated from Fatrop's stages: the same plans and
    multipliers as with them as equality rows, within the solver's tolerance (Fatrop's convergence test weighs
    the multipliers of every row, so the last iteration may differ), the fixed inputs at their bounds and their
    multipliers those Fatrop computes for the equality rows."""
    config = SolverConfig(name="fatrop-direct", codegen=codegen, tolerance=1e-8, warm_barrier_init=None)
    mpc_rows, rows = _trot_steps(robot, problem, replace(config, extra_options={"eliminate_fixed_inputs": False}))
    mpc, eliminated = _trot_steps(robot, problem, config)
    assert mpc.solver.eliminate_fixed_inputs and not mpc_rows.solver.eliminate_fixed_inputs
    for r, e in zip(rows, eliminated):
        assert r.success and e.success
        np.testing.assert_allclose(e.x, r.x, atol=1e-6)
    data = step_data
    expected = mpc_rows.solver.recreated().solve(**data)
    got = mpc.solver.recreated().solve(**data)
    fixed = data["lbx"] == data["ubx"]
    assert fixed.any()
    assert np.array_equal(got.x[fixed], data["lbx"][fixed])
    scale = max(1.0, np.abs(expected.lam_x[fixed]).max())
    np.testing.assert_allclose(got.lam_x[fixed], expected.lam_x[fixed], atol=1e-5 * scale)


def test_multiplier_warm_start_in_the_mpc(robot, problem, codegen):
    """With the primal-dual warm start (default) the steps converge to the same plans within the
    solver tolerance, in no more iterations in total."""
    _, expected = _trot_steps(robot, problem, SolverConfig())
    _, got = _trot_steps(robot, problem, SolverConfig(name="fatrop-direct", codegen=codegen,
                                                      extra_options={"mpc_tolerances": False}))
    for e, g in zip(expected, got):
        assert g.success, g.stats
        np.testing.assert_allclose(g.x, e.x, atol=1e-3)
        assert g.stats.max_constraint_violation <= SolverConfig().constraint_tolerance
    assert sum(g.stats.iterations for g in got) <= sum(e.stats.iterations for e in expected)


def test_given_multipliers_restart_a_solution(direct, step_data, codegen, problem, monkeypatch):
    """Multipliers in the NLP's layout handed to the shim (`takes_multipliers`) land on their own rows: a solution's
    own multipliers restart it at its primal (from a barrier below the tolerance) in at most two iterations, fewer
    than from zeros or from the negated ones (a row's multiplier on another row, or of the wrong sign, is a worse
    start)."""
    solver = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen, extra_options={
        "shifted_multipliers": True, "mpc_tolerances": False, "multiplier_barrier_init": 1e-4}))
    assert solver.takes_multipliers and not direct.takes_multipliers  # go2's point feet: off by default
    data = step_data
    solution = solver.solve(**data)
    assert solution.stats.success
    bounds = (data["p"], data["lbx"], data["ubx"], data["lbg"], data["ubg"])
    iterations = {}
    for name, sign in (("own", 1.0), ("zeros", 0.0), ("negated", -1.0)):
        restart = solver.recreated().solve(*bounds, solution.x, sign * solution.lam_g, sign * solution.lam_x,
                                           warm_start=True)
        assert restart.stats.success, (name, restart.stats)
        np.testing.assert_allclose(restart.x, solution.x, atol=1e-3)
        iterations[name] = restart.stats.iterations
    assert iterations["own"] <= 2 and iterations["own"] < min(iterations["zeros"], iterations["negated"]), iterations
    # a warm step that converged within QUIET_ITERATIONS (a plan standing still) hands the next one to the instance's
    # multipliers; a longer one keeps the given ones (the restart takes 2 here: the rule's count set to that)
    monkeypatch.setattr(fatrop_direct, "QUIET_ITERATIONS", iterations["own"])
    steps = solver.recreated()
    steps.solve(*bounds, solution.x, solution.lam_g, solution.lam_x, warm_start=True)
    assert steps.last_start == "given"
    steps.solve(*bounds, solution.x, solution.lam_g, solution.lam_x, warm_start=True)
    assert steps.last_start == "instance"
    steps = solver.recreated()
    far = steps.solve(*bounds, data["x0"], solution.lam_g, solution.lam_x, warm_start=True)  # from the MPC's guess
    assert steps.last_start == "given" and far.stats.success and far.stats.iterations > 2, far.stats
    steps.solve(*bounds, data["x0"], solution.lam_g, solution.lam_x, warm_start=True)
    assert steps.last_start == "given"


def test_the_mpc_hands_its_shifted_multipliers_to_a_solver_that_takes_them(robot, problem, codegen):
    """With `shifted_multipliers` the MPC's warm steps give the solver the last plan's multipliers moved by
    constraint identity (ocp/multipliers.py); the plans stay those of the default warm start within the MPC
    tolerances."""
    config = SolverConfig(name="fatrop-direct", codegen=codegen)
    _, expected = _trot_steps(robot, problem, config)
    mpc = MPC(robot, MpcConfig(ocp=TINY, recovery=RecoveryConfig(fallback_solver=None), solver=replace(
        config, extra_options={"shifted_multipliers": True})), problem=problem)
    handed = []
    solve = mpc.solver.solve

    def spy(p, lbx, ubx, lbg, ubg, x0, *multipliers, **kwargs):
        handed.append(tuple(np.shape(m) for m in multipliers))
        return solve(p, lbx, ubx, lbg, ubg, x0, *multipliers, **kwargs)

    mpc.solver.solve = spy
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.1, 0.05]
    got = [mpc.solve(robot.q_nominal, v0, t_s=t) for t in (0.1, 0.1125, 0.125, 0.2)]
    assert handed[0] == () and all(h == ((problem.n_constraints,), (problem.n_variables,)) for h in handed[1:])
    for e, g in zip(expected, got):
        assert g.success, g.stats
        np.testing.assert_allclose(g.x, e.x, atol=1e-2)


def test_mpc_tolerances(robot, problem, codegen):
    """By default the binding stops at its own MPC tolerances (fatrop_settings.MPC_TOLERANCE, ..._CONSTRAINT_TOLERANCE):
    the plans stay within them of casadi's Fatrop at SolverConfig's tolerances, in no more iterations;
    tolerances set in SolverConfig are kept."""
    from wbmpc.solvers.fatrop_settings import MPC_CONSTRAINT_TOLERANCE, MPC_TOLERANCE

    _, expected = _trot_steps(robot, problem, SolverConfig())
    mpc, got = _trot_steps(robot, problem, SolverConfig(name="fatrop-direct", codegen=codegen))
    assert (mpc.solver.tolerance, mpc.solver.constraint_tolerance) == (MPC_TOLERANCE, MPC_CONSTRAINT_TOLERANCE)
    for e, g in zip(expected, got):
        assert g.success, g.stats
        assert g.stats.max_constraint_violation <= MPC_CONSTRAINT_TOLERANCE
        np.testing.assert_allclose(g.x, e.x, atol=1e-2)
    assert sum(g.stats.iterations for g in got) <= sum(e.stats.iterations for e in expected)
    kept = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen, tolerance=1e-6))
    assert (kept.tolerance, kept.constraint_tolerance) == (1e-6, SolverConfig().constraint_tolerance)


def test_flat_feet_defaults():
    """Flat feet: the KKT tolerance FLAT_FEET_MPC_TOLERANCE and warm attempts from the MPC's multipliers; point feet
    keep MPC_TOLERANCE and the instance's multipliers; set values win."""
    from wbmpc.solvers.fatrop_settings import (
        FLAT_FEET_MPC_TOLERANCE,
        MPC_CONSTRAINT_TOLERANCE,
        MPC_TOLERANCE,
        MULTIPLIER_BARRIER_INIT,
        MULTIPLIER_MAX_ITERATIONS,
    )

    config = SolverConfig(name="fatrop-direct")
    assert mpc_tolerances(config, flat_feet=True) == (FLAT_FEET_MPC_TOLERANCE, MPC_CONSTRAINT_TOLERANCE) == (1e-2, 1e-4)
    assert mpc_tolerances(config, flat_feet=False) == (MPC_TOLERANCE, MPC_CONSTRAINT_TOLERANCE) == (1e-3, 1e-4)
    assert mpc_tolerances(replace(config, tolerance=1e-6), flat_feet=True) == (1e-6, SolverConfig().constraint_tolerance)
    assert mpc_tolerances(replace(config, extra_options={"mpc_tolerances": False}), flat_feet=True) == (1e-4, 1e-6)
    assert multiplier_start(config, flat_feet=True) == (True, MULTIPLIER_BARRIER_INIT, MULTIPLIER_MAX_ITERATIONS)
    assert not multiplier_start(config, flat_feet=False)[0]
    assert multiplier_start(replace(config, extra_options={"shifted_multipliers": False, "multiplier_barrier_init": 1e-4,
                                                           "multiplier_max_iterations": 5}), flat_feet=True) == \
        (False, 1e-4, 5)


def test_iteration_cap_per_call_returns_its_iterate(direct, step_data):
    result = direct.solve(**step_data, max_iterations=1)
    assert not result.stats.success and result.stats.status == "Maximum_Iterations_Exceeded"
    # Fatrop's convergence check sees the iteration count before its increment: max_iter 1 stops after 2
    assert result.stats.iterations <= 2 and np.all(np.isfinite(result.x))


def test_a_new_row_structure_gets_its_own_fatrop(direct, step_data):
    """A step whose rows split differently (a contact switch) is refused by the last Fatrop instance and solved by
    one built for it; the next step of the first structure goes back to the first instance."""
    solver = direct.recreated()
    first = solver.solve(**step_data)
    lbg, ubg = step_data["lbg"].copy(), step_data["ubg"].copy()
    free = np.nonzero(np.isinf(lbg) & np.isinf(ubg))[0]
    lbg[free[0]], ubg[free[0]] = -1e3, 1e3  # one more inequality row in some stage
    other = solver.solve(**{**step_data, "lbg": lbg, "ubg": ubg})
    again = solver.solve(**step_data)
    assert first.stats.success and other.stats.success and again.stats.success
    assert len(solver.structure_keys) == 2
    np.testing.assert_allclose(again.x, first.x, atol=1e-6)


def test_least_recently_used_instances_are_freed_and_rebuilt(direct, step_data, monkeypatch):
    """Beyond MAX_INSTANCES the least recently used Fatrop instance is freed; a structure met again gets a new one
    that solves it as the first did (same iterations, same solution), with its options set again."""
    monkeypatch.setattr(fatrop_direct, "MAX_INSTANCES", 2)
    solver = direct.recreated(extra_options={"fatrop": {"max_iter": 40}})
    lbg, ubg = step_data["lbg"].copy(), step_data["ubg"].copy()
    free = np.nonzero(np.isinf(lbg) & np.isinf(ubg))[0]
    variants, seen = [], set()
    for row in free:  # three structures: one more inequality row in another stage each
        lo, hi = lbg.copy(), ubg.copy()
        lo[row], hi[row] = -1e3, 1e3
        key = solver.structure_key(step_data["lbx"], step_data["ubx"], lo, hi)
        if key not in seen and len(variants) < 3:
            seen.add(key)
            variants.append({**step_data, "lbg": lo, "ubg": hi})
    assert len(variants) == 3
    first = [solver.solve(**variant) for variant in variants]
    keys = solver.structure_keys
    assert len(keys) == 2 and solver.structure_key(variants[0]["lbx"], variants[0]["ubx"], variants[0]["lbg"],
                                                   variants[0]["ubg"]) not in keys
    again = solver.solve(**variants[0])  # built again, the second structure freed
    assert len(solver.structure_keys) == 2
    assert again.stats.iterations == first[0].stats.iterations
    np.testing.assert_array_equal(again.x, first[0].x)
    assert all(result.stats.success for result in first)


def test_fatrop_options_pass_through_and_an_unknown_one_is_named(direct, step_data):
    """extra_options["fatrop"] reach Fatrop (a loose tolerance stops the solve earlier); a misspelt option or one
    of the wrong type is refused by name instead of silently ignored."""
    loose = direct.recreated(extra_options={"fatrop": {"tolerance": 1e-1, "constr_viol_tol": 1e-1}})
    assert loose.solve(**step_data).stats.iterations < direct.solve(**step_data).stats.iterations
    for options in ({"bound_pish": 1e-2}, {"bound_push": 1}):
        with pytest.raises(ConfigError, match=f"Fatrop has no .*option '{next(iter(options))}'"):
            direct.recreated(extra_options={"fatrop": options}).solve(**step_data)


@pytest.mark.parametrize("name, index, value, status", [
    ("x0", None, np.nan, "invalid_input_nan"), ("x0", 7, np.inf, "invalid_input_nan"),
    ("p", -1, np.nan, "invalid_input_nan"), ("lbx", "above", 1.0, "invalid_bounds"), ("ubg", -1, np.nan, "invalid_bounds"),
    ("lbg", 0, np.nan, "invalid_bounds")])
def test_refused_inputs_give_a_named_failure_and_no_nan_plan(problem, codegen, step_data, name, index, value, status):
    """The shim checks the inputs before any work (Fatrop can hang on a NaN start; a NaN bound would reach its
    iterates): a non-finite p or x0, or a bound out of order or NaN, is a failed solve whose status says which,
    with no Fatrop instance built for such bounds; the next valid call solves."""
    fresh = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen))
    bad = {key: np.array(value_, dtype=float) for key, value_ in step_data.items()}
    if index is None:
        bad[name][:] = value
    elif index == "above":  # a variable's lower bound above its (finite) upper one
        index = int(np.flatnonzero(np.isfinite(bad["ubx"]))[0])
        bad[name][index] = bad["ubx"][index] + value
    else:
        bad[name][index] = value
    result = fresh.solve(**bad, warm_start=True)
    assert result.stats.status == status and not result.stats.success
    assert np.isnan(result.x).all() and fresh.structure_keys == ()
    assert fresh.solve(**step_data).stats.success


def test_inputs_of_another_size_are_refused_by_name(direct, step_data):
    with pytest.raises(ConfigError, match=r"lbg has 3 entries, the problem \d+"):
        direct.solve(**{**step_data, "lbg": np.zeros(3)})


def test_shim_reports_its_own_work_around_fatrop_as_interface(direct, step_data):
    """The split's parts add up to the call: the shim's checks, row classification and unpacking (timed in C) are
    `interface`, not `outside_solver` (the Python and ctypes around the call)."""
    stats = direct.solve(**step_data).stats
    split = stats.split_ms
    assert split["interface"] > 0 and split["outside_solver"] >= 0
    assert sum(split.values()) == pytest.approx(1e3 * stats.solve_time_s, rel=0.05, abs=0.05)


def test_missing_compiler_falls_back_to_casadis_fatrop(problem, step_data, tmp_path):
    config = SolverConfig(name="fatrop-direct", codegen=CodegenConfig(compiler="no-such-cc", cache_dir=tmp_path))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver = make_solver(problem, config)
    assert not solver.is_direct and "no-such-cc" in solver.direct_error
    assert any("casadi's Fatrop" in str(w.message) for w in caught)
    assert solver.solve(**step_data).stats.success


def test_deadline_returns_the_last_iterate_and_the_solver_stays_usable(direct, step_data):
    """Fatrop has no time limit: the shim throws from a callback past the deadline and Fatrop returns."""
    expected = direct.solve(**step_data)
    stopped = direct.solve(**step_data, time_limit_s=1e-6)
    assert stopped.stats.status == "time_limit_reached" and not stopped.stats.success
    assert np.all(np.isfinite(stopped.x))
    again = direct.solve(**step_data)
    assert again.stats.success and again.stats.iterations == expected.stats.iterations
    np.testing.assert_allclose(again.x, expected.x, atol=1e-12)


def test_the_mpc_builds_its_instances_before_the_clock_and_then_plans_as_before(robot, problem, codegen, step_data):
    """`MPC.prepare_structures` builds the Fatrop instances of the row patterns that steps meet in the first two gait
    cycles (g1 walking meets ~30, each ~11 ms to build); the steps then build none and give the plans, bit for bit, of
    an MPC that built each instance at the first step that needed it. `prepare_structure` builds one instance per
    pattern, once."""
    config = MpcConfig(ocp=TINY, recovery=RecoveryConfig(fallback_solver=None),
                       solver=SolverConfig(name="fatrop-direct", codegen=codegen))
    lazy, prepared = MPC(robot, config, problem=problem), MPC(robot, config, problem=problem)
    prepared.prepare_structures(rate_hz=80.0)
    built = set(prepared.solver.structure_keys)
    assert built and not lazy.solver.structure_keys
    v0 = np.zeros(robot.nv)
    v0[:2] = [0.1, 0.05]
    for t_s in (0.1, 0.1125, 0.125, 0.2, 0.5, 0.9):
        expected, got = lazy.solve(robot.q_nominal, v0, t_s=t_s), prepared.solve(robot.q_nominal, v0, t_s=t_s)
        assert got.success, got.stats
        np.testing.assert_array_equal(got.x, expected.x)
    assert set(prepared.solver.structure_keys) == built and set(lazy.solver.structure_keys) <= built
    bounds = tuple(step_data[name].copy() for name in ("lbx", "ubx", "lbg", "ubg"))
    bounds[2][-1], bounds[3][-1] = -np.inf, np.inf  # the last row dropped: another pattern
    fresh = FatropDirectSolver(problem, SolverConfig(name="fatrop-direct", codegen=codegen))
    for _ in range(2):
        fresh.prepare_structure(*bounds)
        assert fresh.structure_keys == (fresh.structure_key(*bounds),)


def test_a_rehearsed_instance_forgets_its_rehearsal(problem, codegen, step_data, monkeypatch):
    """`prepare_structures` solves on each instance it builds before the clock (its first solve costs more than the
    next) and the instance forgets that solution: a warm step from the instance's multipliers then runs as on an
    instance never rehearsed, bit for bit. The rehearsal here converges (uncapped), and the warm step starts from its
    solution, so an instance that kept the rehearsal's multipliers would stop at once (0 iterations)."""
    monkeypatch.setattr(fatrop_direct, "REHEARSAL_ITERATIONS", 100)
    config = SolverConfig(name="fatrop-direct", codegen=codegen)
    bounds = tuple(step_data[name] for name in ("lbx", "ubx", "lbg", "ubg"))
    plain, rehearsed = FatropDirectSolver(problem, config), FatropDirectSolver(problem, config)
    rehearsed.prepare_structures([(*bounds, step_data["p"], step_data["x0"])] * 2)
    assert rehearsed.structure_keys == (rehearsed.structure_key(*bounds),)
    solution = plain.recreated().solve(**step_data)
    assert solution.stats.success
    warm_step = dict(step_data, x0=solution.x)  # the instance's own multipliers start it (no given ones)
    expected, got = (solver.solve(**warm_step, warm_start=True) for solver in (plain, rehearsed))
    assert got.stats.success and got.stats.iterations == expected.stats.iterations > 0
    np.testing.assert_array_equal(got.x, expected.x)
    # an instance that keeps its converged solution does start from it: what the forgetting prevents
    keeping = plain.recreated()
    assert keeping.solve(**step_data).stats.success
    assert keeping.solve(**warm_step, warm_start=True).stats.iterations == 0
