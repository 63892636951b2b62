"""Real-time iteration (`--solver rti`): iterated at a fixed state it reaches Fatrop's KKT point;
one step per MPC period keeps the robot up in MuJoCo; bad settings are rejected."""

import numpy as np
import pytest

from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.control.loop import ClosedLoop, LoopConfig
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.sim import make_plant
from wbmpc.solvers import make_solver
from wbmpc.solvers.nlp import NlpSolver, SolverConfig
from wbmpc.solvers.rti import (
    DIRECT_QP_BARRIER_INIT,
    FALLBACK_FIRST_CALLS,
    FLAT_FOOT_FALLBACK_FIRST_CALLS,
    FLAT_FOOT_QP_BARRIER_INIT,
    FLAT_FOOT_RTI_QP_TOLERANCE,
    QP_TOLERANCE,
    RtiConfig,
    RtiSolver,
    fallback_first_calls,
    qp_defaults,
)

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


@pytest.mark.parametrize("binding", ["direct", "casadi"])
def test_iterated_rti_converges_to_the_fatrop_solution(fixed_state, binding):
    """On our HPIPM binding and on casadi's conic alike: Fatrop's KKT point, a feasible plan."""
    problem, data, reference = fixed_state
    one = RtiSolver(problem, SolverConfig(name="rti", extra_options={"hpipm_binding": binding})).solve(*data)
    assert one.stats.success, one.stats.status
    assert np.abs(one.x - reference.x).max() > 1e-2  # a single step from the cold guess is not the optimum
    iterated = RtiSolver(problem, SolverConfig(name="rti", extra_options={"sqp_iterations": 12, "step_tolerance": 0.0,
                                                                         "qp_tolerance": 1e-6, "hpipm_binding": binding}))
    if binding == "direct" and not iterated.direct_qp:
        pytest.skip(f"no HPIPM binding here: {iterated.direct_error}")
    assert iterated.direct_qp == (binding == "direct")
    result = iterated.solve(*data)
    assert result.stats.success, result.stats.status
    np.testing.assert_allclose(result.x, reference.x, atol=1e-5)
    # same multipliers (CasADi's sign convention), hence the same KKT point, and a feasible plan
    scale = max(1.0, np.abs(reference.lam_g).max())
    np.testing.assert_allclose(result.lam_g / scale, reference.lam_g / scale, atol=1e-5)
    assert result.stats.max_constraint_violation < 1e-8
    assert result.stats.cost == pytest.approx(reference.stats.cost, rel=1e-8)
    assert set(iterated.last_timing) >= {"linearize_ms", "qp_ms", "evaluate_ms", "cpu_ms"}


def test_the_active_set_guess_takes_the_interior_points_step(fixed_state):
    """The RTI's QP at a state whose plan touches no inequality is solved by the active-set guess (one factorisation,
    `stats.iterations` 1): the step of the interior point (guess off) at a tight QP tolerance, to 1e-7; iterated, the
    same KKT point."""
    problem, data, reference = fixed_state
    results = {}
    for guess in (True, False):
        solver = RtiSolver(problem, SolverConfig(name="rti", extra_options={
            "qp_active_set_guess": guess, "qp_tolerance": 1e-9, "qp_mode": "balance", "sqp_iterations": 3,
            "step_tolerance": 0.0}))
        if not solver.direct_qp:
            pytest.skip(f"no HPIPM binding here: {solver.direct_error}")
        results[guess] = solver.solve(*data)
        assert results[guess].stats.success, results[guess].stats.status
        assert solver.qp.config.active_set_guess is guess
        if guess:
            assert solver.qp.guess_stats["hits"] == 3 and results[guess].stats.iterations == 3
    assert results[False].stats.iterations > 3 * 2
    np.testing.assert_allclose(results[True].x, results[False].x, atol=1e-7)
    scale = max(1.0, np.abs(results[False].lam_g).max())
    np.testing.assert_allclose(results[True].lam_g / scale, results[False].lam_g / scale, atol=1e-7)


