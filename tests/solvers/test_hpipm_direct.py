"""Our HPIPM binding (`solvers/hpipm_direct.py`) solves the same QP as casadi's hpipm conic: same step and
multipliers (CasADi's sign convention) on go2's trot QP, in every HPIPM mode including speed_abs, whose
equality multipliers casadi's conic does not return; the RTI and anytime SQP use it where it builds."""

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.solvers.hpipm_direct import DirectQp, HpipmUnavailable, make_qp
from wbmpc.solvers.nlp import SolverConfig
from wbmpc.solvers.qp import QpConfig, StructuredQp, stage_dimensions
from wbmpc.solvers.rti import RtiSolver

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


@pytest.fixture(scope="module")
def qp_data():
    """The QP of the first SQP iteration of go2's trot OCP from a moving state (with active bounds)."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None), solver=SolverConfig(name="rti")))
    calls = []
    solve = mpc.solver.solve

    def recording(*args, **kwargs):
        calls.append(args)
        return solve(*args, **kwargs)

    mpc.solver.solve = recording
    v0 = np.zeros(robot.nv)
    v0[:3] = [0.4, -0.2, 0.0]
    mpc.solve(robot.q_nominal, v0, t_s=0.0)
    (p, lbx, ubx, lbg, ubg, x0), = calls
    problem, nlp = mpc.problem, mpc.problem.nlp
    x, pp = nlp["x"], nlp["p"]
    g, J = ca.Function("qp_jacobian", [x, pp], [nlp["g"], ca.jacobian(nlp["g"], x)])(x0, p)
    gradient = ca.Function("qp_gradient", [x, pp], [ca.gradient(nlp["f"], x)])(x0, p)
    H = ca.Function("qp_hessian", [x, pp], [ca.hessian(nlp["f"], x)[0] + 1e-6 * ca.SX.eye(x.numel())])(x0, p)
    g = np.asarray(g).ravel()
    return problem, (H, gradient, J, lbg - g, ubg - g, lbx - x0, ubx - x0)


def _direct(problem, data, config):
    try:
        return DirectQp(problem, data[0].sparsity(), data[2].sparsity(), config)
    except HpipmUnavailable as exc:
        pytest.skip(f"no HPIPM binding here: {exc}")


def _objective(data, step):
    H, gradient = ca.DM(data[0]), np.asarray(gradient_of(data)).ravel()
    return float(0.5 * step @ np.asarray(H.full()) @ step + gradient @ step)


def gradient_of(data):
    return data[1].full() if isinstance(data[1], ca.DM) else data[1]


@pytest.mark.parametrize("mode", ["balance", "robust", "speed_abs"])
def test_direct_hpipm_returns_casadis_solution(qp_data, mode):
    """balance/robust: casadi's solution to 1e-6; speed_abs (absolute form, it exits on the barrier alone) is less exact,
    but it returns the equality multipliers (casadi's conic returns zeros there): same QP optimum to 1e-5 relative."""
    problem, data = qp_data
    reference = StructuredQp(problem, data[0].sparsity(), data[2].sparsity(),
                             QpConfig(mode="balance", tolerance=1e-6, max_iterations=200)).solve(*data)
    assert reference.success, reference.status
    direct = _direct(problem, data, QpConfig(mode=mode, tolerance=1e-6, max_iterations=200))
    atol = 1e-6 if mode != "speed_abs" else 2e-2
    for H, J in ((data[0], data[2]), (np.array(data[0].nonzeros()), np.array(data[2].nonzeros()))):  # DMs or nonzeros
        result = direct.solve(H, data[1], J, *data[3:])
        assert result.success, result.status
        assert _objective(data, result.step) == pytest.approx(_objective(data, reference.step), rel=1e-5)
        scale = max(1.0, np.abs(reference.step).max())
        np.testing.assert_allclose(result.step / scale, reference.step / scale, atol=atol)
        lam_scale = max(1.0, np.abs(reference.lam_g).max(), np.abs(reference.lam_x).max())
        np.testing.assert_allclose(result.lam_g / lam_scale, reference.lam_g / lam_scale, atol=atol)
        np.testing.assert_allclose(result.lam_x / lam_scale, reference.lam_x / lam_scale, atol=atol)
    # some bounds and rows are active, and the dynamics multipliers are not zero: the comparison covers their signs
    assert np.abs(reference.lam_x).max() > 1e-3 and np.abs(reference.lam_g[direct.gap_index]).max() > 1e-1


def test_a_failed_direct_qp_reports_hpipms_status(qp_data):
    problem, data = qp_data
    capped = QpConfig(mode="speed_abs", tolerance=1e-10, max_iterations=1, active_set_guess=False)
    result = _direct(problem, data, capped).solve(*data)
    assert not result.success and result.status == "QP_Maximum_Iterations_Exceeded" and result.iterations == 1


def test_the_sqp_solvers_use_it_and_fall_back_to_casadis_conic(qp_data, monkeypatch):
    """Where the binding cannot be built (here: no compiler) the RTI and the anytime SQP warn, name the reason
    (`direct_error`, the run's metrics `direct_fallback`) and run on casadi's conic: an MPC step still succeeds."""
    problem, data = qp_data
    rti = RtiSolver(problem, SolverConfig(name="rti"))
    if rti.direct_error is not None:
        pytest.skip(f"no HPIPM binding here: {rti.direct_error}")
    assert rti.direct_qp and isinstance(rti.qp, DirectQp) and isinstance(rti.fallback_qp, DirectQp)
    import wbmpc.solvers.hpipm_direct as hd

    def unavailable(*args, **kwargs):
        raise HpipmUnavailable("no compiler")

    monkeypatch.setattr(hd, "shim_library", unavailable)
    qp, error = make_qp(problem, data[0].sparsity(), data[2].sparsity(), QpConfig(mode="speed_abs"))
    # casadi's conic in the relative mode: its speed_abs returns no equality multipliers
    assert isinstance(qp, StructuredQp) and qp.config.mode == "speed" and "no compiler" in error
    with pytest.warns(RuntimeWarning, match="direct binding is unavailable.*no compiler"):
        fallback = RtiSolver(problem, SolverConfig(name="rti"))
    assert not fallback.direct_qp and "no compiler" in fallback.direct_error
    assert isinstance(fallback.qp, StructuredQp) and isinstance(fallback.fallback_qp, StructuredQp)
    robot = load_robot("go2")
    with pytest.warns(RuntimeWarning, match="direct binding is unavailable"):
        mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp"), step_budget_s=0.05))
    assert all(isinstance(q, StructuredQp) for q in (mpc.solver.qp, *mpc.solver.capped_qps.values()))
    first = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0)
    second = mpc.solve(first.q[1], first.v[1], t_s=0.0125)
    assert first.success and second.success, second.stats.status
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import solver_summary

    assert "no compiler" in solver_summary(mpc, RunConfig(solver="sqp", delay_ms=6.0))["direct_fallback"]


