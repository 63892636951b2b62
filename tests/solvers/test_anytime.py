"""Anytime SQP (`--solver sqp`): converges to Fatrop's KKT point without a deadline, stops at its deadline
(an injected clock: no timing assertions) with the best iterate and its status, refuses a budget shorter
than one iteration, and never hands the loop NaN."""

import numpy as np
import pytest

from wbmpc.control import MPC, MpcConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.solvers import make_solver
from wbmpc.solvers.anytime import AnytimeConfig, AnytimeSqpSolver, DeadlineError
from wbmpc.solvers.nlp import SolverConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


class FakeClock:
    """Advances `tick` seconds per reading: the solver's time is the number of its clock readings."""

    def __init__(self, tick: float = 1e-3):
        self.now, self.tick = 0.0, tick

    def __call__(self) -> float:
        self.now += self.tick
        return self.now


def _solver(problem, clock=None, **options):
    return AnytimeSqpSolver(problem, SolverConfig(name="sqp", extra_options={"qp_tolerance": 1e-6, **options}), clock=clock)


@pytest.mark.parametrize("binding", ["direct", "casadi"])
def test_without_deadline_it_converges_to_the_fatrop_solution(fixed_state, binding):
    problem, data, reference = fixed_state
    solver = make_solver(problem, SolverConfig(name="sqp", extra_options={"qp_tolerance": 1e-6,
                                                                        "dual_tolerance": 1e-7,
                                                                        "primal_tolerance": 1e-9,
                                                                        "hpipm_binding": binding}))
    assert isinstance(solver, AnytimeSqpSolver)
    if binding == "direct" and not solver.direct_qp:
        pytest.skip(f"no HPIPM binding here: {solver.direct_error}")
    assert solver.direct_qp == (binding == "direct")
    result = solver.solve(*data)
    assert result.stats.success and result.stats.status.startswith("Converged"), result.stats.status
    details = result.stats.details
    assert 1 < details["sqp_iterations"] <= 20
    assert details["primal_residual"] < 1e-9 and details["budget_ms"] is None and not details["late"]
    np.testing.assert_allclose(result.x, reference.x, atol=1e-5)
    assert result.stats.max_constraint_violation < 1e-8
    # every accepted step lowered the merit function: lengths in (0, 1], the full step near the solution
    assert all(0 < alpha <= 1 for alpha in details["step_lengths"]) and details["step_lengths"][0] == 1.0


def test_stops_at_its_deadline_with_the_best_iterate(fixed_state):
    problem, (p, lbx, ubx, lbg, ubg, x0), _ = fixed_state
    clock = FakeClock()
    solver = _solver(problem, clock=clock, dual_tolerance=1e-9, primal_tolerance=1e-12)
    solver.solve(p, lbx, ubx, lbg, ubg, x0)  # cold: no deadline, measures the iterations
    one_iteration_s = solver.min_iteration_s
    assert one_iteration_s is not None and one_iteration_s > 0
    merits = []
    for budget_iterations in (1.5, 3.5):
        start = clock.now
        deadline = start + budget_iterations * one_iteration_s * solver.anytime.safety
        result = solver.solve(p, lbx, ubx, lbg, ubg, x0, warm_start=True, deadline=deadline)
        details = result.stats.details
        assert result.stats.status == "Deadline" and result.stats.success
        assert 1 <= details["sqp_iterations"] <= int(budget_iterations) + 1
        assert clock.now <= deadline + one_iteration_s  # stopped at the deadline, not after another iteration
        assert np.all(np.isfinite(result.x))
        assert details["primal_residual"] == result.stats.max_constraint_violation
        # the dual residual of the last iterate linearised: there is one after two iterations
        assert np.isfinite(details["dual_residual"]) == (details["sqp_iterations"] > 1)
        merits.append((details["sqp_iterations"], result.stats.max_constraint_violation))
    # more budget, more iterations, a more feasible iterate
    assert merits[1][0] > merits[0][0] and merits[1][1] <= merits[0][1]
    # kkt_at_exit: the returned iterate is linearised once more for its own dual residual
    exact = _solver(problem, clock=FakeClock(), kkt_at_exit=True)
    exact.solve(p, lbx, ubx, lbg, ubg, x0)
    one = exact.solve(p, lbx, ubx, lbg, ubg, x0, warm_start=True, deadline=exact.clock.now)
    assert one.stats.details["sqp_iterations"] == 1 and np.isfinite(one.stats.details["dual_residual"])


