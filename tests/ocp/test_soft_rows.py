"""Soft rows (L1-penalised slacks, ocp/problem.py) and when the MPC frees them (control/mpc.py)."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control import MPC, Commands, CostWeights, MpcConfig, PushConfig, RecoveryConfig
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers.nlp import NlpSolver, SolverConfig

GRID = TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06)
SOFT_FEET = OcpConfig(grid=GRID, soft_rows=("foot_vel",))  # a1 has no arm: soften its foot velocity rows


@pytest.fixture(scope="module")
def a1():
    return load_robot("a1")


class Capture:
    """Wraps an NlpSolver's solve and keeps the arguments and result of each call."""

    def __init__(self, solver):
        self.solver, self.calls = solver, []
        self._solve = solver.solve
        solver.solve = self

    def __call__(self, p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        result = self._solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)
        self.calls.append({"p": p, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg, "x0": x0, "result": result})
        return result


def test_slacks_sit_on_input_nodes_1_to_n_minus_1_and_unknown_tags_are_refused(a1):
    problem = OcpProblem(a1, SOFT_FEET)
    n_feet, N = len(a1.feet), GRID.n_intervals
    assert problem.n_slack_variables == 2 * 3 * n_feet * (N - 1)
    assert problem.idx["slack"].shape == (N - 1, 2 * 3 * n_feet)
    assert OcpProblem(a1, OcpConfig(grid=GRID, soft_rows=("ee_vel",))).n_slack_variables == 0  # no arm
    with pytest.raises(ConfigError, match="cannot be softened"):
        OcpConfig(soft_rows=("dynamics",))


def _trot_step(a1, ocp: OcpConfig, weight: float, q, v):
    """One trot step (t = 0.11 s: a diagonal pair in swing) with the slacks forced free."""
    # the gait's own period in push recovery mode too: the hard and soft steps plan the same schedule
    mpc = MPC(a1, MpcConfig(ocp=ocp, gait="trot", recovery=RecoveryConfig(fallback_solver=None), weights=CostWeights(soft_constraint=weight),
                            push=PushConfig(gait_period_scale=None)))
    capture = Capture(mpc.solver)
    mpc.enter_push_recovery()  # as after a push
    solution = mpc.solve(q, v, Commands(), t_s=0.11)
    return mpc, solution, capture.calls[-1]


def test_free_slacks_stay_zero_and_leave_a_feasible_plan_unchanged(a1):
    """Exact penalty: a weight above the rows' multipliers gives the hard OCP's solution. The state is
    node 1 of a plan (a nominal MPC step); from rest the swing feet's first 10 ms ask for more."""
    first = MPC(a1, MpcConfig(ocp=replace(SOFT_FEET, soft_rows=()), gait="trot", recovery=RecoveryConfig(fallback_solver=None)))
    plan = first.solve(a1.q_nominal, np.zeros(a1.nv), Commands(), t_s=0.1)
    assert plan.success
    q, v = plan.q[1], plan.v[1]
    _, hard, _ = _trot_step(a1, replace(SOFT_FEET, soft_rows=()), 100.0, q, v)
    mpc, soft, call = _trot_step(a1, SOFT_FEET, 100.0, q, v)
    assert hard.success and soft.success
    assert np.isinf(call["ubx"][mpc.problem.idx["slack"]]).all()  # really free
    assert np.abs(mpc.problem.unpack(call["result"].x)["slack"]).max() < 1e-4
    np.testing.assert_allclose(soft.tau, hard.tau, atol=0.05)  # N m, of torques up to ~20
    np.testing.assert_allclose(soft.q, hard.q, atol=1e-4)


def test_slacks_make_an_infeasible_ocp_solvable_with_the_least_l1_violation(a1):
    """Joints locked (a rigid body) but FL and RL, on the same side, asked to move at +1 and -1 m/s along x
    on node 2: no motion does both (rigid rotations give them the same v_x), the least L1 violation is 2."""
    mpc = MPC(a1, MpcConfig(ocp=SOFT_FEET, gait="stand", recovery=RecoveryConfig(fallback_solver=None)))
    capture = Capture(mpc.solver)
    mpc.enter_push_recovery()
    mpc.solve(a1.q_nominal, np.zeros(a1.nv), Commands(), t_s=0.0)
    problem, call = mpc.problem, capture.calls[-1]
    lbx, ubx, lbg, ubg = (np.array(call[k], dtype=float) for k in ("lbx", "ubx", "lbg", "ubg"))
    locked = problem.idx["v"][1:, 6:]
    lbx[locked] = ubx[locked] = 0.0
    rows = problem.rows["foot_vel"].reshape(len(problem.row_nodes["foot_vel"]), len(a1.feet), 3)
    node = list(problem.row_nodes["foot_vel"]).index(2)
    fl, rl = a1.feet.index("FL_foot"), a1.feet.index("RL_foot")
    lbg[rows[node, fl, 0]] = ubg[rows[node, fl, 0]] = 1.0
    lbg[rows[node, rl, 0]] = ubg[rows[node, rl, 0]] = -1.0
    solver = NlpSolver(problem, SolverConfig(max_iterations=60))
    soft = solver.solve(call["p"], lbx, ubx, lbg, ubg, call["x0"])
    assert soft.stats.success, soft.stats.status
    assert soft.stats.max_constraint_violation < 1e-5
    slack = problem.unpack(soft.x)["slack"]
    assert slack.sum() == pytest.approx(2.0, abs=0.02)
    pinned = ubx.copy()
    pinned[problem.idx["slack"]] = 0.0  # the hard OCP
    hard = solver.solve(call["p"], lbx, pinned, lbg, ubg, call["x0"])
    assert not hard.stats.success