def test_casadis_conic_on_request_and_bad_binding_names_the_fix(qp_data):
    from wbmpc.errors import ConfigError

    problem, _ = qp_data
    conic = RtiSolver(problem, SolverConfig(name="rti", extra_options={"hpipm_binding": "casadi"}))
    assert not conic.direct_qp and isinstance(conic.qp, StructuredQp) and conic.qp.config.mode == "speed"
    with pytest.raises(ConfigError, match="unknown hpipm_binding 'ctypes'; available: direct, casadi"):
        RtiSolver(problem, SolverConfig(name="rti", extra_options={"hpipm_binding": "ctypes"}))


def _tight(mode="balance", eliminate=True):
    return QpConfig(mode=mode, tolerance=1e-9, max_iterations=200, eliminate_fixed=eliminate)


def _assert_same_solution(result, reference, atol, lam_atol=1e-4):
    """Same step to atol; same multipliers to lam_atol relative to the largest (a few rows' are less well determined:
    one go2 row's differs by 7e-6 of the largest between two 1e-9 solutions)."""
    scale = max(1.0, np.abs(reference.step).max())
    np.testing.assert_allclose(result.step / scale, reference.step / scale, atol=atol)
    lam_scale = max(1.0, np.abs(reference.lam_g).max(), np.abs(reference.lam_x).max())
    np.testing.assert_allclose(result.lam_g / lam_scale, reference.lam_g / lam_scale, atol=lam_atol)
    np.testing.assert_allclose(result.lam_x / lam_scale, reference.lam_x / lam_scale, atol=lam_atol)


