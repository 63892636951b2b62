"""Node times that follow the gait's contact switches (`TimeGrid.on_switches`, `Gait.switch_times`) and the multiplier
shift between plans on such grids, against brute-force references: the contact sampled finely, linear interpolation
written out node by node."""

import numpy as np
import pytest

from wbmpc.gait import GaitClock, make_gait
from wbmpc.ocp.grid import FIXED_NODES, ON_SWITCH_AFTER_S, TimeGrid
from wbmpc.ocp.multipliers import MultiplierShift
from wbmpc.ocp.problem import EARLY_NODES, OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers import step_pack

GRID = TimeGrid(follow_contact_switches=True)  # the default geometric grid: 10 -> 100 ms over 14 intervals


def brute_force_switches(gait, start_s: float, end_s: float) -> np.ndarray:
    """Times where some foot's contact changes, from the contact sampled every 0.1 ms and refined by bisection."""
    times = np.arange(start_s, end_s, 1e-4)
    contact = gait.contact(times)
    found = []
    for k in np.flatnonzero((contact[1:] != contact[:-1]).any(axis=1)):
        lo, hi = times[k], times[k + 1]
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if (gait.contact(np.array([mid]))[0] == contact[k]).all() else (lo, mid)
        if not found or hi - found[-1] > 1e-7:  # (a standing interval's end may flicker for 1 ns: one switch)
            found.append(hi)
    return np.array(found)


@pytest.mark.parametrize("name, feet", [("walk", 2), ("trot", 4), ("walk", 4)])
def test_switch_times_are_where_the_contact_changes(name, feet):
    """On a fixed gait, a retimed clock (faster after t = 0.9 s) and across a standing interval with a restart."""
    gait = GaitClock(make_gait(name, feet, None if feet == 2 else 0.6, leg_length_m=0.7))
    np.testing.assert_allclose(gait.switch_times(0.05, 2.0), brute_force_switches(gait, 0.05, 2.0), atol=1e-9)
    gait.retime(0.9, 0.7 * gait.period_s)
    gait.stand_from(1.5)
    gait.walk_from(2.2)
    expected = brute_force_switches(gait, 0.3, 3.5)
    np.testing.assert_allclose(gait.switch_times(0.3, 3.5), expected, atol=1e-9)
    assert len(expected) > 8


def test_a_gait_without_swing_has_no_switches():
    assert make_gait("stand", 4).switch_times(0.0, 5.0).size == 0


def test_each_switch_in_a_far_nodes_cell_sits_on_that_node_and_the_nodes_between_spread_linearly():
    """Switches far apart (a biped's): each one in a movable node's cell is that node's time less ON_SWITCH_AFTER_S;
    the first FIXED_NODES nodes and the last keep the grid's times (the bounds' early nodes read those); every other
    node lies where linear interpolation of the grid's times between its fixed or moved neighbours puts it."""
    times, rng = GRID.node_times_s, np.random.default_rng(3)
    assert FIXED_NODES > EARLY_NODES
    edges = 0.5 * (times[:-1] + times[1:])
    edges[-1] = times[-1] - GRID.dt_first_s  # node N-1 takes the switches up to the last node's shortest interval
    for _ in range(200):
        switches = np.cumsum(rng.uniform(0.2, 0.35, size=3)) - rng.uniform(0.0, 0.3)
        moved = GRID.on_switches(switches)
        np.testing.assert_array_equal(moved[:FIXED_NODES], times[:FIXED_NODES])
        assert moved[-1] == times[-1] and np.all(np.diff(moved) >= GRID.dt_first_s - 1e-12)
        on_node = {}
        for switch in switches:
            node = int(np.searchsorted(edges, switch, side="right"))
            if FIXED_NODES <= node < len(times) - 1:
                assert moved[node] == pytest.approx(switch + ON_SWITCH_AFTER_S, abs=1e-15)
                on_node[node] = moved[node]
        anchors = sorted({**{k: times[k] for k in range(FIXED_NODES)}, len(times) - 1: times[-1], **on_node}.items())
        for k in range(len(times)):
            (k0, t0), (k1, t1) = max((a for a in anchors if a[0] <= k)), min((a for a in anchors if a[0] >= k))
            expected = t0 if k0 == k1 else t0 + (times[k] - times[k0]) / (times[k1] - times[k0]) * (t1 - t0)
            assert moved[k] == pytest.approx(expected, abs=1e-12)


def test_without_switches_in_the_far_cells_the_grid_is_the_default_one():
    assert GRID.on_switches(np.array([0.005, 0.03])) is GRID.node_times_s
    assert GRID.on_switches(np.zeros(0)) is GRID.node_times_s


