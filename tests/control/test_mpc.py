"""The whole-body inverse-dynamics MPC: sizes, dynamic consistency of its solutions, warm start."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import world_forces_to_pinocchio
from wbmpc.control import MPC, Commands, MpcConfig, PushConfig, RecoveryConfig, ReferenceConfig
from wbmpc.errors import ConfigError
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import BLEND_TIME_S, OcpConfig, OcpProblem
from wbmpc.solvers.nlp import SolverConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.06))


def test_paper_configuration_has_1226_decision_variables(b1z1):
    assert OcpProblem(b1z1, OcpConfig()).n_variables == 1226


@pytest.fixture(scope="module")
def trot_mpc(b1z1):
    return MPC(b1z1, MpcConfig(ocp=SMALL, gait="trot"))


@pytest.fixture(scope="module")
def trot_solution(trot_mpc, b1z1):
    commands = Commands(base_velocity_m_s=np.array([0.2, 0, 0]), ee_velocity_m_s=np.array([0.05, 0, 0]),
                        ee_force_n=np.array([10.0, 0, 0]))
    # t = 0.3 s: FL/RR in stance, FR/RL in swing with the apex inside the horizon
    return trot_mpc.solve(b1z1.q_nominal, np.zeros(b1z1.nv), commands, t_s=0.3), commands


def _kinematics(robot, q, v):
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q, v)
    pin.updateFramePlacements(robot.model, data)
    return data


def test_solution_converges(trot_solution):
    solution, _ = trot_solution
    assert solution.success, solution.stats
    assert solution.stats.max_constraint_violation < 1e-5
    assert np.all(np.isfinite(solution.tau))


def test_pinocchio_rnea_confirms_the_solution(trot_solution, b1z1):
    solution, _ = trot_solution
    weight = b1z1.mass_kg * 9.81
    for k in range(len(solution.a)):
        data = _kinematics(b1z1, solution.q[k], solution.v[k])
        fext = world_forces_to_pinocchio(b1z1, data, solution.forces[k])
        tau = pin.rnea(b1z1.model, data, solution.q[k], solution.v[k], solution.a[k], fext)
        assert np.abs(tau[:6]).max() < 1e-5 * weight, (k, tau[:6])
        if k < len(solution.tau):
            np.testing.assert_allclose(tau[6:], solution.tau[k], atol=1e-4)


def test_contacts_friction_and_swing(trot_solution, trot_mpc, b1z1):
    solution, commands = trot_solution
    mu = trot_mpc.config.friction_coefficient
    _, contact, swing_vz = trot_mpc.schedule(solution.t_s)
    n_feet = len(b1z1.feet)
    assert contact[0].tolist() == [1, 0, 0, 1]
    for k in range(1, len(solution.q)):
        data = _kinematics(b1z1, solution.q[k], solution.v[k])
        for i, foot in enumerate(b1z1.feet):
            vel = pin.getFrameVelocity(b1z1.model, data, b1z1.frame_id(foot), pin.LOCAL_WORLD_ALIGNED).linear
            if contact[k, i]:
                np.testing.assert_allclose(vel, 0, atol=1e-6)  # stance feet do not move
            else:
                assert vel[2] == pytest.approx(swing_vz[k, i], abs=1e-6)  # swing follows the spline
    forces = solution.forces[:, : 3 * n_feet].reshape(-1, n_feet, 3)
    stance = contact[: len(forces)].astype(bool)
    assert np.all(forces[stance][:, 2] >= -1e-6)
    # the cone is imposed on forces scaled by the weight share with a smoothing of 1e-3 of that scale
    scale = b1z1.mass_kg * 9.81 / n_feet
    tangential = np.linalg.norm(forces[stance][:, :2], axis=1)
    assert np.all(tangential <= mu * forces[stance][:, 2] + 1e-3 * scale)
    np.testing.assert_allclose(forces[~stance], 0, atol=1e-6)
    assert np.any(swing_vz[1:] > 0.1)  # the horizon really contains a lift-off


def test_arm_follows_its_commands(trot_solution, b1z1):
    solution, commands = trot_solution
    arm = solution.forces[:, -3:]
    np.testing.assert_allclose(arm, -commands.ee_force_n[None, :].repeat(len(arm), 0), atol=1e-6)
    # from rest, the end-effector velocity goes linearly to the command over BLEND_TIME_S, then holds it (eq. 7)
    blend = np.clip(solution.node_times_s / BLEND_TIME_S, 0.0, 1.0)
    for k in range(1, len(solution.q)):
        data = _kinematics(b1z1, solution.q[k], solution.v[k])
        vel = pin.getFrameVelocity(b1z1.model, data, b1z1.frame_id(b1z1.arm_ee), pin.LOCAL_WORLD_ALIGNED).linear
        np.testing.assert_allclose(vel, blend[k] * commands.ee_velocity_m_s, atol=1e-6)
    assert blend[-1] == 1.0


def test_limits_hold(trot_solution, b1z1):
    solution, _ = trot_solution
    assert np.all(solution.q[1:, 7:] >= b1z1.q_min - 1e-6) and np.all(solution.q[1:, 7:] <= b1z1.q_max + 1e-6)
    assert np.all(np.abs(solution.v[1:, 6:]) <= b1z1.v_max + 1e-6)
    assert np.all(np.abs(solution.tau) <= b1z1.tau_max + 1e-6)
    assert solution.tau.shape == (3, b1z1.n_joints)


def test_ipopt_finds_the_same_solution(trot_mpc, trot_solution, b1z1):
    solution, commands = trot_solution
    ipopt = MPC(b1z1, MpcConfig(ocp=SMALL, solver=SolverConfig(name="ipopt")), problem=trot_mpc.problem)
    other = ipopt.solve(b1z1.q_nominal, np.zeros(b1z1.nv), commands, t_s=0.3)
    assert other.success
    np.testing.assert_allclose(other.tau, solution.tau, atol=1e-2)


def test_warm_start_needs_fewer_iterations(b1z1, trot_mpc):
    cold = MPC(b1z1, MpcConfig(ocp=SMALL, warm_start=False), problem=trot_mpc.problem, solver=trot_mpc.solver)
    warm = MPC(b1z1, MpcConfig(ocp=SMALL, warm_start=True), problem=trot_mpc.problem, solver=trot_mpc.solver)
    iterations = {}
    for name, mpc in (("cold", cold), ("warm", warm)):
        q, v, total = b1z1.q_nominal.copy(), np.zeros(b1z1.nv), 0
        for step in range(6):
            solution = mpc.solve(q, v, Commands(), t_s=step / 80)
            assert solution.success
            total += solution.stats.iterations
            q = pin.integrate(b1z1.model, solution.q[0], solution.v[0] / 80)
            v = solution.v[0] + solution.a[0] / 80
        iterations[name] = total
    assert iterations["warm"] < iterations["cold"], iterations


@pytest.mark.parametrize("bad, message", [
    (dict(q=np.full(23, np.nan)), "NaN"),
    (dict(q=np.zeros(7)), "needs nq = 23"),
    (dict(v=np.zeros(3)), "needs nv = 22"),
    (dict(commands=Commands(base_velocity_m_s=np.array([5.0, 0, 0]))), "exceeds limits.base_speed"),
    (dict(commands=Commands(ee_velocity_m_s=np.array([0, 0, 3.0]))), "exceeds limits.ee_speed"),
])
def test_bad_input_is_rejected_before_solving(trot_mpc, b1z1, bad, message):
    args = dict(q=b1z1.q_nominal, v=np.zeros(b1z1.nv), commands=Commands())
    args.update(bad)
    with pytest.raises(ConfigError, match=message):
        trot_mpc.solve(args["q"], args["v"], args["commands"], t_s=0.0)


def test_unknown_gait_and_negative_dt(b1z1):
    with pytest.raises(ConfigError, match="unknown gait 'pace'"):
        MPC(b1z1, MpcConfig(ocp=SMALL, gait="pace"))
    with pytest.raises(ConfigError, match="dt_first_s must be > 0 s"):
        OcpConfig(grid=TimeGrid(dt_first_s=-0.01))


def test_arm_is_carried_along_by_default(trot_mpc, b1z1):
    """Without an arm velocity command the end-effector moves with the commanded base velocity."""
    solution = trot_mpc.solve(b1z1.q_nominal, np.zeros(b1z1.nv), Commands(base_velocity_m_s=np.array([0.2, 0, 0])), t_s=0.3)
    assert solution.success
    k = int(np.argmax(solution.node_times_s >= BLEND_TIME_S))  # past the blend from the measured velocity
    data = _kinematics(b1z1, solution.q[k], solution.v[k])
    vel = pin.getFrameVelocity(b1z1.model, data, b1z1.frame_id(b1z1.arm_ee), pin.LOCAL_WORLD_ALIGNED).linear
    np.testing.assert_allclose(vel, [0.2, 0.0, 0.0], atol=1e-6)
    assert solution.v[-1, 0] > 0.1  # and the base really speeds up over the horizon


@pytest.mark.parametrize("robot_name, gait", [("go2", "trot"), ("a1", "walk"), ("b1_z1_full", "stand")])
def test_other_robots_and_gaits_solve_consistently(robot_name, gait):
    """Any legged robot with a URDF: legs-only robots, the six-joint arm, three-legged stance phases."""
    from wbmpc.robots import load_robot

    robot = load_robot(robot_name)
    mpc = MPC(robot, MpcConfig(ocp=SMALL, gait=gait))
    solution = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(), t_s=0.1)
    assert solution.success, solution.stats
    weight = robot.mass_kg * 9.81
    for k in range(len(solution.a)):
        data = _kinematics(robot, solution.q[k], solution.v[k])
        fext = world_forces_to_pinocchio(robot, data, solution.forces[k])
        tau = pin.rnea(robot.model, data, solution.q[k], solution.v[k], solution.a[k], fext)
        assert np.abs(tau[:6]).max() < 1e-5 * weight
    stance_per_node = solution.contact[:-1].sum(axis=1)
    assert stance_per_node.min() >= (3 if gait == "walk" else 2)


def test_state_past_its_limits_stays_solvable(trot_mpc, b1z1):
    """A measurement beyond a joint limit (possible after a push) must not make the OCP infeasible."""
    q, v = b1z1.q_nominal.copy(), np.zeros(b1z1.nv)
    j = b1z1.joint_index("joint1")
    q[7 + j] = b1z1.q_max[j] + 0.02  # past the position limit ...
    v[6 + j] = 1.2 * b1z1.v_max[j]  # ... and still moving outwards faster than allowed
    solution = trot_mpc.solve(q, v, Commands(), t_s=0.0)
    assert solution.success, solution.stats
    assert solution.v[-1, 6 + j] <= b1z1.v_max[j] + 1e-6  # brought back within the limits later on


def test_state_right_after_a_push_is_solvable(trot_mpc, b1z1):
    """A 0.8 m/s lateral base kick with the feet still sliding (section VI-B1): the stance feet are
    brought to rest over BLEND_TIME_S (a fresh Fatrop recovers if the warm one stalls)."""
    v = np.zeros(b1z1.nv)
    v[1] = 0.8
    solution = trot_mpc.solve(b1z1.q_nominal, v, Commands(), t_s=0.5)
    assert solution.success, solution.stats
    _, contact, _ = trot_mpc.schedule(0.5)
    for k in np.flatnonzero(solution.node_times_s >= BLEND_TIME_S):
        data = _kinematics(b1z1, solution.q[k], solution.v[k])
        for i, foot in enumerate(b1z1.feet):
            if contact[k, i]:
                vel = pin.getFrameVelocity(b1z1.model, data, b1z1.frame_id(foot), pin.LOCAL_WORLD_ALIGNED).linear
                np.testing.assert_allclose(vel, 0.0, atol=1e-3)
    # a recovery re-solve may stop at the solvers' acceptable level (constraint violation <= 1e-2, in
    # units of the torque limits for the torque bounds)
    assert np.all(np.abs(solution.tau) <= 1.02 * b1z1.tau_max)


def test_velocity_only_base_tracking_does_not_pull_drift_back(trot_mpc, b1z1):
    """The paper's velocity-only base tracking (`base_tracking="velocity"`) takes the base x/y/yaw
    targets from the measured base at every step, so a drift of 5 cm stays uncorrected; the default
    position anchor keeps the targets where the run began (no command) and plans back towards it."""
    drifted = b1z1.q_nominal.copy()
    drifted[0] += 0.05
    planned_vx = {}
    for mode in ("position", "velocity"):
        mpc = MPC(b1z1, MpcConfig(ocp=SMALL, gait="stand", references=ReferenceConfig(base_tracking=mode)), problem=trot_mpc.problem,
                  solver=trot_mpc.solver)
        assert mpc.solve(b1z1.q_nominal, np.zeros(b1z1.nv), Commands(), t_s=0.0).success  # the run starts here
        solution = mpc.solve(drifted, np.zeros(b1z1.nv), Commands(), t_s=0.1)
        assert solution.success, solution.stats
        start = drifted if mode == "velocity" else b1z1.q_nominal
        np.testing.assert_allclose(mpc.references.anchor_xy_m, start[:2], atol=1e-12)
        planned_vx[mode] = float(np.mean(solution.v[1:, 0]))
    assert planned_vx["position"] < planned_vx["velocity"] - 5e-4  # the anchor pulls back, velocity-only does not
    with pytest.raises(ConfigError, match="--base-tracking"):
        ReferenceConfig(base_tracking="anchor")


def test_flat_settings_of_before_the_groups_still_work_for_one_release_with_a_warning():
    """`MpcConfig(push_hold_s=...)` and `config.fallback_solver` (the flat names of 0.x) map onto the groups."""
    with pytest.warns(DeprecationWarning, match="push_hold_s -> push.hold_s"):
        config = MpcConfig(gait="stand", push_hold_s=0.2, fallback_solver=None, max_ee_force_n=50.0)
    assert config.push.hold_s == 0.2 and config.recovery.fallback_solver is None and config.limits.ee_force_n == 50.0
    assert config.push == PushConfig(hold_s=0.2) and config.gait == "stand"
    with pytest.warns(DeprecationWarning, match="recovery_time_limit_s -> recovery.budget_s"):
        assert config.recovery_time_limit_s == RecoveryConfig().budget_s
    with pytest.warns(DeprecationWarning):
        assert dataclasses.replace(config, support_sway=0.3).references.support_sway == 0.3
    with pytest.raises(ConfigError, match="push.hold_s"), pytest.warns(DeprecationWarning):
        MpcConfig(push_hold_s=-1.0)
    with pytest.raises(AttributeError):
        config.no_such_setting  # noqa: B018