def test_a_budget_below_one_iteration_is_refused(fixed_state):
    problem, data, _ = fixed_state
    # 10 us: below half of any QP of this go2 OCP (0.3-0.8 ms of CPU, shorter once the caches are warm)
    solver = _solver(problem, clock=FakeClock(), budget_ms=0.01)
    with pytest.raises(DeadlineError, match="shorter than one QP"):
        solver.solve(*data)  # the cold first step measures the iteration and refuses the budget


def test_bad_settings_name_the_fix():
    with pytest.raises(Exception, match="clock"):
        AnytimeConfig(clock="sundial")
    with pytest.raises(Exception, match="budget_ms"):
        AnytimeConfig(budget_ms=0.0)
    with pytest.raises(Exception, match="line search"):
        AnytimeConfig(backtrack=1.5)


def test_mpc_step_past_its_budget_still_makes_one_iteration_and_never_nan():
    """Through the MPC: the step budget reaches the solver as a deadline; a warm step whose budget is gone
    before the solver starts still makes one iteration (a plan comes out of every step), finite."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp")))
    first = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0)  # cold: converged
    assert first.success and first.stats.details["sqp_iterations"] >= 1
    second = mpc.solve(first.q[1], first.v[1], t_s=0.0125, budget_s=1e-6)
    assert second.success, second.stats.status
    assert second.stats.details["sqp_iterations"] == 1 and second.stats.details["late"]
    assert np.all(np.isfinite(second.tau)) and np.all(np.isfinite(second.q))


def test_mpc_refuses_a_budget_below_one_iteration_on_the_first_step():
    robot = load_robot("go2")
    clock = FakeClock()
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp"), step_budget_s=1e-4))
    mpc.solver.clock = clock
    with pytest.raises(DeadlineError):
        mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0, budget_s=1e-4)


def test_a_slow_first_step_before_the_solver_is_not_taken_for_a_short_budget(monkeypatch):
    """The cold first step's own work before the solver (one-off costs, a load spike on a wall clock: here 9.7 ms
    of a 10 ms budget) does not count against the budget check, which only asks whether a QP fits the budget."""
    robot = load_robot("go2")
    clock = FakeClock(tick=1e-7)
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp"), step_budget_s=0.01))
    mpc.solver.clock = clock
    advance = mpc.references.advance  # the step's own work before the solver starts

    def slow_advance(*args, **kwargs):
        clock.now += 9.7e-3
        return advance(*args, **kwargs)

    monkeypatch.setattr(mpc.references, "advance", slow_advance)
    assert mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0).success


def test_realtime_loop_with_the_anytime_solver_and_delay_compensation_stays_up():
    """`--delay-mode realtime` with the anytime SQP and delay compensation on the small robot: it stays up, every
    answer's delay is measured by the simulation (transport included: never below the solver's time) and the
    solver reports its iterations per step. No timing assertions."""
    from wbmpc.control.loop import ClosedLoop, LoopConfig
    from wbmpc.sim import make_plant

    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.02, dt_last_s=0.08)),
                               gait="stand", solver=SolverConfig(name="sqp"), step_budget_s=0.01,
                               delay_compensation=True))
    plant = make_plant("pinocchio", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    log = ClosedLoop(mpc, plant, LoopConfig(delay_mode="realtime")).run(0.5)
    assert not log.fell and log.mpc_failures == 0
    assert len(log.delay_ms) == len(log.solve_ms) - 1 >= 5
    assert all(d >= s for d, s in zip(log.delay_ms, log.solve_ms[1:]))
    details = log.solver_details()
    assert details["sqp_iterations"].size == len(log.solve_ms) and np.all(details["sqp_iterations"] >= 1)


def test_a_solver_asked_to_be_compiled_that_was_not_says_so(monkeypatch):
    """Honest reporting: no compiler -> the CasADi VM, and the run's metrics name it (not a warning alone)."""
    import wbmpc.solvers.rti as rti
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import solver_summary
    from wbmpc.solvers.codegen import CompileError

    def no_compiler(*args, **kwargs):
        raise CompileError("gcc not found")

    monkeypatch.setattr(rti, "compile_nlp", no_compiler)
    robot = load_robot("go2")
    with pytest.warns(RuntimeWarning, match="compiled RTI unavailable"):
        mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp", compiled=True)))
    summary = solver_summary(mpc, RunConfig(solver="sqp", compiled=True, delay_ms=6.0))
    assert summary["solver"] == "sqp" and summary["compiled_requested"] and not summary["solver_compiled"]
    assert "gcc not found" in summary["compile_error"]
    # the run's defaults: anytime SQP with a budget on CPU time and delay compensation with a simulated delay
    from wbmpc.control.policy import default_solver
    from wbmpc.scenarios import make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    assert default_solver(compiled=False, delay_mode="none") == "sqp" and default_solver(True, "none") == "fatrop-direct"
    assert default_solver(True, "realtime") == "sqp"
    config = RunConfig(solver="auto", compiled=True, delay_ms=6.0)
    mpc_config = mpc_config_for(make_scenario("push", robot, config.options), config, robot)
    assert mpc_config.solver.name == "sqp" and mpc_config.delay_compensation
    assert mpc_config.solver.extra_options["clock"] == "cpu" and mpc_config.step_budget_s == pytest.approx(0.01)
    # a solver with a deadline drops the arm's velocity rows in push recovery mode (post-push QPs stay feasible)
    assert mpc_config.push.relaxed_rows == ("ee_vel",)
    converged = mpc_config_for(make_scenario("push", robot, config.options), RunConfig(solver="auto", compiled=True), robot)
    assert converged.step_budget_s is None and converged.push.relaxed_rows == ()


