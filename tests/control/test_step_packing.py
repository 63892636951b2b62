"""The MPC step's data prepared the fast way (parameters packed from kept shapes, the warm start re-sampled with
weights computed once, the plan's configurations integrated in the same call as its trajectories) against the
straightforward computation, on the states of a short closed loop."""

import math

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.control.trajectory import Resampler, interp_rows
from wbmpc.control.warm_start import ShiftedGuess
from wbmpc.gait import SwingProfile
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot
from wbmpc.solvers import step_pack
from wbmpc.solvers.codegen import CodegenConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=5, dt_first_s=0.01, dt_last_s=0.05))


def reference_interp_rows(new_times, old_times, values):
    """The re-sampling as it was written first (np.clip)."""
    out = np.empty((len(new_times), values.shape[1]))
    if len(old_times) < 2:
        out[:] = values[0]
        return out
    pos = np.clip(np.searchsorted(old_times, new_times) - 1, 0, len(old_times) - 2)
    t0, t1 = old_times[pos], old_times[pos + 1]
    w = np.clip((new_times - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    out[:] = (1 - w) * values[pos] + w * values[pos + 1]
    return out


def reference_pack(params, values) -> np.ndarray:
    """Parameters laid out block after block in `names` order, matrices column-major."""
    blocks = []
    for name in params.names:
        shape = params.shape(name)
        blocks.append(np.asarray(values[name], dtype=float).reshape(shape).ravel(order="F"))
    return np.concatenate(blocks)


@pytest.fixture(scope="module")
def steps():
    """Each step of a short trot (moving base, contact changes): its targets, the p and the warm start handed to
    the solver, the previous plan and the new plan."""
    robot = load_robot("go2")
    mpc = MPC(robot, MpcConfig(ocp=SMALL))
    records, current = [], {}
    targets = mpc.references.targets_at  # (the NumPy path: `advance`, then the targets at the step's node times)

    def targets_spy(*args, **kwargs):
        current["targets"] = (*targets(*args, **kwargs), None)
        return current["targets"][:2]

    mpc.references.targets_at = targets_spy
    solve = mpc.solver.solve

    def solver_spy(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs):
        current["p"], current["x0"] = p.copy(), x0.copy()
        return solve(p, lbx, ubx, lbg, ubg, x0, *args, **kwargs)

    mpc.solver.solve = solver_spy
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    v[:2] = [0.2, -0.05]
    for k in range(5):
        previous = mpc.last_plan
        solution = mpc.solve(q, v, Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0])), t_s=0.0125 * k)
        assert solution.success
        records.append({**current, "previous": previous, "solution": solution, "q": q.copy()})
        q, v = solution.q[1].copy(), solution.v[1].copy()
    return robot, mpc, records


def step_values(robot, mpc, record) -> dict:
    """Every parameter block of a step from public data: the measurement, the weights and friction of the
    configuration, the flat ground, the step's targets and its force guess (the warm start's forces)."""
    problem = mpc.problem
    q = record["q"].copy()
    q[3:7] /= math.sqrt(float(q[3:7] @ q[3:7]))
    dq_des, v_des, _ = record["targets"]
    return {"q_ref": q, "rot_ref": pin.Quaternion(q[3:7]).toRotationMatrix(), "dt": problem.config.grid.dt_s,
            "dq_des": dq_des, "v_des": v_des, "F_des": problem.unpack(record["x0"])["F"].T,
            "mu": [mpc.config.friction_coefficient],
            "contact_normal": np.tile([0.0, 0.0, 1.0], (problem.N, len(robot.feet))).T,
            **mpc.config.weights.vectors(robot, problem.nf)}


def test_resampling_equals_the_straightforward_one_bitwise():
    rng = np.random.default_rng(0)
    for _ in range(20):
        old = np.sort(rng.uniform(0, 1, 9))
        new = np.sort(rng.uniform(-0.2, 1.3, 9))
        resample = Resampler(new, old)
        for n in (9, 8, 3, 1):
            values = rng.normal(size=(n, 4))
            expected = reference_interp_rows(new[:n], old[:n], values)
            assert np.array_equal(resample(values), expected)
            assert np.array_equal(interp_rows(new[:n], old[:n], values), expected)


def test_parameters_equal_the_straightforward_packing(steps):
    """The p each step hands the solver (a template's constant blocks, this step's written into a copy) is every
    block packed anew: bit for bit but the force guess, read back from the scaled warm start (rounding)."""
    robot, mpc, records = steps
    params = mpc.problem.params
    forces = params.block("F_des")
    for record in records:
        expected = reference_pack(params, step_values(robot, mpc, record))
        rest = np.ones(params.size, dtype=bool)
        rest[forces] = False
        assert np.array_equal(record["p"][rest], expected[rest])
        np.testing.assert_allclose(record["p"][forces], expected[forces], rtol=1e-14, atol=1e-12)
        assert np.array_equal(params.pack(step_values(robot, mpc, record)), reference_pack(params, step_values(
            robot, mpc, record)))


def test_the_plan_is_its_trajectories_and_their_integrated_configurations(steps):
    """v, a, F, tau bit for bit those of `OcpProblem.trajectory_function`; q = q_ref (+) dq as pinocchio
    integrates it."""
    robot, mpc, records = steps
    trajectories = mpc.problem.trajectory_function()
    for record in records:
        solution = record["solution"]
        dq, v, a, forces, tau = (np.asarray(m).T for m in trajectories(solution.x, record["p"]))
        for got, expected in ((solution.v, v), (solution.a, a), (solution.forces, forces), (solution.tau, tau)):
            assert np.array_equal(got, expected)
        q = np.array([pin.integrate(robot.model, record["q"], step) for step in dq])
        np.testing.assert_allclose(solution.q, q, atol=1e-12)


