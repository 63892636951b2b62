"""Flat feet's wrenches in the warm start, re-sampled by contact pattern (control/warm_start.py), against a
node-by-node reference of the rule and on a small biped's MPC steps across its contact switches."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control import MPC, MpcConfig
from wbmpc.control.warm_start import shifted_sole_wrenches
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import GRAVITY_M_S2, RobotModel, RobotSpec
from wbmpc.solvers.nlp import SolverConfig


def reference_wrenches(forces, previous_forces, previous_contact, contact, new_times, old_times, columns,
                       torque_nodes=0):
    """The rule node by node: the old nodes around the new time (the last one alone past the old horizon; a new node
    k < torque_nodes among the old nodes < torque_nodes only) with the new node's stance feet; both interpolated,
    one taken, none: `forces` kept; written to stance feet only."""
    out = forces.copy()
    for k, t in enumerate(new_times):
        last = min(torque_nodes, len(old_times)) - 1 if k < torque_nodes else len(old_times) - 1
        if t > old_times[last]:
            sources = [(last, 1.0)]
        else:
            a = min(max(int(np.searchsorted(old_times, t)) - 1, 0), last - 1)
            w = min(max((t - old_times[a]) / (old_times[a + 1] - old_times[a]), 0.0), 1.0)
            sources = [(a, 1.0 - w), (a + 1, w)]
        same = [(j, w) for j, w in sources if np.array_equal(previous_contact[j] > 0.5, contact[k] > 0.5)]
        if not same:
            continue
        total = sum(w for _, w in same) if len(same) == len(sources) else None
        for foot, cols in columns.items():
            if contact[k, foot] <= 0.5:
                continue
            if total is None:  # one source of the pattern: its wrench
                out[k, cols] = previous_forces[same[0][0], cols]
            else:
                out[k, cols] = sum(w * previous_forces[j, cols] for j, w in same)
    return out


def test_wrenches_follow_the_contact_pattern_not_the_interpolation_across_a_switch():
    """Two soles (columns 0-2 / 6-8 and 3-5 / 9-11), a lift-off of foot 0 inside an old interval, a touchdown past
    the old horizon: the stance foot takes its wrench from the old node of the same pattern, never the half of a
    loaded and an unloaded node; a node whose pattern neither old node has keeps the re-initialised share."""
    old_times = np.array([0.0, 0.01, 0.03, 0.06, 0.1])
    new_times = old_times + 0.015
    columns = {0: np.r_[0:3, 6:9], 1: np.r_[3:6, 9:12]}
    previous_contact = np.array([[1, 1], [1, 1], [0, 1], [0, 1], [0, 1]], dtype=float)
    contact = np.array([[1, 1], [0, 1], [0, 1], [0, 1], [1, 1]], dtype=float)  # foot 0 down again at the end
    rng = np.random.default_rng(3)
    previous_forces = rng.normal(size=(5, 12)) * 100
    forces = rng.normal(size=(5, 12))  # the weight share stands in
    out = shifted_sole_wrenches(forces, previous_forces, previous_contact, contact, new_times, old_times, columns)
    # node 0 (t = 0.015, between old nodes 1 and 2 with the lift-off between): old node 1's wrenches
    np.testing.assert_array_equal(out[0], np.where(np.isin(np.arange(12), np.r_[columns[0], columns[1]]),
                                                   previous_forces[1], forces[0]))
    # node 1 (t = 0.025, same pattern [0, 1] at old node 2 only): foot 1 from node 2, foot 0 (swing) untouched
    np.testing.assert_array_equal(out[1, columns[1]], previous_forces[2, columns[1]])
    np.testing.assert_array_equal(out[1, columns[0]], forces[1, columns[0]])
    # node 2 (t = 0.045 between old nodes 2 and 3, both [0, 1]): interpolated
    np.testing.assert_allclose(out[2, columns[1]], 0.5 * (previous_forces[2] + previous_forces[3])[columns[1]])
    # node 4 (past the old horizon, pattern [1, 1] the last old node lacks): the re-initialised guess
    np.testing.assert_array_equal(out[4], forces[4])
    reference = reference_wrenches(forces, previous_forces, previous_contact, contact, new_times, old_times, columns)
    np.testing.assert_allclose(out, reference, rtol=0, atol=1e-12)


def test_torque_nodes_take_their_wrenches_from_the_old_torque_nodes():
    """The first input nodes carry the torques (their RNEA joint rows tie the wrenches to them): a new torque node
    past the last old torque node holds that node's wrench instead of interpolating towards the next old node (the
    free node after the torque nodes, whose wrench the plan sets apart); later nodes interpolate as before."""
    old_times = np.array([0.0, 0.01, 0.022, 0.036, 0.053, 0.073])
    new_times = old_times + 0.0125
    columns = {0: np.r_[0:3, 6:9], 1: np.r_[3:6, 9:12]}
    stance = np.ones((6, 2))
    previous_forces = np.arange(6)[:, None] * np.ones((6, 12))  # node j's wrench: j everywhere
    out = shifted_sole_wrenches(np.zeros((6, 12)), previous_forces, stance, stance, new_times, old_times, columns, 3)
    np.testing.assert_allclose(out[0], 1 + 0.0025 / 0.012)  # between old nodes 1 and 2
    np.testing.assert_allclose(out[1], 2.0)  # past old node 2, the last torque node: held, not 2 + 0.0005 / 0.014
    np.testing.assert_allclose(out[2], 2.0)  # (t = 0.0345 lies before old node 3: interpolated without the rule)
    np.testing.assert_allclose(out[3], 3 + 0.0125 / 0.017)  # free nodes: as without torque nodes
    plain = shifted_sole_wrenches(np.zeros((6, 12)), previous_forces, stance, stance, new_times, old_times, columns)
    np.testing.assert_array_equal(out[3:], plain[3:])
    assert plain[2, 0] > 2.8  # without the rule node 2 took most of old node 3's wrench


def test_random_schedules_match_the_reference(rng):
    columns = {0: np.r_[0:3, 9:12], 2: np.r_[6:9, 12:15]}  # foot 1 a point foot: never written
    for _ in range(50):
        steps = np.cumsum(rng.uniform(0.005, 0.05, size=7))
        old_times = np.concatenate([[0.0], steps])
        new_times = old_times + rng.uniform(0.0, 0.06)
        previous_contact = (rng.uniform(size=(8, 3)) < 0.6).astype(float)
        contact = (rng.uniform(size=(8, 3)) < 0.6).astype(float)
        previous_contact[rng.integers(0, 8, size=4)] = contact[rng.integers(0, 8, size=4)]  # some shared patterns
        previous_forces, forces = rng.normal(size=(8, 15)), rng.normal(size=(8, 15))
        torque_nodes = int(rng.integers(0, 5))
        out = shifted_sole_wrenches(forces, previous_forces, previous_contact, contact, new_times, old_times, columns,
                                    torque_nodes)
        reference = reference_wrenches(forces, previous_forces, previous_contact, contact, new_times, old_times, columns,
                                       torque_nodes)
        np.testing.assert_allclose(out, reference, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(out[:, 3:6], forces[:, 3:6])


@pytest.fixture(scope="module")
def biped(tmp_path_factory):
    from tests.control.test_humanoid import _biped_urdf

    urdf = tmp_path_factory.mktemp("biped") / "biped.urdf"
    urdf.write_text(_biped_urdf(with_box=True))
    return RobotModel(RobotSpec(name="biped", urdf=str(urdf), feet=("l_foot", "r_foot"), foot_contact="surface"))


def test_the_mpc_warm_starts_a_bipeds_sole_wrenches_by_contact_pattern(biped, rng):
    """A small flat-footed biped walking: a warm step's F guess is the last plan's wrenches moved by the rule (from
    the public plan: forces, contact, node times) on the stance soles, the weight share where no old node has the
    pattern; last plans (random wrenches) just before the walk's contact switches, so that switches lie between
    old nodes. Only the guess is checked (3 iterations a solve)."""
    config = MpcConfig(gait="walk", ocp=OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05)),
                       solver=SolverConfig(name="fatrop", max_iterations=3))
    mpc = MPC(biped, replace(config, recovery=replace(config.recovery, fallback_solver=None, barrier_init=None)))
    problem, guesses = mpc.problem, []
    solve = mpc.solver.solve

    def spy(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        guesses.append(x0.copy())
        return solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)

    mpc.solver.solve = spy
    q, v = biped.q_nominal.copy(), np.zeros(biped.nv)
    plan = mpc.solve(q, v, t_s=0.0)
    columns = {i: np.r_[3 * i : 3 * i + 3, problem.dyn.moment_slice(i)] for i in problem.surface_feet}
    times = np.arange(0.0, 2 * mpc.gait.period_s, 1e-3)
    contact = mpc.gait.contact(times)
    switch_times = times[1:][(contact[1:] != contact[:-1]).any(axis=1)]
    switches = 0
    for t_s in np.concatenate([switch_times[:4] - 0.02, switch_times[:4] - 0.005]):
        old_times = t_s + plan.node_times_s[:-1]
        previous = replace(plan, t_s=float(t_s), contact=mpc.gait.contact(t_s + plan.node_times_s),
                           forces=rng.normal(size=plan.forces.shape) * 50)
        mpc.continue_from(previous)
        first_call = len(guesses)
        solution = mpc.solve(q, v, t_s=float(t_s) + 0.0125)
        guess = guesses[first_call] * problem.x_scale
        new_times = solution.t_s + solution.node_times_s[:-1]
        stance = mpc.gait.contact(new_times)
        share = np.zeros((len(new_times), problem.nf))  # the weight over the stance soles, no moments
        share[:, [2, 5]] = stance * biped.mass_kg * GRAVITY_M_S2 / stance.sum(axis=1, keepdims=True)
        expected = reference_wrenches(share, previous.forces, previous.contact, stance, new_times, old_times, columns,
                                      len(problem.idx["tau"]))
        np.testing.assert_allclose(guess[problem.idx["F"]], expected, rtol=0, atol=1e-9)
        # new nodes whose two old nodes around differ in their stance feet: the rule's case
        first = np.clip(np.searchsorted(old_times, new_times) - 1, 0, len(old_times) - 2)
        switches += int((previous.contact[first] != previous.contact[first + 1]).any(axis=1).sum())
    assert switches >= 4


def test_shifted_duals_record_the_kinds_of_the_bounds_they_were_shifted_to(biped, rng):
    """`ShiftedDuals.record` reuses the bound kinds `at` found for the same step's bounds: the next shift equals that
    of a ShiftedDuals that recorded the same plan without an `at` before it, and a record with other bounds than
    `at` saw takes its own (a wrong reuse moves multipliers onto rows of another kind, or zeroes them)."""
    from wbmpc.control.warm_start import ShiftedDuals

    config = MpcConfig(gait="walk", ocp=OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05)))
    problem = MPC(biped, config).problem
    n_g, n_x = problem.n_constraints, problem.n_variables

    def random_bounds():
        lower = [np.where(rng.random(n) < 0.3, -np.inf, rng.normal(size=n)) for n in (n_x, n_g)]
        upper = [np.where(rng.random(n) < 0.3, np.inf, lo + rng.choice([0.0, 1.0], size=n)) for lo, n in
                 zip(lower, (n_x, n_g))]
        return lower[0], upper[0], lower[1], upper[1]

    class Result:
        def __init__(self):
            self.lam_g, self.lam_x = rng.normal(size=n_g), rng.normal(size=n_x)

    first, second, third, other = (random_bounds() for _ in range(4))
    plan_1, plan_2 = Result(), Result()
    cached, fresh, mismatched = ShiftedDuals(problem), ShiftedDuals(problem), ShiftedDuals(problem)
    for duals in (cached, mismatched):
        duals.record(0.0, plan_1, first)
        assert len(duals.at(0.0125, second, 0.0)) == 2
    cached.record(0.0125, plan_2, second)
    mismatched.record(0.0125, plan_2, other)  # not the bounds `at` saw: their own kinds
    fresh.record(0.0125, plan_2, second)
    expected = fresh.at(0.025, third, 0.0125)
    for got in cached.at(0.025, third, 0.0125):
        assert np.isfinite(got).all()
    for got, want in zip(cached.at(0.025, third, 0.0125), expected):
        np.testing.assert_array_equal(got, want)
    reference = ShiftedDuals(problem)
    reference.record(0.0125, plan_2, other)
    for got, want in zip(mismatched.at(0.025, third, 0.0125), reference.at(0.025, third, 0.0125)):
        np.testing.assert_array_equal(got, want)
    assert any(not np.array_equal(a, b) for a, b in zip(expected, reference.at(0.025, third, 0.0125)))
