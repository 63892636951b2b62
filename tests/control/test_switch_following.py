"""The MPC on node times that follow the gait's contact switches (`TimeGrid.follow_contact_switches`; go2 trotting,
whose small NLP converges in the default suite): the plan is solved on the moved grid (its Euler rows hold with the
moved intervals), a node on a switch carries the interval after it, and the warm start is the last plan interpolated
at the new node times."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.ocp.grid import ON_SWITCH_AFTER_S, TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.solvers.nlp import SolverConfig

GRID = TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.08, follow_contact_switches=True)  # nodes 5-7 move


@pytest.fixture(scope="module")
def walking():
    """go2 trotting forward on the moved grid: its plans over 0.4 s of steps (each from the last plan's node 1) and
    the solver's p and initial guess of each."""
    robot = load_robot("go2")
    config = MpcConfig(gait="trot", ocp=OcpConfig(grid=GRID), solver=SolverConfig(name="fatrop", max_iterations=60))
    mpc = MPC(robot, replace(config, recovery=replace(config.recovery, fallback_solver=None)))
    guesses, solve = [], mpc.solver.solve

    def spy(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        guesses.append((p.copy(), x0.copy()))
        return solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)

    mpc.solver.solve = spy
    commands = Commands(base_velocity_m_s=np.array([0.1, 0.0, 0.0]))
    q, v, plans = robot.q_nominal.copy(), np.zeros(robot.nv), []
    for t_s in np.arange(0.0, 0.4, 0.0125):
        first = len(guesses)
        plans.append((mpc.solve(q, v, commands, t_s=float(t_s)), guesses[first]))
        q, v = plans[-1][0].q[1].copy(), plans[-1][0].v[1].copy()
    return mpc, plans


def test_the_plans_are_solved_on_the_moved_node_times(walking):
    """Each plan's node times are the step's switch-following grid; p's time steps are their intervals; the plan's
    Euler rows v_k+1 = v_k + a_k dt_k hold with those intervals (not the grid's); a third of the plans or more have moved nodes."""
    mpc, plans = walking
    dt_block, moved = mpc.problem.params.block("dt"), 0
    for plan, (p, _) in plans:
        assert plan.success, plan.stats.status
        expected = GRID.on_switches(mpc.gait.switch_times(plan.t_s, plan.t_s + GRID.horizon_s) - plan.t_s)
        np.testing.assert_array_equal(plan.node_times_s, expected)
        np.testing.assert_allclose(p[dt_block], np.diff(plan.node_times_s), rtol=0, atol=1e-15)  # (grid's: its dt_s)
        dt = np.diff(plan.node_times_s)[:, None]
        np.testing.assert_allclose(plan.v[1:], plan.v[:-1] + plan.a * dt, rtol=0, atol=1e-6)
        moved += not np.array_equal(plan.node_times_s, GRID.node_times_s)
    assert moved >= len(plans) // 3


def test_a_node_on_a_switch_carries_the_interval_after_it(walking):
    """A node sitting ON_SWITCH_AFTER_S after a touchdown is a stance node of that foot, after a lift-off a swing node;
    the gait's contact just before the switch is the other one."""
    mpc, plans = walking
    checked = 0
    for plan, _ in plans:
        switches = mpc.gait.switch_times(plan.t_s, plan.t_s + GRID.horizon_s)
        for k, time_s in enumerate(plan.t_s + plan.node_times_s):
            on = np.abs(switches + ON_SWITCH_AFTER_S - time_s) < 1e-9
            if k and on.any():
                before = mpc.gait.contact(np.array([time_s - 2 * ON_SWITCH_AFTER_S]))[0]
                after = mpc.gait.contact(np.array([time_s + ON_SWITCH_AFTER_S]))[0]
                assert (before != after).any()
                np.testing.assert_array_equal(plan.contact[k], after)
                checked += 1
    assert checked >= 10


def test_the_warm_start_is_the_last_plan_at_the_new_node_times(walking):
    """The guess of every variable that is not the measurement (node 0) or a force is the last plan's value linearly
    interpolated at the new node times (held past the old horizon): configurations as increments on the new reference
    q, velocities and accelerations as they are."""
    mpc, plans = walking
    problem = mpc.problem
    idx, scale = problem.idx, problem.x_scale
    compared = 0
    for (previous, _), (plan, (_, x0)) in zip(plans[:-1], plans[1:]):
        if not previous.success:  # (the MPC warm-starts from its last good plan)
            continue
        compared += 1
        guess = x0 * scale
        new, old = plan.t_s + plan.node_times_s, previous.t_s + previous.node_times_s
        for name, values in (("v", previous.v), ("a", previous.a)):
            if name not in idx:
                continue
            nodes = idx[name]
            expected = np.column_stack([np.interp(new[: len(nodes)], old[: len(values)], column) for column in values.T])
            start = 1 if name in problem.state_names else 0
            np.testing.assert_allclose(guess[nodes[start:]], expected[start:], rtol=0, atol=1e-9, err_msg=name)
    assert compared >= len(plans) - 3