class FailingQp:
    """Stands in for the HPIPM QP: a failed solve (iteration cap) that returns `step` (NaN: no usable iterate)
    and burns `cost_s` on the solver's FakeClock, as a QP that runs into its iteration cap after a push does."""

    def __init__(self, real, clock: FakeClock, step=None, cost_s: float = 5e-3):
        self.real, self.clock, self.step, self.cost_s, self.calls = real, clock, step, cost_s, 0
        self.config = real.config

    def solve(self, *data):
        from wbmpc.solvers.qp import QpResult

        self.calls += 1
        self.clock.now += self.cost_s
        exact = self.real.solve(*data)
        step = exact.step if self.step is None else np.full_like(exact.step, self.step)
        return QpResult(step=step, lam_g=exact.lam_g, lam_x=exact.lam_x, status="QP_Maximum_Iterations_Exceeded",
                        success=False, iterations=30, solve_time_s=self.cost_s)


def _failing(solver, clock, step):
    failing = FailingQp(solver.qp, clock, step)
    solver.qp = failing
    solver.capped_qps.clear()  # every QP is the failing one
    return failing


def _assert_no_fatrop_recovery(solver, result):
    """A step with a deadline never runs the converged Fatrop re-solve (built lazily at its first use)."""
    assert solver.recovery_solver is None and "recovery_ms" not in solver.last_timing
    assert "fatrop recovery" not in result.stats.status


def test_a_failed_qp_under_a_deadline_returns_in_time_with_a_counted_status(fixed_state):
    """A QP that fails with no usable iterate: the warm step with a deadline ends right after it (no converged
    Fatrop re-solve, no second QP mode), failed, with the failure counted; never NaN handed on as a plan."""
    problem, (p, lbx, ubx, lbg, ubg, x0), _ = fixed_state
    clock = FakeClock()
    solver = _solver(problem, clock=clock, fallback_qp_mode="balance")
    solver.solve(p, lbx, ubx, lbg, ubg, x0)  # cold: converges, measures the iterations
    failing = _failing(solver, clock, step=np.nan)
    solver.fallback_qp = FailingQp(solver.fallback_qp, clock, np.nan)
    start = clock.now
    deadline = start + 3e-3  # shorter than the failing QP: no time for the fallback mode after it
    result = solver.solve(p, lbx, ubx, lbg, ubg, x0, warm_start=True, deadline=deadline)
    _assert_no_fatrop_recovery(solver, result)
    assert not result.stats.success and "QP_Maximum_Iterations_Exceeded" in result.stats.status
    assert "no time for balance" in result.stats.status and solver.fallback_qp.calls == 0
    assert failing.calls == 1 and result.stats.details["qp_failures"] == 1
    assert result.stats.details["inexact_steps"] == 0 and result.stats.details["late"]
    assert clock.now - start < failing.cost_s + 100 * clock.tick  # the QP and a few clock readings, no re-solve


