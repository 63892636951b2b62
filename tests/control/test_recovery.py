"""Bounded recovery of failed MPC steps and the fallback to the last good plan shifted in time."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control import MPC, Commands, MpcConfig, RecoveryConfig
from wbmpc.control.interpolator import interpolate
from wbmpc.control.policy import DELAYED_RECOVERY_PERIODS, MpcChoices, TaskNeeds, mpc_config
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.solvers.nlp import NlpSolver, SolverConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


@pytest.fixture(scope="module")
def a1_mpc():
    robot = load_robot("a1")
    return robot, MPC(robot, MpcConfig(ocp=SMALL, gait="trot", recovery=RecoveryConfig(fallback_solver=None)))


def test_failed_step_is_bounded_and_holds_the_last_plan_shifted(a1_mpc):
    robot, mpc = a1_mpc
    mpc.reset()
    good = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t_s=0.0)
    assert good.success, good.stats
    # the same MPC with every attempt capped at 2 iterations: a strongly pushed state cannot converge
    capped = MPC(robot, replace(mpc.config, recovery=RecoveryConfig(barrier_init=None, fallback_max_iterations=2)), problem=mpc.problem,
                 solver=NlpSolver(mpc.problem, SolverConfig(max_iterations=2)))
    capped.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t_s=0.0)  # sets references, fails (2 iterations)
    capped.continue_from(good)  # the last good plan, as after a successful step
    v = np.zeros(robot.nv)
    v[1], v[3] = 1.5, 2.0  # lateral kick and roll rate
    t = 0.03
    held = capped.solve(robot.q_nominal, v, Commands(), t_s=t)
    assert not held.success and held.held_previous
    assert held.stats.iterations <= 3 + 3  # main Fatrop + IPOPT, each capped at 2 (counted from 0 or 1)
    assert "holding the last good plan" in held.stats.status and "ipopt" in held.stats.status
    # the held plan is the good one re-sampled at the new node times
    for k in (0, 2):
        expected = np.array([np.interp(t + held.node_times_s[k], good.t_s + good.node_times_s, good.q[:, j])
                             for j in range(robot.nq)])
        expected[3:7] /= np.linalg.norm(expected[3:7])
        np.testing.assert_allclose(held.q[k], expected, atol=1e-9)
    # the loop applies it: its first torque is the good plan's torque at t (held beyond its 3 nodes)
    np.testing.assert_allclose(interpolate(held, t).tau_ff, good.tau[-1], atol=1e-9)


def test_no_recovery_attempt_starts_once_the_step_has_spent_its_cpu_budget(a1_mpc):
    """The budget counts the failed main solve: with a budget it exhausts, the step goes straight to the
    held plan (no fresh Fatrop, no fallback); without one, both attempts run."""
    robot, mpc = a1_mpc
    mpc.reset()
    good = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t_s=0.0)
    v = np.zeros(robot.nv)
    v[1], v[3] = 1.5, 2.0
    for budget_s in (1e-9, None):
        capped = MPC(robot, replace(mpc.config, recovery=RecoveryConfig(budget_s=budget_s, fallback_max_iterations=2,
                                                                fatrop_max_iterations=2, fallback_first_s=0.0)),  # Fatrop first, also after a rescue
                     problem=mpc.problem, solver=NlpSolver(mpc.problem, SolverConfig(max_iterations=2)))
        capped.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t_s=0.0)
        capped.continue_from(good)  # the last good plan
        held = capped.solve(robot.q_nominal, v, Commands(), t_s=0.03)
        assert not held.success and held.held_previous
        recovered = "recovery after" in held.stats.status
        assert recovered == (budget_s is None), held.stats.status
        if recovered:
            assert "fatrop mu_init" in held.stats.status and "ipopt:" in held.stats.status
        assert held.stats.cpu_time_s > 0


def test_a_waiting_run_caps_its_recovery_by_iterations_only_and_a_delayed_run_by_time():
    """A run whose plant waits for the solver must not depend on the machine's load: no CPU or wall budget
    (IPOPT would get `max_wall_time`); with a delay the plant runs on, so the re-solves get a few periods."""
    robot = load_robot("a1")
    waiting = mpc_config(robot, TaskNeeds(gait="trot"), MpcChoices(delay_mode="none"))
    delayed = mpc_config(robot, TaskNeeds(gait="trot"), MpcChoices(delay_mode="measured"))
    assert waiting.recovery.budget_s is None
    assert waiting.recovery.fallback_max_iterations > 0 and waiting.recovery.fatrop_max_iterations > 0
    assert delayed.recovery.budget_s == pytest.approx(DELAYED_RECOVERY_PERIODS / MpcChoices().mpc_rate_hz)
    fallback = MPC(robot, replace(waiting, ocp=SMALL)).recovery.fallback_solver()
    assert fallback.config.name == "ipopt" and fallback.config.time_limit_s is None