def test_failed_qp_is_reported_not_raised(fixed_state):
    problem, (p, lbx, ubx, lbg, ubg, x0), _ = fixed_state
    # (a QP capped at one interior-point iteration fails; the active-set guess, off here, would solve this one)
    solver = RtiSolver(problem, SolverConfig(name="rti", max_iterations=1, extra_options={
        "recovery_barrier_init": None, "qp_active_set_guess": False}))
    result = solver.solve(p, lbx, ubx, lbg, ubg, x0)
    assert not result.stats.success
    assert result.stats.status == ("QP_Maximum_Iterations_Exceeded (balance after speed_abs: "
                                   "QP_Maximum_Iterations_Exceeded)")
    assert result.stats.iterations == 2  # one per mode
    assert np.all(np.isnan(result.x)) and result.stats.max_constraint_violation == np.inf
    # after the first mode failed, the fallback mode goes first for `fallback_first_calls` calls
    again = solver.solve(p, lbx, ubx, lbg, ubg, x0)
    assert again.stats.status == "QP_Maximum_Iterations_Exceeded (speed_abs after balance: QP_Maximum_Iterations_Exceeded)"
    bad = solver.solve(p, lbx, ubx, lbg, ubg, np.full_like(x0, np.nan))
    assert not bad.stats.success and bad.stats.status == "invalid_input_nan"


def test_failed_qp_is_recovered_by_a_converged_fatrop_solve(fixed_state):
    problem, data, reference = fixed_state
    result = RtiSolver(problem, SolverConfig(name="rti", max_iterations=1,
                                             extra_options={"qp_active_set_guess": False})).solve(*data)
    assert result.stats.success
    assert result.stats.status.endswith("(fatrop recovery after rti: QP_Maximum_Iterations_Exceeded (balance after "
                                        "speed_abs: QP_Maximum_Iterations_Exceeded))")
    np.testing.assert_allclose(result.x, reference.x, atol=1e-4)  # converged to Fatrop's (default) tolerance


def test_capped_recovery_is_built_ahead_and_stops_at_its_cap(fixed_state):
    """Real-time runs cap the re-solve (`recovery_max_iterations`) and build it before the clock runs."""
    problem, data, _ = fixed_state
    solver = RtiSolver(problem, SolverConfig(name="rti", max_iterations=1, extra_options={
        "recovery_max_iterations": 2, "qp_active_set_guess": False}))
    solver.prepare_recovery()
    assert solver.recovery_solver is not None and solver.recovery_solver.config.max_iterations == 2
    result = solver.solve(*data)
    assert not result.stats.success and "Maximum_Iterations_Exceeded (fatrop recovery after rti" in result.stats.status
    assert result.stats.iterations <= 2 + 3  # one QP iteration per HPIPM mode, then Fatrop stops after its cap (+1)


def test_bad_rti_settings_name_the_fix(fixed_state):
    problem = fixed_state[0]
    with pytest.raises(ConfigError, match="unknown RTI option.*sqp_iterations"):
        make_solver(problem, SolverConfig(name="rti", extra_options={"iterations": 3}))
    with pytest.raises(ConfigError, match="sqp_iterations must be >= 1"):
        RtiConfig(sqp_iterations=0)
    with pytest.raises(ConfigError, match="recovery_max_iterations must be >= 1"):
        RtiConfig(recovery_max_iterations=0)
    with pytest.raises(ConfigError, match="unknown HPIPM mode"):
        make_solver(problem, SolverConfig(name="rti", extra_options={"qp_mode": "fast"}))
    with pytest.raises(ConfigError, match="qp_tolerance must be positive"):
        RtiConfig(qp_tolerance=0.0)
    with pytest.raises(ConfigError, match="make_solver"):
        NlpSolver(problem, SolverConfig(name="rti"))


