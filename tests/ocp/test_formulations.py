"""The six Table I formulations: sizes, and plans that satisfy the rigid-body dynamics (pinocchio)."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import world_forces_to_pinocchio
from wbmpc.control import MPC, MpcConfig, RecoveryConfig
from wbmpc.ocp.formulations import FORMULATIONS
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig, OcpProblem
from wbmpc.robots import load_robot

PAPER_COUNTS = {"wb_inverse": 1226, "wb_forward": 1094, "centroidal_vel_path": 938, "centroidal_vel": 854,
                "centroidal_acc_path": 1178, "centroidal_acc": 1094}
ACCELERATION_LEVEL = ("wb_inverse", "wb_forward", "centroidal_acc_path", "centroidal_acc")


@pytest.mark.parametrize("name", PAPER_COUNTS)
def test_decision_variables_match_table_1(b1z1, name):
    assert OcpProblem(b1z1, OcpConfig(formulation=name)).n_variables == PAPER_COUNTS[name]


def test_every_formulation_is_registered():
    assert set(FORMULATIONS) == set(PAPER_COUNTS)


@pytest.fixture(scope="module")
def robot():
    return load_robot("go2")  # a small legs-only robot keeps the six builds quick


@pytest.fixture(scope="module", params=list(PAPER_COUNTS))
def planned(request, robot):
    """One trot OCP (t = 0.1 s: a diagonal pair in swing) solved from a moving state."""
    config = MpcConfig(ocp=OcpConfig(formulation=request.param, grid=TimeGrid(n_intervals=8, dt_first_s=0.01,
                                                                              dt_last_s=0.06)),
                       gait="trot", recovery=RecoveryConfig(fallback_solver=None))
    mpc = MPC(robot, config)
    v0 = np.zeros(robot.nv)
    v0[:3] = [0.1, -0.05, 0.0]
    solution = mpc.solve(robot.q_nominal, v0, t_s=0.1)
    return request.param, mpc, solution


def test_solves_and_starts_at_the_measurement(planned, robot):
    name, mpc, solution = planned
    assert solution.success, f"{name}: {solution.stats.status}"
    assert solution.stats.max_constraint_violation < 1e-5
    np.testing.assert_allclose(solution.q[0], robot.q_nominal, atol=1e-9)
    if name in ACCELERATION_LEVEL:
        np.testing.assert_allclose(solution.v[0][:3], [0.1, -0.05, 0.0], atol=1e-9)
    assert np.all(np.isfinite(solution.tau)) and solution.tau.shape == (3, robot.n_joints)
    if name.startswith("wb_"):  # torque variables are bounded; centroidal ones bound only an estimate
        assert np.all(np.abs(solution.tau) <= robot.tau_max * (1 + 1e-6))


def test_configuration_follows_the_velocities(planned, robot):
    """dq_{k+1} = dq_k + v_k dt_k on every interval (eq. 4), with dq = q_hat (-) q from pinocchio."""
    name, mpc, solution = planned
    dq = [pin.difference(robot.model, solution.q[0], q) for q in solution.q]
    for k, dt in enumerate(solution.dt_s):
        np.testing.assert_allclose(dq[k + 1], dq[k] + solution.v[k] * dt, atol=1e-7, err_msg=f"{name} node {k}")


def test_plan_satisfies_the_dynamics(planned, robot):
    """Acceleration-level plans: pinocchio's RNEA base rows (Newton-Euler of the whole robot) vanish
    and the torque variables equal the joint rows. Velocity-level plans: the momentum state equals
    pinocchio's A(q) v and evolves with the contact forces and gravity."""
    name, mpc, solution = planned
    model, data = robot.model, robot.model.createData()
    weight = robot.mass_kg * 9.81
    n_checked = len(solution.dt_s) if name in ACCELERATION_LEVEL else len(solution.dt_s) - 1
    h = mpc.problem.unpack(solution.x).get("h")
    for k in range(n_checked):
        q, v, a, forces = solution.q[k], solution.v[k], solution.a[k], solution.forces[k]
        pin.framesForwardKinematics(model, data, q)
        fext = world_forces_to_pinocchio(robot, data, forces)
        if name in ACCELERATION_LEVEL:
            tau = pin.rnea(model, data, q, v, a, fext)
            assert np.abs(tau[:6]).max() < 1e-3 * weight, f"{name} node {k}: base rows {tau[:6]}"
            if k < solution.tau.shape[0]:
                np.testing.assert_allclose(solution.tau[k], tau[6:], atol=1e-3 * robot.tau_max.max())
            continue
        momentum = pin.computeCentroidalMomentum(model, data, q, v)
        np.testing.assert_allclose(h[k], np.r_[momentum.linear, momentum.angular], atol=1e-4 * robot.mass_kg)
        com = pin.centerOfMass(model, data, q)
        linear, angular = robot.mass_kg * model.gravity.linear, np.zeros(3)
        for i, frame in enumerate(robot.contact_frames):
            force = forces[3 * i : 3 * i + 3]
            linear += force
            angular += np.cross(data.oMf[robot.frame_id(frame)].translation - com, force)
        np.testing.assert_allclose(h[k + 1], h[k] + solution.dt_s[k] * np.r_[linear, angular], atol=1e-4 * robot.mass_kg)


def test_centroidal_torque_estimate_is_bounded(robot):
    """Centroidal formulations bound g_j(q) - J_j^T F on k < 3 through rows in [-1, 1]."""
    problem = OcpProblem(robot, OcpConfig(formulation="centroidal_vel", grid=TimeGrid(n_intervals=4)))
    assert problem.row_nodes["torque"].tolist() == [0, 1, 2]
    assert problem.rows["torque"].shape == (3, robot.n_joints)
    assert "tau" not in problem.idx
