"""Stage kinds whose Hessian and Jacobian are another kind's (solvers/stage_covers.py): which kinds are covered,
and that a kind with rows of its own that are not linear, or with other expressions, is not. The covered kind's
derivatives through the wrappers against its own CasADi functions: test_fatrop_threads (go2's first stage)."""

import casadi as ca
import numpy as np

from wbmpc.solvers.stage_covers import find_cover, find_covers


def _stage(rows, tags, cost_scale=1.0):
    """A stage function (x, u, p) -> (next state, rows, cost) of two states, two inputs, one parameter."""
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 2), ca.SX.sym("p")
    next_state = x + 0.1 * ca.vertcat(x[1], ca.sin(x[0]) * u[0])
    cost = cost_scale * (ca.sumsqr(x - p) + ca.sumsqr(u))
    return ca.Function("stage", [x, u, p], [next_state, ca.vertcat(*rows(x, u, p)), cost]), tags


def _cover_stage():  # rows: dynamics (nonlinear), foot (nonlinear), cone (linear)
    return _stage(lambda x, u, p: [ca.cos(x[0]) * u[1] - p, x[1] * x[0], u[0] + 2 * u[1]],
                  [("dynamics", 1), ("foot_vel", 1), ("cone", 1)])


def test_first_stage_is_covered_by_the_torque_stage():
    cover_function, cover_tags = _cover_stage()
    # the first stage: x0 rows (linear, its own), the cover's dynamics and cone rows, no foot rows
    function, tags = _stage(lambda x, u, p: [x, ca.cos(x[0]) * u[1] - p, u[0] + 2 * u[1]],
                            [("x0", 2), ("dynamics", 1), ("cone", 1)])
    cover = find_cover(0, function, tags, 1, cover_function, cover_tags)
    assert cover is not None and cover.cover == 1
    assert cover.rows == (-1, -1, 0, 2)
    # x0 rows' transposed Jacobian columns in z = (u, x): unit entries at the states
    assert cover.linear == {0: ((2, 1.0),), 1: ((3, 1.0),)}
    assert find_covers([(function, tags), (cover_function, cover_tags)]) == {0: cover}


def test_a_nonlinear_row_of_its_own_or_other_expressions_are_no_cover():
    cover_function, cover_tags = _cover_stage()
    nonlinear, tags = _stage(lambda x, u, p: [x * x[0], ca.cos(x[0]) * u[1] - p], [("x0", 2), ("dynamics", 1)])
    assert find_cover(0, nonlinear, tags, 1, cover_function, cover_tags) is None
    other_row, tags = _stage(lambda x, u, p: [x, ca.cos(x[0]) * u[1] + p], [("x0", 2), ("dynamics", 1)])
    assert find_cover(0, other_row, tags, 1, cover_function, cover_tags) is None
    other_cost, tags = _stage(lambda x, u, p: [x, ca.cos(x[0]) * u[1] - p], [("x0", 2), ("dynamics", 1)], 2.0)
    assert find_cover(0, other_cost, tags, 1, cover_function, cover_tags) is None
    resized, tags = _stage(lambda x, u, p: [x, ca.cos(x[0]) * u[1] - p, p], [("x0", 2), ("dynamics", 2)])
    assert find_cover(0, resized, tags, 1, cover_function, cover_tags) is None
    # two kinds never cover each other (one keeps its code)
    assert len(find_covers([(cover_function, cover_tags), (cover_function, cover_tags)])) == 1


def test_go2_first_stage_kind_is_covered(problem):
    stages, seen = [], set()
    for k in range(problem.N + 1):
        function, tags = problem.stage_function(k)
        if function.name() not in seen:
            seen.add(function.name())
            stages.append((function, tags))
    covers = find_covers(stages)
    assert 0 in covers and [tag for tag, _ in stages[0][1]][0] == "x0"
    assert np.all(np.array(covers[0].rows[:problem.nx]) == -1)  # the x0 rows are its own, linear