def test_a_failed_qps_usable_iterate_is_taken_when_it_lowers_the_merit(fixed_state):
    """HPIPM stopped at its iteration cap with a good iterate (here the exact step): the line search takes it,
    the step succeeds as an inexact one and ends (its QP took the whole cap)."""
    problem, (p, lbx, ubx, lbg, ubg, x0), _ = fixed_state
    clock = FakeClock()
    solver = _solver(problem, clock=clock)
    solver.solve(p, lbx, ubx, lbg, ubg, x0)
    failing = _failing(solver, clock, step=None)
    result = solver.solve(p, lbx, ubx, lbg, ubg, x0, warm_start=True, deadline=clock.now + 1.0)
    _assert_no_fatrop_recovery(solver, result)
    assert result.stats.success and "inexact step taken" in result.stats.status, result.stats.status
    details = result.stats.details
    assert details["inexact_steps"] == 1 and details["qp_failures"] == 1 and details["sqp_iterations"] == 1
    assert failing.calls == 1 and np.all(np.isfinite(result.x))
    # a garbage iterate (a huge step) is rejected by the line search, not applied
    _failing(solver, clock, step=1e6)
    rejected = solver.solve(p, lbx, ubx, lbg, ubg, x0, warm_start=True, deadline=clock.now + 1.0)
    _assert_no_fatrop_recovery(solver, rejected)
    assert not rejected.stats.success and "rejected by the line search" in rejected.stats.status


def test_the_qp_iteration_cap_follows_the_time_left(fixed_state):
    """With a deadline the QP's HPIPM iteration cap is the largest that fits the time left (never below
    min_qp_iterations); without one, the full cap."""
    from wbmpc.solvers.anytime import QP_ITERATION_CAPS

    problem = fixed_state[0]
    solver = _solver(problem, clock=FakeClock(), min_qp_iterations=6)
    assert solver.qp_for(1.0) is solver.qp  # nothing measured yet
    for n, t in ((3, 2.65e-3), (10, 6.5e-3), (5, 3.75e-3)):  # 1 ms + 0.55 ms per iteration
        solver.record_qp(t, n)
    assert solver.qp_iteration_s == pytest.approx(0.55e-3, rel=1e-6)
    per = solver.anytime.safety * solver.qp_iteration_s
    assert solver.qp_for(9.5 * per).config.max_iterations == 9
    assert solver.qp_for(1.0 * per).config.max_iterations == 6  # the floor
    assert solver.qp_for(1.0) is solver.qp
    assert all(solver.capped_qps[cap].config.max_iterations == cap for cap in QP_ITERATION_CAPS
               if cap < solver.qp.config.max_iterations)


def test_mpc_holds_the_last_good_plan_at_once_when_a_step_with_a_deadline_fails(monkeypatch):
    """A failed step of the anytime SQP with a step budget: no recovery ladder (converged re-solves of 50-150 ms),
    the last good plan shifted in time, counted as failed, finite torques."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait="trot", solver=SolverConfig(name="sqp"), step_budget_s=0.01))
    first = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t_s=0.0)
    assert first.success
    failing = FailingQp(mpc.solver.qp, FakeClock(), np.nan, cost_s=0.0)
    mpc.solver.qp = failing
    mpc.solver.capped_qps.clear()
    monkeypatch.setattr(mpc.recovery, "recover", lambda *a, **k: pytest.fail("no recovery ladder within a deadline"))
    second = mpc.solve(first.q[1], first.v[1], t_s=0.0125)
    assert not second.success and second.held_previous
    assert "no recovery re-solve past the step's deadline" in second.stats.status
    assert second.stats.details["qp_failures"] == 1
    assert np.all(np.isfinite(second.tau)) and np.all(np.isfinite(second.q))
