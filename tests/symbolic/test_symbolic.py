"""Symbolic dynamics against pinocchio's numeric algorithms and physical identities."""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import (
    random_samples,
    validate_dynamics,
    world_forces_to_pinocchio,
)
from wbmpc.robots import PRESET_NAMES, load_robot
from wbmpc.symbolic import Motion, SymbolicDynamics

LARGE = {"centauro", "talos", "talos_full", "romeo", "icub", "icub_full", "g1", "simple_humanoid"}  # nv > 30


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in LARGE else n for n in PRESET_NAMES]
)
def test_every_legged_robot_matches_pinocchio(name):
    """Every legged robot of example-robot-data passes `bench dynamics` (paper robot: 100 states)."""
    samples = 100 if name == "b1_z1" else 3
    report = validate_dynamics(load_robot(name), samples=samples, seed=7)
    for function, row in report["functions"].items():
        assert row["samples"] == samples
        assert row["max_abs_error"] <= 1e-9, (function, row)


def test_rnea_is_smaller_than_the_papers(b1z1):
    report = validate_dynamics(b1z1, samples=2)
    assert report["functions"]["rnea"]["instructions"] <= 3818


@pytest.fixture(scope="module")
def b1z1_functions(b1z1):
    dyn = SymbolicDynamics(b1z1)
    return dyn, dyn.functions()


def test_forward_dynamics_inverts_rnea(b1z1, b1z1_functions, rng):
    dyn, fns = b1z1_functions
    for s in random_samples(b1z1, dyn.n_forces, 10, seed=3):
        acc = np.array(fns["forward_dynamics"](s["q"], s["v"], s["tau_j"], s["f"])).ravel()
        tau = np.array(fns["rnea"](s["q"], s["v"], acc, s["f"])).ravel()
        np.testing.assert_allclose(tau[:6], 0, atol=1e-8)
        np.testing.assert_allclose(tau[6:], s["tau_j"], atol=1e-8)


def test_mass_matrix_is_symmetric_positive_definite(b1z1, b1z1_functions):
    _, fns = b1z1_functions
    mass = np.array(fns["crba"](b1z1.random_configuration(np.random.default_rng(0))))
    np.testing.assert_allclose(mass, mass.T, atol=1e-12)
    assert np.linalg.eigvalsh(mass).min() > 0


def test_momentum_rate_is_the_time_derivative_of_momentum(b1z1, b1z1_functions):
    _, fns = b1z1_functions
    rng = np.random.default_rng(5)
    q, v, a = b1z1.random_configuration(rng), rng.normal(size=22), rng.normal(size=22)
    h = lambda t: np.array(fns["centroidal_momentum"](pin.integrate(b1z1.model, q, v * t + 0.5 * a * t * t), v + a * t)).ravel()
    eps = 1e-6
    numeric = (h(eps) - h(-eps)) / (2 * eps)
    np.testing.assert_allclose(np.array(fns["centroidal_momentum_rate"](q, v, a)).ravel(), numeric, atol=1e-5)


def test_base_rows_balance_gravity_and_contacts_in_static_stance(b1z1):
    """Standing still, feet carrying the weight in proportion found by least squares, base rows vanish."""
    dyn = SymbolicDynamics(b1z1)
    fns = dyn.functions()
    q, zeros = b1z1.q_nominal, np.zeros(b1z1.nv)
    data = b1z1.model.createData()
    pin.framesForwardKinematics(b1z1.model, data, q)
    # base wrench of gravity, then forces on the 4 feet that cancel it
    gravity_only = np.array(fns["rnea"](q, zeros, zeros, np.zeros(dyn.n_forces))).ravel()
    jac_rows = np.column_stack([np.array(fns["rnea"](q, zeros, zeros, e)).ravel()[:6] - gravity_only[:6]
                                for e in np.eye(dyn.n_forces)[:12]])
    forces = np.linalg.lstsq(jac_rows, -gravity_only[:6], rcond=None)[0]
    total = np.array(fns["rnea"](q, zeros, zeros, np.r_[forces, 0, 0, 0])).ravel()
    np.testing.assert_allclose(total[:6], 0, atol=1e-8)
    assert forces[2::3].sum() == pytest.approx(b1z1.mass_kg * 9.81, rel=1e-6)
    # pinocchio agrees on the joint torques of that stance
    tau_ref = pin.rnea(b1z1.model, data, q, zeros, zeros, world_forces_to_pinocchio(b1z1, data, np.r_[forces, 0, 0, 0]))
    np.testing.assert_allclose(total, tau_ref, atol=1e-9)


def test_increment_configuration_matches_integrate_and_has_finite_derivatives(b1z1):
    dyn = SymbolicDynamics(b1z1)
    dq = ca.SX.sym("dq", dyn.nv)
    v = ca.SX.sym("v", dyn.nv)
    q_ref = ca.SX.sym("q_ref", dyn.nq)
    rot_ref = ca.SX.sym("R", 3, 3)
    cfg = dyn.configuration_from_increment(rot_ref, q_ref, dq)
    foot_vel = dyn.frame_linear_velocity(cfg, Motion(cfg, v), "FL_foot")
    pos, _ = dyn.frame_placement(cfg, "FL_foot")
    out = ca.vertcat(foot_vel, pos)
    fn = ca.Function("f", [dq, v, q_ref, rot_ref], [out, ca.jacobian(out, ca.vertcat(dq, v)), ca.hessian(ca.sum1(out), dq)[0]])
    rng = np.random.default_rng(2)
    q0 = b1z1.random_configuration(rng)
    rot0 = pin.Quaternion(q0[3:7]).toRotationMatrix()
    data = b1z1.model.createData()
    for delta in (np.zeros(22), rng.normal(size=22) * 0.3):
        vel = rng.normal(size=22)
        value, jac, hess = fn(delta, vel, q0, rot0)
        assert np.all(np.isfinite(np.array(jac))) and np.all(np.isfinite(np.array(hess)))
        q = pin.integrate(b1z1.model, q0, delta)
        pin.forwardKinematics(b1z1.model, data, q, vel)
        pin.updateFramePlacements(b1z1.model, data)
        fid = b1z1.frame_id("FL_foot")
        ref_vel = pin.getFrameVelocity(b1z1.model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
        np.testing.assert_allclose(np.array(value).ravel(), np.r_[ref_vel, data.oMf[fid].translation], atol=1e-10)


def test_unsupported_joint_type_is_reported():
    import types

    from wbmpc.errors import ModelError

    robot = load_robot("a1")
    fake = types.SimpleNamespace(**{k: getattr(robot, k) for k in ("model", "contact_frames")})
    model = pin.Model()
    model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root_joint")
    model.addJoint(1, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    fake.model = model
    with pytest.raises(ModelError, match="joint 'ball' has unsupported type JointModelSpherical"):
        SymbolicDynamics(fake)


def test_bench_robots_cli_reports_every_requested_robot(capsys):
    import json

    from wbmpc.cli import main

    assert main(["bench", "robots", "--robots", "bolt,solo8", "--samples", "2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [r["robot"] for r in report["robots"]] == ["bolt", "solo8"]
    assert report["max_abs_error"] < 1e-12 and report["robots"][1]["joint_types"] == {"RY": 8}
    assert main(["bench", "robots", "--robots", "cheetah"]) == 2
    assert "unknown robot 'cheetah'" in capsys.readouterr().err
