"""Shared fixtures of the solver tests."""

import numpy as np
import pytest

from tests.solvers.mpc_steps import TINY
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers.nlp import SolverConfig

SMALL_GRID = OcpConfig(grid=TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06))


@pytest.fixture(scope="module")
def robot():
    return load_robot("go2")


@pytest.fixture(scope="module")
def problem(robot):
    """go2's OCP on the tiny grid (`mpc_steps.TINY`); a module may define its own."""
    return OcpProblem(robot, TINY)


@pytest.fixture(scope="module")
def fixed_state():
    """(problem, NLP data, Fatrop's result): go2's trot OCP on a 6-interval grid from a moving state, solved by Fatrop
    to 1e-10 through the MPC (the NLP data recorded from that solve)."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL_GRID, gait="trot", recovery=RecoveryConfig(fallback_solver=None),
                               solver=SolverConfig(tolerance=1e-10, max_iterations=300)))
    calls = []
    solve = mpc.solver.solve

    def recording(*args, **kwargs):
        result = solve(*args, **kwargs)
        calls.append((args, result))
        return result

    mpc.solver.solve = recording
    v0 = np.zeros(robot.nv)
    v0[:3] = [0.1, -0.05, 0.0]
    solution = mpc.solve(robot.q_nominal, v0, t_s=0.0)
    assert solution.success, solution.stats.status
    (data, reference), = calls
    assert reference.stats.status == "Solve_Succeeded"
    return mpc.problem, data, reference