def test_two_switches_in_one_cell_keep_the_nearer_and_close_neighbours_the_nearer():
    times = GRID.node_times_s
    node = 10
    near, far = times[node] + 0.001, times[node] - 0.02
    moved = GRID.on_switches(np.array([far, near]))
    assert moved[node] == pytest.approx(near + ON_SWITCH_AFTER_S)
    # two switches 4 ms apart around the edge of two cells: the one farther from its node's grid time stays a flip
    edge = 0.5 * (times[node] + times[node + 1])
    for first, second in ((edge - 0.003, edge + 0.001), (edge - 0.001, edge + 0.003)):
        moved = GRID.on_switches(np.array([first, second]))
        assert np.all(np.diff(moved) >= GRID.dt_first_s - 1e-12)
        keep, drop = (node, node + 1) if first - times[node] < times[node + 1] - second else (node + 1, node)
        assert moved[keep] == pytest.approx((first if keep == node else second) + ON_SWITCH_AFTER_S, abs=1e-15)
        assert not np.isin(np.array([first, second]) + ON_SWITCH_AFTER_S, moved[drop]).any()


def test_a_biped_walks_with_no_contact_switch_inside_a_far_interval():
    """g1's walk sampled on the moved grid every 2.5 ms over two cycles: within the far nodes' intervals the gait's
    contact is constant (every switch is on a node), and a node on a switch has the flags of the interval after it
    (stance at a touchdown, swing at a lift-off); on the fixed grid switches fall inside those intervals."""
    gait = GaitClock(make_gait("walk", 2, None, leg_length_m=0.7))
    inside_fixed = 0
    for t_s in np.arange(0.0, 2 * gait.period_s, 0.0025):
        moved = GRID.on_switches(gait.switch_times(t_s, t_s + GRID.horizon_s) - t_s)
        for grid_times, count in ((moved, False), (GRID.node_times_s, True)):
            for k in range(FIXED_NODES, len(grid_times) - 2):
                samples = t_s + np.linspace(grid_times[k], grid_times[k + 1], 12)[:-1]
                same = (gait.contact(samples) == gait.contact(samples[:1])).all()
                if count:
                    inside_fixed += not same
                else:
                    assert same, (t_s, k)
    assert inside_fixed > 50


@pytest.fixture(scope="module")
def g1_problem():
    problem = OcpProblem(load_robot("g1"), OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.08)))
    return problem


def test_multipliers_move_to_each_plans_own_node_times(g1_problem):
    """Rows whose multipliers are linear in their old node's time come out at the new node's time (mapped into the old
    plan: + dt_s), clamped to the old horizon, for moved old and new grids; with the compiled step packer the same
    bits."""
    grid = g1_problem.config.grid
    old = grid.node_times_s.copy()
    old[6] += 0.011
    new = grid.node_times_s.copy()
    new[5:8] += [0.004, -0.006, 0.012]
    shift, dt_s = MultiplierShift(g1_problem), 0.0125
    gap, nodes = g1_problem.rows["gap"], g1_problem.row_nodes["gap"]
    lam = np.zeros(g1_problem.n_constraints)
    lam[gap] = old[nodes][:, None] * 1e3
    kinds = np.full(lam.size, 4)
    moved = shift.shift(lam, kinds, kinds, dt_s, new_times=new, old_times=old)
    expected = np.clip(new[nodes] + dt_s, old[0], old[nodes.max()]) * 1e3
    np.testing.assert_allclose(moved[gap], np.broadcast_to(expected[:, None], gap.shape), rtol=0, atol=1e-9)
    on_grid = shift.shift(lam, kinds, kinds, dt_s)  # the grid's times: another result
    assert not np.allclose(on_grid[gap], moved[gap])
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler")
    g1_problem.bounds_packer = packer
    try:
        compiled = MultiplierShift(g1_problem)
    finally:
        g1_problem.bounds_packer = None
    rng = np.random.default_rng(2)
    for rows, size in ((True, g1_problem.n_constraints), (False, g1_problem.n_variables)):
        lam = rng.normal(size=size)
        kind_old, kind_new = rng.integers(0, 5, size=size), rng.integers(0, 5, size=size)
        got = compiled.shift(lam, kind_old, kind_new, dt_s, rows=rows, new_times=new, old_times=old)
        np.testing.assert_array_equal(got, shift.shift(lam, kind_old, kind_new, dt_s, rows=rows, new_times=new,
                                                       old_times=old))