def test_hpipm_settings_follow_the_contacts():
    """Flat feet (a wrench cone with rows active on most nodes) start HPIPM from a lower barrier and, for one
    iteration per step, stop it at a looser tolerance; point feet keep 1e3 and 1e-4; given settings win."""
    assert qp_defaults(RtiConfig(), flat_feet=False) == (QP_TOLERANCE, DIRECT_QP_BARRIER_INIT) == (1e-4, 1e3)
    assert qp_defaults(RtiConfig(), flat_feet=True) == (FLAT_FOOT_RTI_QP_TOLERANCE, FLAT_FOOT_QP_BARRIER_INIT)
    assert qp_defaults(RtiConfig(sqp_iterations=5), flat_feet=True) == (QP_TOLERANCE, FLAT_FOOT_QP_BARRIER_INIT)
    assert qp_defaults(RtiConfig(qp_tolerance=1e-6, qp_barrier_init=100.0), flat_feet=True) == (1e-6, 100.0)


def test_qp_fallback_mode_goes_first_after_a_failure_on_point_feet_only(fixed_state):
    """Point feet: after a failed QP the fallback mode goes first for 20 calls (post-push QPs where speed stalls);
    flat feet: never (g1's failed QPs fail in both modes, and balance costs more a QP); a given count wins."""
    assert fallback_first_calls(RtiConfig(), flat_feet=False) == FALLBACK_FIRST_CALLS == 20
    assert fallback_first_calls(RtiConfig(), flat_feet=True) == FLAT_FOOT_FALLBACK_FIRST_CALLS == 0
    assert fallback_first_calls(RtiConfig(fallback_first_calls=3), flat_feet=True) == 3
    assert fallback_first_calls(RtiConfig(fallback_first_calls=0), flat_feet=False) == 0
    with pytest.raises(ConfigError, match="fallback_first_calls must be >= 0"):
        RtiConfig(fallback_first_calls=-1)
    problem = fixed_state[0]  # go2: point feet
    assert RtiSolver(problem, SolverConfig(name="rti")).fallback_first_calls == FALLBACK_FIRST_CALLS


def test_rti_trot_stays_up_in_mujoco(b1z1):
    """One SQP iteration per 12.5 ms step, linearised at the shifted previous plan, on b1_z1."""
    grid = OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.06))
    mpc = MPC(b1z1, MpcConfig(ocp=grid, gait="trot", solver=SolverConfig(name="rti")))
    assert isinstance(mpc.solver, RtiSolver)
    plant = make_plant("mujoco", b1z1)
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    log = ClosedLoop(mpc, plant, LoopConfig(delay_mode="none")).run(0.8)
    a = log.arrays()
    assert not log.fell
    assert log.mpc_failures == 0
    assert a["q"][:, 2].min() > 0.85 * b1z1.q_nominal[2]
    assert np.all(np.abs(a["tau"]) <= b1z1.tau_max + 1e-9)
    assert (np.linalg.norm(a["contact_forces"], axis=2) < 1e-6).any()  # the swing legs really lift
    assert np.all(a["iterations"] >= 1)  # QP iterations of the single SQP step


@pytest.mark.slow
@pytest.mark.parametrize("formulation", ["wb_forward", "centroidal_vel_path", "centroidal_vel", "centroidal_acc_path",
                                         "centroidal_acc"])
def test_iterated_rti_converges_on_every_formulation(formulation):
    """The cost Hessian is Gauss-Newton only for [q, v] states; for [h, q] states it is the exact cost
    Hessian. Either way the SQP fixed point is Fatrop's solution."""
    robot = load_robot("go2")
    ocp = OcpConfig(formulation=formulation, grid=SMALL.grid)
    v0 = np.zeros(robot.nv)
    v0[:3] = [0.1, -0.05, 0.0]
    fatrop = MPC(robot, MpcConfig(ocp=ocp, recovery=RecoveryConfig(fallback_solver=None), solver=SolverConfig(tolerance=1e-9, max_iterations=300)))
    reference = fatrop.solve(robot.q_nominal, v0, t_s=0.0)
    assert reference.success, reference.stats.status
    rti = MPC(robot, MpcConfig(ocp=ocp, recovery=RecoveryConfig(fallback_solver=None), solver=SolverConfig(
        name="rti", extra_options={"sqp_iterations": 15, "step_tolerance": 0.0, "qp_tolerance": 1e-6})), problem=fatrop.problem)
    solution = rti.solve(robot.q_nominal, v0, t_s=0.0)
    assert solution.success, solution.stats.status
    np.testing.assert_allclose(solution.x, reference.x, atol=1e-5)