def test_the_warm_start_is_the_last_plan_resampled(steps):
    """Each step's initial guess: the previous plan's variables at the new node times (configurations as increments
    on the new measurement), node 0 at the measurement, forces re-initialised; from public data alone."""
    robot, mpc, records = steps
    problem = mpc.problem
    for record in records[1:]:
        previous, solution = record["previous"], record["solution"]
        guess = problem.unpack(record["x0"])
        new_times, old_times = solution.t_s + solution.node_times_s, previous.t_s + previous.node_times_s
        parts = problem.unpack(previous.x)
        parts["dq"] = np.array([pin.difference(robot.model, record["q"], q) for q in previous.q])
        for name, values in parts.items():
            if name in ("F", "dq"):
                continue
            expected = reference_interp_rows(new_times[: len(values)], old_times[: len(values)], values)
            if name in problem.state_names:
                expected[0] = guess[name][0]  # the measurement
            np.testing.assert_allclose(guess[name], expected, atol=1e-12)
        expected_dq = reference_interp_rows(new_times, old_times, parts["dq"])
        np.testing.assert_allclose(guess["dq"][1:], expected_dq[1:], atol=1e-9)
        assert np.all(guess["dq"][0] == 0.0)


def reference_vertical_velocity(profile, progress, swing_duration_s):
    """The swing spline's v_z piece by piece on masked subsets, as it was written first."""
    from wbmpc.gait import _cubic_velocity

    s, T, h = np.asarray(progress, dtype=float), swing_duration_s / 2, profile.apex_height_m
    out = np.zeros_like(s)
    up, down = (s >= 0) & (s < 0.5), s >= 0.5
    out[up] = _cubic_velocity(s[up] / 0.5, 0.0, h, profile.liftoff_velocity_m_s * T, 0.0) / T
    out[down] = _cubic_velocity((s[down] - 0.5) / 0.5, h, 0.0, 0.0, profile.touchdown_velocity_m_s * T) / T
    return out


def test_swing_velocity_in_one_pass_equals_the_piecewise_spline_bitwise():
    from wbmpc.gait import SwingProfile

    rng = np.random.default_rng(2)
    for profile in (SwingProfile(), SwingProfile(0.12, 0.3, -0.25)):
        progress = np.where(rng.uniform(size=(15, 4)) < 0.4, -1.0, rng.uniform(size=(15, 4)))
        progress[0, :3] = (0.0, 0.5, 0.999)
        assert np.array_equal(profile.vertical_velocity(progress, 0.3), reference_vertical_velocity(profile, progress, 0.3))
    standing = -np.ones((15, 4))  # no swing: zeros, even with a swing duration of 0
    with np.errstate(all="raise"):
        assert np.array_equal(SwingProfile().vertical_velocity(standing, 0.0), np.zeros((15, 4)))


def test_the_compiled_warm_start_resampling_equals_numpys_bitwise(steps):
    """`ShiftedGuess` in C (`solvers/step_pack.py`) against its NumPy code: random vectors and node times, the old
    horizon ahead of, behind and around the new one (held values, one-node parts)."""
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler: the NumPy re-sampling runs")
    problem = steps[1].problem
    numpy_shift, compiled_shift = ShiftedGuess(problem), ShiftedGuess(problem, packer=packer)
    rng = np.random.default_rng(3)
    node_times = problem.config.grid.node_times_s
    for shift in (0.0, 0.004, 0.0125, 0.03, 0.2, -0.01):
        old_x = rng.normal(size=problem.n_variables)
        new_times, old_times = 1.0 + shift + node_times, 1.0 + node_times
        expected = numpy_shift(old_x, new_times, old_times)
        got = compiled_shift(old_x, new_times, old_times)
        assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))


def test_the_mpc_packs_with_numpy_without_a_compiler(tmp_path):
    """Without a compiler the step packer is None (a RuntimeWarning says so) and the warm start re-samples with NumPy."""
    with pytest.warns(RuntimeWarning, match="step packer is unavailable"):
        packer = step_pack.library(CodegenConfig(compiler="no-such-cc", cache_dir=tmp_path))
    assert packer is None
    problem = MPC(load_robot("go2"), MpcConfig(ocp=SMALL)).problem
    shift = ShiftedGuess(problem, packer=packer)
    x = np.arange(problem.n_variables, dtype=float)
    times = problem.config.grid.node_times_s
    assert np.array_equal(shift(x, times, times), ShiftedGuess(problem)(x, times, times))


def test_the_compiled_swing_velocity_equals_the_profiles_bitwise():
    """`SwingVelocity` (C) against `SwingProfile.vertical_velocity` (NumPy): stance, both cubic pieces and their
    joint, lift-off and touch-down velocities, a standing gait (no swing time)."""
    packer = step_pack.library()
    if packer is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(2)
    for profile in (SwingProfile(), SwingProfile(apex_height_m=0.11, liftoff_velocity_m_s=0.3, touchdown_velocity_m_s=-0.2)):
        compiled = step_pack.SwingVelocity(profile, packer, (16, 4))
        for duration in (0.25, 0.1 / 3, 0.0):
            progress = np.where(rng.uniform(size=(16, 4)) < 0.4, -1.0, rng.uniform(size=(16, 4)))
            progress[0, :3] = [0.0, 0.5, np.nextafter(0.5, 0)]
            if duration == 0.0:  # a standing gait: every foot in stance
                progress[:] = -1.0
            expected, got = profile.vertical_velocity(progress, duration), compiled(progress, duration)
            assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
        assert np.array_equal(compiled(progress[:3], 0.25), profile.vertical_velocity(progress[:3], 0.25))  # other shape
