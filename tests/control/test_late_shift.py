"""A real-time step that starts late (the last solve overran, so the next one starts two or more MPC periods after
the plan it warm-starts from) shifts that plan by the time that really passed: every variable re-sampled at the new
node times, checked against np.interp over each part's own nodes (held beyond them), for shifts of 1, 2.3 and 4.6
periods of 80 Hz, in NumPy and in C."""

import numpy as np
import pytest

from wbmpc.control.warm_start import ShiftedGuess
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers import step_pack

PERIOD_S = 1.0 / 80.0


@pytest.fixture(scope="module")
def problem():
    return OcpProblem(load_robot("go2"), OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05)))


@pytest.mark.parametrize("periods", [1.0, 2.3, 4.6])
@pytest.mark.parametrize("compiled", [False, True])
def test_a_late_step_shifts_the_plan_by_the_time_that_passed(problem, periods, compiled):
    packer = step_pack.library() if compiled else None
    if compiled and packer is None:
        pytest.skip("no C compiler: the NumPy re-sampling runs")
    shift = ShiftedGuess(problem, packer=packer)
    rng = np.random.default_rng(7)
    old_x = rng.normal(size=problem.n_variables)
    node_times = problem.config.grid.node_times_s
    old_times = 3.0 + node_times
    new_times = old_times + periods * PERIOD_S
    got = shift(old_x, new_times, old_times)
    for name, index in problem.idx.items():
        if name == "F":  # the forces are re-initialised by the MPC, not shifted
            assert np.all(got[index] == 0.0)
            continue
        nodes = len(index)
        for column in range(index.shape[1]):
            expected = np.interp(new_times[:nodes], old_times[:nodes], old_x[index[:, column]]) if nodes > 1 else \
                np.full(nodes, old_x[index[0, column]])
            np.testing.assert_allclose(got[index[:, column]], expected, rtol=0, atol=1e-12, err_msg=name)