def test_fixed_inputs_and_the_initial_state_left_out_give_the_same_solution(qp_data):
    """HPIPM solves the QP without the inputs with lb == ub and without x_0 (fixed by its rows): smaller stages, the same
    step, and the left-out bounds' and initial-state rows' multipliers (from stationarity) those of the full QP."""
    problem, data = qp_data
    lbx, ubx = data[5], data[6]
    full, reduced = _direct(problem, data, _tight(eliminate=False)), _direct(problem, data, _tight())
    reference, result = full.solve(*data), reduced.solve(*data)
    assert reference.success and result.success, (reference.status, result.status)
    fixed = (lbx == ubx)[reduced.u_index]
    assert fixed.any() and not (lbx == ubx)[reduced.x_index].any()  # the swing feet's forces; x_0 by rows
    sizes, full_sizes = reduced.solved_sizes, full.solved_sizes
    assert sizes["nx"][0] == 0 and full_sizes["nx"][0] == problem.nx
    assert sum(full_sizes["nu"]) - sum(sizes["nu"]) == fixed.sum()
    assert sum(full_sizes["ng"]) - sum(sizes["ng"]) == np.asarray(problem.rows["x0"]).size
    _assert_same_solution(result, reference, atol=1e-7)
    np.testing.assert_array_equal(result.step[reduced.u_index[fixed]],
                                  lbx[reduced.u_index[fixed]])
    # the eliminated inputs' and the initial-state rows' multipliers are not trivially zero
    assert np.abs(reference.lam_x[reduced.u_index[fixed]]).max() > 1e-3
    assert np.abs(reference.lam_g[np.asarray(problem.rows["x0"]).ravel()]).max() > 1e-3


def test_each_pattern_of_fixed_inputs_has_its_hpipm_instance(qp_data):
    """Freeing some fixed inputs (another contact pattern) builds a second HPIPM instance; the first pattern's is reused
    when it comes back; every pattern's solution is the full QP's."""
    problem, data = qp_data
    lbx, ubx = data[5].copy(), data[6].copy()
    full, reduced = _direct(problem, data, _tight(eliminate=False)), _direct(problem, data, _tight())
    fixed = np.nonzero(lbx == ubx)[0]
    freed_lbx, freed_ubx = lbx.copy(), ubx.copy()
    freed_lbx[fixed[:3]] -= 10.0
    freed_ubx[fixed[:3]] += 10.0
    freed = (*data[:5], freed_lbx, freed_ubx)
    for qp_data_k, rebuilds in ((data, 1), (freed, 2), (data, 2)):
        result = reduced.solve(*qp_data_k)
        assert result.success and reduced.rebuilds == rebuilds
        _assert_same_solution(result, full.solve(*qp_data_k), atol=1e-7)


