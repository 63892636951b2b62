"""The last step's multipliers moved to the next step by constraint identity (ocp/multipliers.py)."""

import numpy as np
import pytest

from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.multipliers import MultiplierShift, bound_kind
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot
from wbmpc.solvers import step_pack

DT_S = 0.02


@pytest.fixture(scope="module")
def problem():
    return OcpProblem(load_robot("go2"), OcpConfig(grid=TimeGrid.uniform_steps(3, DT_S)))


def test_bound_kind():
    inf = np.inf
    kinds = bound_kind(np.array([-inf, 0.0, -inf, 0.0, 1.0]), np.array([inf, inf, 0.0, 1.0, 1.0]))
    np.testing.assert_array_equal(kinds, [0, 1, 2, 3, 4])


def test_rows_follow_their_identity_one_node_later(problem):
    """On a uniform grid one node later: every row takes the multiplier of the same tag and place at the next
    node (held at the last), whatever its position among its stage's rows; across a change of a row's bound kind (a
    foot's rows at touchdown) the old node of its kind alone, 0 where neither is; no shift returns the multipliers
    unchanged."""
    shift = MultiplierShift(problem)
    lam = np.arange(1.0, problem.n_constraints + 1)
    kinds = np.full(problem.n_constraints, 4)
    np.testing.assert_array_equal(shift.shift(lam, kinds, kinds, 0.0), lam)
    moved = shift.shift(lam, kinds, kinds, DT_S)
    gap, foot_vel = problem.rows["gap"], problem.rows["foot_vel"]
    np.testing.assert_array_equal(moved[gap[:-1]], lam[gap[1:]])
    np.testing.assert_array_equal(moved[gap[-1]], lam[gap[-1]])
    np.testing.assert_array_equal(moved[problem.rows["x0"]], lam[problem.rows["x0"]])  # node 0 only: its own
    half = shift.shift(lam, kinds, kinds, DT_S / 2)
    np.testing.assert_allclose(half[gap[0]], 0.5 * (lam[gap[0]] + lam[gap[1]]))
    touchdown = kinds.copy()
    touchdown[foot_vel[0]] = 1  # the source rows (node 2 of foot_vel's nodes 1..3) were of another kind
    changed = shift.shift(lam, touchdown, kinds, DT_S)
    assert np.all(changed[foot_vel[0]] == lam[foot_vel[1]]) and np.all(changed[foot_vel[-1]] == lam[foot_vel[-1]])
    touchdown[foot_vel[1]] = 1
    changed = shift.shift(lam, touchdown, kinds, DT_S)  # the source's kind differs, the next node's is the row's
    assert np.all(changed[foot_vel[0]] == lam[foot_vel[2]])
    half = shift.shift(lam, touchdown, kinds, DT_S / 2)  # between old nodes of another kind (0) and of its (alone)
    assert np.all(half[foot_vel[0]] == 0.0) and np.all(half[foot_vel[1]] == lam[foot_vel[2]])
    touchdown[foot_vel[2]] = 1
    changed = shift.shift(lam, touchdown, kinds, DT_S)  # neither old node of the row's kind
    assert np.all(changed[foot_vel[0]] == 0.0)
    np.testing.assert_array_equal(changed[gap[:-1]], lam[gap[1:]])


def test_variables_follow_their_identity(problem):
    shift = MultiplierShift(problem)
    lam = np.arange(1.0, problem.n_variables + 1)
    kinds = np.full(problem.n_variables, 1)
    moved = shift.shift(lam, kinds, kinds, DT_S, rows=False)
    forces = np.atleast_2d(problem.idx["F"])
    np.testing.assert_array_equal(moved[forces[:-1]], lam[forces[1:]])
    np.testing.assert_array_equal(moved[forces[-1]], lam[forces[-1]])


def test_the_compiled_shift_equals_numpys_bitwise(monkeypatch):
    """With the compiled step packer (`OcpProblem.bounds_packer`) the shift's sources (old rows, weights) are one C
    call: on g1 (flat feet: wrench and CoP rows), shifts within a node, across several, beyond the horizon and by a
    rounding error, the sources and the shifted random multipliers are NumPy's bits, and the NumPy code does not run;
    the bound kinds too."""
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler")
    problem = OcpProblem(load_robot("g1"), OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05)))
    numpy_shift = MultiplierShift(problem)
    problem.bounds_packer = packer
    compiled_shift = MultiplierShift(problem)
    calls, sources = [], MultiplierShift._sources
    monkeypatch.setattr(MultiplierShift, "_sources", lambda self, dt, *times: calls.append(dt) or sources(self, dt, *times))
    rng = np.random.default_rng(5)
    for rows, size in ((True, problem.n_constraints), (False, problem.n_variables)):
        for dt in (0.0, 0.0125, 0.0125 + 2e-18, 0.011, 0.07, 0.3):
            for got, expected in zip(compiled_shift.sources(dt, rows), numpy_shift.sources(dt, rows)):
                assert got.dtype == expected.dtype and np.array_equal(got, expected)
            lam = rng.normal(size=size) * (rng.uniform(size=size) < 0.8)
            kind_old, kind_new = rng.integers(0, 5, size=size), rng.integers(0, 5, size=size)
            same = rng.uniform(size=size) < 0.7
            kind_new[same] = kind_old[same]  # most rows keep their kind
            expected = numpy_shift.shift(lam, kind_old, kind_new, dt, rows=rows)
            got = compiled_shift.shift(lam, kind_old, kind_new, dt, rows=rows)
            assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
    assert len(calls) == 24  # NumPy's sources: the reference's two calls per shift only
    values = np.array([-np.inf, np.inf, np.nan, 0.0, -0.0, 1.0, -2.5])  # bound kinds: C against `bound_kind`
    lower, upper = rng.choice(values, size=(2, 4000))
    upper[::7] = lower[::7]
    np.testing.assert_array_equal(compiled_shift.kinds(lower, upper), bound_kind(lower, upper), strict=True)