def test_a_push_frees_the_slacks_and_relaxes_rows_and_nominal_steps_do_neither(a1):
    config = MpcConfig(ocp=SOFT_FEET, gait="trot", recovery=RecoveryConfig(fallback_solver=None),
                       push=PushConfig(hold_s=0.2, relaxed_rows=("foot_vel",)))
    mpc = MPC(a1, config)
    capture = Capture(mpc.solver)
    slack = mpc.problem.idx["slack"]
    rows = mpc.problem.rows["foot_vel"].reshape(-1, len(a1.feet), 3)[..., 2]  # v_z: constrained stance or swing
    v = np.zeros(a1.nv)
    mpc.solve(a1.q_nominal, v, Commands(), t_s=0.0)
    call = capture.calls[-1]
    assert (call["ubx"][slack] == 0).all() and np.isfinite(call["ubg"][rows]).all()  # nominal: the hard OCP
    v[1] = 1.0  # a lateral kick: 1 m/s off the plan and the command
    mpc.solve(a1.q_nominal, v, Commands(), t_s=0.0125)
    call = capture.calls[-1]
    assert np.isinf(call["ubx"][slack]).all() and np.isinf(call["ubg"][rows]).all()
    assert mpc.push_mode.until_t_s == pytest.approx(0.2125)
    mpc.reset()
    assert mpc.push_mode.until_t_s is None


def test_a_base_velocity_far_from_the_command_keeps_the_push_mode(a1):
    mpc = MPC(a1, MpcConfig(ocp=OcpConfig(grid=GRID), gait="stand", recovery=RecoveryConfig(fallback_solver=None),
                            push=PushConfig(hold_s=0.2)))
    v = np.zeros(a1.nv)
    v[0] = 0.5  # moving at 0.5 m/s while commanded to stand: still drifting away after a push
    mpc.solve(a1.q_nominal, v, Commands(), t_s=0.0)
    assert mpc.push_mode.until_t_s == pytest.approx(0.2)
    mpc.reset()
    mpc.solve(a1.q_nominal, v, Commands(base_velocity_m_s=np.array([0.5, 0.0, 0.0])), t_s=0.0)
    assert mpc.push_mode.until_t_s is None  # the commanded motion


def test_soft_torque_limits_are_rows_in_place_of_the_bounds(a1):
    problem = OcpProblem(a1, OcpConfig(grid=GRID, soft_rows=("torque_limit",)))
    n_tau = problem.config.n_torque_nodes
    assert problem.rows["torque_limit"].shape == (n_tau, a1.n_joints)
    assert problem.idx["slack_tau"].shape == (n_tau, 2 * a1.n_joints)
    # a cold start takes about 100 iterations, its path sensitive to the last bits of the cones' Hessian (which the
    # ground normal as a parameter changes by 1e-16): a cap with room keeps this the hard solve
    mpc = MPC(a1, MpcConfig(ocp=problem.config, gait="trot", solver=SolverConfig(max_iterations=200),
                            recovery=RecoveryConfig(fallback_solver=None)), problem=problem)
    capture = Capture(mpc.solver)
    solution = mpc.solve(a1.q_nominal, np.zeros(a1.nv), Commands(), t_s=0.1)
    call = capture.calls[-1]
    assert len(capture.calls) == 1  # the hard step, not a re-solve
    assert solution.success
    assert np.isinf(call["lbx"][problem.idx["tau"]]).all()  # the rows carry the limits
    assert (call["lbg"][problem.rows["torque_limit"]] == -1).all() and (call["ubg"][problem.rows["torque_limit"]] == 1).all()
    assert (call["ubx"][problem.idx["slack_tau"]] == 0).all()  # pinned on a nominal step
    assert np.all(np.abs(solution.tau) <= a1.tau_max * (1 + 1e-6))