def test_the_rti_leaves_fixed_inputs_out_and_takes_the_same_step(qp_data):
    """RtiSolver's default QP eliminates; `qp_eliminate_fixed=False` keeps them: the same RTI steps (QPs solved to 1e-8;
    at the RTI's own QP tolerance, 1e-4, they differ by up to 4e-4; at 1e-9 the full QP of the second step sits at
    HPIPM's limits, a round-off change in its data sent it to max iterations)."""
    problem, _ = qp_data
    robot = load_robot("go2")
    steps = []
    for eliminate in (True, False):
        mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None),
                                   solver=SolverConfig(name="rti", extra_options={
                                       "qp_eliminate_fixed": eliminate, "qp_tolerance": 1e-8, "qp_mode": "balance"})))
        if mpc.solver.direct_error is not None:
            pytest.skip(f"no HPIPM binding here: {mpc.solver.direct_error}")
        assert mpc.solver.qp.config.eliminate_fixed is eliminate
        v0 = np.zeros(robot.nv)
        v0[:3] = [0.4, -0.2, 0.0]
        first = mpc.solve(robot.q_nominal, v0, t_s=0.0)
        second = mpc.solve(first.q[1], first.v[1], t_s=0.0125)
        assert first.success and second.success
        steps.append(np.concatenate([second.q.ravel(), second.v.ravel()]))
        if eliminate:
            assert sum(mpc.solver.qp.solved_sizes["nu"]) < sum(stage_dimensions(mpc.problem)["nu"])
    np.testing.assert_allclose(steps[0], steps[1], atol=1e-7)


def test_malformed_qp_data_is_refused_by_name(qp_data):
    """The shim reads the data by index: data of another size, or gap rows that are no equalities, raise before HPIPM."""
    from wbmpc.errors import WbmpcError

    problem, data = qp_data
    qp = _direct(problem, data, QpConfig(mode="speed_abs"))
    with pytest.raises(ValueError, match="QP data of sizes"):
        qp.solve(data[0], data[1], np.asarray(data[2].nonzeros())[:-1], *data[3:])
    lbg = np.asarray(data[3], dtype=float).copy()
    lbg[qp.gap_index[0]] -= 1.0
    with pytest.raises(WbmpcError, match="dynamics rows must be equalities"):
        qp.solve(data[0], data[1], data[2], lbg, *data[4:])


def _inactive(data, margin=10.0):
    """The QP with every inequality (rows and bounds with lb < ub) widened by `margin` on its finite sides: none active."""
    lbg, ubg, lbx, ubx = (np.asarray(v, dtype=float).copy() for v in data[3:])
    for lower, upper in ((lbg, ubg), (lbx, ubx)):
        inequality = lower < upper
        lower[inequality & np.isfinite(lower)] -= margin
        upper[inequality & np.isfinite(upper)] += margin
    return (*data[:3], lbg, ubg, lbx, ubx)


def test_the_active_set_guess_solves_a_qp_with_no_active_inequality_in_one_factorisation(qp_data):
    """Where no inequality is active, eliminating the equality rows and dropping the inequalities gives the interior
    point's solution (step and multipliers, the equality rows' from stationarity) at one factorisation."""
    problem, data = qp_data
    data = _inactive(data)
    guessed, interior = (_direct(problem, data, replace(_tight(), active_set_guess=on)) for on in (True, False))
    reference, result = interior.solve(*data), guessed.solve(*data)
    assert reference.success and result.success, (reference.status, result.status)
    assert guessed.guess_stats == {"tries": 1, "hits": 1, "last": 0} and interior.guess_stats["tries"] == 0
    assert result.iterations == 1 < reference.iterations
    _assert_same_solution(result, reference, atol=1e-7, lam_atol=1e-7)
    assert np.abs(reference.lam_g).max() > 1.0  # the equality rows' multipliers are not trivially zero


def test_a_wrong_active_set_guess_falls_back_to_the_interior_point(qp_data):
    """go2's QP from a moving state has active bounds: the guess violates them, the interior point solves the QP (the
    same solution as without the guess), and the next calls skip the guess for a while."""
    problem, data = qp_data
    guessed, interior = (_direct(problem, data, replace(_tight(), active_set_guess=on)) for on in (True, False))
    reference, result = interior.solve(*data), guessed.solve(*data)
    assert reference.success and result.success, (reference.status, result.status)
    assert guessed.guess_stats == {"tries": 1, "hits": 0, "last": 1}
    np.testing.assert_array_equal(result.step, reference.step)
    guessed.solve(*_inactive(data))  # skipped although it would be right
    assert guessed.guess_stats == {"tries": 1, "hits": 0, "last": -1}
