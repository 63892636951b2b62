"""Mass distribution online (issue 22 part 3): inertial NLP parameters against pinocchio on an edited model,
and the online estimator recovering a known base CoM offset / payload."""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.bench.dynamics import random_samples, world_forces_to_pinocchio
from wbmpc.symbolic import InertialParameters, Motion, SymbolicDynamics


def _symbolic(robot):
    dyn = SymbolicDynamics(robot)
    q, v, a = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv), ca.SX.sym("a", robot.nv)
    f, dc, m_p, m_b = ca.SX.sym("f", dyn.n_forces), ca.SX.sym("dc", 3), ca.SX.sym("m_p"), ca.SX.sym("m_b")
    cfg = dyn.configuration(q)
    nominal = ca.Function("nominal", [q, v, a, f], [dyn.rnea(cfg, Motion(cfg, v), a, f), dyn.mass_matrix(cfg)])
    cfg = dyn.configuration(q)
    cfg.inertial = InertialParameters(dc, m_p, m_b)
    edited = ca.Function("edited", [q, v, a, f, dc, m_p, m_b], [dyn.rnea(cfg, Motion(cfg, v), a, f), dyn.mass_matrix(cfg)])
    return dyn, nominal, edited


def _stand_and_identify(robot, plant, steps: int):
    """`steps` physics steps of the plant held at the nominal pose by joint PD, an inertial identification
    hook on it (returned)."""
    from wbmpc.estimation.inertial import InertialEstimator, InertialIdentification

    hook = InertialIdentification(InertialEstimator(robot))
    plant.add_step_hook(hook)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    q_joints = robot.joint_positions(robot.q_nominal)
    for _ in range(steps):
        q, v = plant.state()
        plant.step(300.0 * (q_joints - robot.joint_positions(q)) - 5.0 * v[6:])
    return hook


def test_inertial_parameters_match_pinocchio_on_an_edited_model(b1z1):
    """RNEA and CRBA with a base CoM offset, a hand payload and a load on the base change exactly as
    pinocchio's on the edited model; zero parameters give today's functions."""
    dyn, nominal, edited = _symbolic(b1z1)
    offset, payload, base_payload = np.array([-0.05, 0.02, 0.01]), 5.0, 7.0
    model = InertialParameters.apply_to(b1z1, offset, payload, base_payload)
    data_nominal, data_edited = b1z1.model.createData(), model.createData()
    for s in random_samples(b1z1, dyn.n_forces, 5, seed=11):
        q, v, a, f = s["q"], s["v"], s["a"], s["f"]
        tau0, mass0 = (np.array(x) for x in nominal(q, v, a, f))
        tau_zero, mass_zero = (np.array(x) for x in edited(q, v, a, f, np.zeros(3), 0.0, 0.0))
        np.testing.assert_allclose(tau_zero, tau0, atol=1e-9)
        np.testing.assert_allclose(mass_zero, mass0, atol=1e-9)
        tau1, mass1 = (np.array(x) for x in edited(q, v, a, f, offset, payload, base_payload))
        pin.framesForwardKinematics(b1z1.model, data_nominal, q)
        fext = world_forces_to_pinocchio(b1z1, data_nominal, f)
        reference = pin.rnea(model, data_edited, q, v, a, fext) - pin.rnea(b1z1.model, data_nominal, q, v, a, fext)
        np.testing.assert_allclose((tau1 - tau0).ravel(), reference, atol=1e-9 * max(1.0, np.abs(reference).max()))
        mass_ref = pin.crba(model, data_edited, q) - pin.crba(b1z1.model, data_nominal, q)
        np.testing.assert_allclose(np.triu(mass1 - mass0), np.triu(mass_ref), atol=1e-9)


def test_ocp_with_zero_inertial_parameters_is_todays(b1z1):
    """The NLP with the parameters at zero evaluates to today's cost and rows; a payload changes the dynamics rows."""
    from wbmpc.ocp.problem import OcpConfig, OcpProblem

    today = OcpProblem(b1z1, OcpConfig())
    edited = OcpProblem(b1z1, OcpConfig(inertial_parameters=True))
    assert edited.params.size == today.params.size + 5  # offset, hand payload, base payload
    assert edited.n_constraints == today.n_constraints and edited.n_variables == today.n_variables
    rng = np.random.default_rng(3)
    x = rng.normal(size=today.n_variables) * 0.1
    p = rng.normal(size=today.params.size) * 0.1
    today.params.select(p, "q_ref")[:] = b1z1.q_nominal  # views into p
    today.params.select(p, "rot_ref")[:] = np.eye(3).ravel()
    today.params.select(p, "dt")[:] = 0.02
    functions = [ca.Function(name, [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
                 for name, nlp in (("today", today.nlp), ("edited", edited.nlp))]
    f0, g0 = (np.array(v).ravel() for v in functions[0](x, p))
    f1, g1 = (np.array(v).ravel() for v in functions[1](x, np.r_[p, np.zeros(5)]))
    np.testing.assert_allclose(f1, f0, rtol=1e-12)
    np.testing.assert_allclose(g1, g0, atol=1e-9)
    _, g2 = (np.array(v).ravel() for v in functions[1](x, np.r_[p, -0.05, 0, 0, 5.0, 3.0]))
    dynamics = edited.rows["dynamics"].ravel()
    assert np.abs(g2[dynamics] - g0[dynamics]).max() > 1e-3


def test_estimator_recovers_offset_and_payload_from_pinocchio_data(b1z1):
    """A base CoM offset, a hand payload and a load on the base from samples of the edited model's dynamics (pinocchio forward dynamics with random torques and contact
    forces at the feet spheres' lowest points): the estimator recovers the offset and the payload."""
    from wbmpc.estimation.inertial import InertialEstimator, InertialEstimatorConfig

    offset, payload, base_payload = np.array([-0.05, 0.01, 0.0]), 5.0, 4.0
    model = InertialParameters.apply_to(b1z1, offset, payload, base_payload)
    data = model.createData()
    estimator = InertialEstimator(b1z1, InertialEstimatorConfig(forgetting_time_s=100.0))
    rng = np.random.default_rng(4)
    feet = [b1z1.frame_id(b1z1.contact_frame(f)) for f in b1z1.feet]
    dt = 1e-3
    for _ in range(200):
        q = pin.integrate(model, b1z1.q_nominal, rng.normal(size=b1z1.nv) * 0.1)
        v = rng.normal(size=b1z1.nv) * 0.3
        tau = rng.normal(size=b1z1.n_joints) * 10
        f = np.r_[[rng.normal(size=3) * 20 + [0, 0, 180] for _ in feet]].ravel()
        pin.framesForwardKinematics(model, data, q)
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        for k, fid in enumerate(feet):
            joint = model.frames[fid].parentJoint
            point = data.oMf[fid].translation - [0.0, 0.0, b1z1.foot_radius_m]  # the sphere's lowest point
            fext[joint] += data.oMi[joint].actInv(pin.Force(f[3 * k : 3 * k + 3], np.cross(point, f[3 * k : 3 * k + 3])))
        a = pin.aba(model, data, q, v, np.r_[np.zeros(6), tau], fext)
        estimator.observe(q, v, v + a * dt, tau, dt)
    np.testing.assert_allclose(estimator.base_com_offset_m, offset, atol=5e-4)  # the prior pulls a little
    assert abs(estimator.payload_kg - payload) < 0.01
    assert abs(estimator.base_payload_kg - base_payload) < 0.05


def test_estimator_recovers_offset_and_payload_in_mujoco(b1z1):
    """The step hook on a MuJoCo plant whose base CoM sits 5 cm back and whose hand carries 3 kg, the robot
    held standing by joint PD: the estimate after 0.6 s is within 5 mm and 0.1 kg (the elbow reaches its limit under the load)."""
    from wbmpc.sim import make_plant
    from wbmpc.sim.model_errors import ModelErrors

    errors = ModelErrors(base_com_offset_m=(-0.05, 0.0, 0.0), ee_payload_kg=3.0)
    plant = make_plant("mujoco", b1z1, errors.plant_config(b1z1))
    hook = _stand_and_identify(b1z1, plant, steps=600)
    metrics = hook.metrics(errors)
    assert metrics["base_com_offset_estimate_error_m"] < 0.005, (metrics["base_com_offset_estimate_m"], metrics["payload_estimate_kg"])
    assert metrics["payload_estimate_error_kg"] < 0.1, metrics["payload_estimate_kg"]


def test_identify_mass_refuses_what_it_cannot_observe_or_feed():
    from wbmpc.errors import ConfigError
    from wbmpc.ocp.problem import OcpConfig
    from wbmpc.scenarios import RunConfig

    with pytest.raises(ConfigError, match="--plant mujoco"):
        RunConfig(identify_mass=True, plant="pinocchio")
    with pytest.raises(ConfigError, match="realtime"):
        RunConfig(identify_mass=True, delay_mode="realtime")
    with pytest.raises(ConfigError, match="wb_inverse"):
        OcpConfig(formulation="centroidal_velocity", inertial_parameters=True)


@pytest.mark.slow
def test_identify_mass_run_reports_the_estimate(b1z1):
    """`wbmpc run --identify-mass` on a plant whose base CoM sits 5 cm back: the MPC plans with the estimate,
    metrics.json reports it within 1 cm after 1 s of trotting."""
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.runner import run_scenario
    from wbmpc.sim.model_errors import ModelErrors

    config = RunConfig(scenario="trot-in-place", duration_s=1.0, identify_mass=True,
                       model_errors=ModelErrors(base_com_offset_m=(-0.05, 0.0, 0.0)))
    result = run_scenario(b1z1, config)
    metrics = result.metrics
    assert not metrics["fell"]
    assert metrics["base_com_offset_estimate_error_m"] < 0.01, metrics["base_com_offset_estimate_m"]
    assert metrics["payload_estimate_kg"] < 0.5
    assert len(metrics["inertial_estimate_history"]) >= 10



def test_row_filter_averages_out_velocity_noise(b1z1):
    """MuJoCo, 5 cm back + 3 kg at the hand, the legs swaying at 1 Hz (feet lift, a shin touches down); the
    velocities the estimator sees carry 0.01 (m|rad)/s of noise, differenced over 2 ms: with the 5 Hz row
    filter x and the payload stay within 5 mm and 0.1 kg after 3 s (unfiltered: x -2.3 cm, 0.2 kg)."""
    from wbmpc.estimation.inertial import InertialEstimator, InertialEstimatorConfig
    from wbmpc.sim import make_plant
    from wbmpc.sim.model_errors import ModelErrors

    errors = ModelErrors(base_com_offset_m=(-0.05, 0.0, 0.0), ee_payload_kg=3.0)
    plant = make_plant("mujoco", b1z1, errors.plant_config(b1z1))
    estimator = InertialEstimator(b1z1, InertialEstimatorConfig(row_filter_hz=5.0))
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    rng = np.random.default_rng(0)
    q_joints = b1z1.joint_positions(b1z1.q_nominal)
    previous = None
    for k in range(3000):
        q, v = plant.state()
        if k % 2 == 0:  # the 500 Hz loop: torques held over two steps, one sample per tick
            target = q_joints + 0.1 * np.sin(2 * np.pi * k * 1e-3) * b1z1.leg_joint_mask
            tau = 300.0 * (target - b1z1.joint_positions(q)) - 5.0 * v[6:]
            measured = v + rng.normal(0.0, 0.01, b1z1.nv)
            if previous is not None:
                estimator.observe(previous[0], previous[1], measured, previous[2], 2e-3)
            previous = (q, measured, None)
        plant.step(tau)
        if k % 2 == 0:
            previous = (previous[0], previous[1], plant.applied_torques())
    assert abs(estimator.base_com_offset_m[0] + 0.05) < 0.005, estimator.base_com_offset_m
    assert abs(estimator.payload_kg - 3.0) < 0.1, estimator.payload_kg


def test_estimator_tells_a_load_on_the_base_from_a_hand_payload_in_mujoco(b1z1):
    """6 kg on the base 10 cm ahead of and 5 cm above its origin (MuJoCo body), standing under joint PD: a 6 kg
    base payload, no hand payload, and the base CoM offset its first moment gives in x (m p_x / m_base)."""
    from dataclasses import replace

    from wbmpc.sim import make_plant
    from wbmpc.sim.base import specialised_config
    from wbmpc.sim.mujoco_scene import MujocoPlantConfig, body_names

    def load(spec):
        spec.body(body_names(b1z1)[0]).add_body(name="back_load", pos=[0.1, 0.0, 0.05], ipos=[0, 0, 0], mass=6.0,
                                                inertia=[1e-3] * 3, explicitinertial=True)

    plant = make_plant("mujoco", b1z1, replace(specialised_config(None, MujocoPlantConfig), spec_callback=load))
    hook = _stand_and_identify(b1z1, plant, steps=1000)
    estimator = hook.estimator
    assert abs(estimator.base_payload_kg - 6.0) < 0.1 and estimator.payload_kg < 0.1
    assert abs(estimator.base_com_offset_m[0] - 6.0 * 0.1 / b1z1.model.inertias[1].mass) < 0.002


def test_estimator_recovers_offset_from_the_estimated_state(b1z1):
    """`--state estimated`: the identification reads the state estimator's state (noisy IMU and encoders, every
    2 ms control tick) and the torques averaged over the physics steps in between. Standing under joint PD on a
    MuJoCo plant whose base CoM sits 5 cm back, the offset after 1.2 s is within 1 cm (issue 22's bound)."""
    from wbmpc.estimation import SensorConfig
    from wbmpc.estimation.inertial import ESTIMATED_STATE_CONFIG, InertialEstimator, InertialIdentification
    from wbmpc.estimation.source import EstimatedState
    from wbmpc.gait import make_gait
    from wbmpc.sim import make_plant
    from wbmpc.sim.model_errors import ModelErrors

    errors = ModelErrors(base_com_offset_m=(-0.05, 0.0, 0.0))
    plant = make_plant("mujoco", b1z1, errors.plant_config(b1z1))
    hook = InertialIdentification(InertialEstimator(b1z1, ESTIMATED_STATE_CONFIG), from_estimate=True)
    plant.add_step_hook(hook)
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    source = EstimatedState(plant, make_gait("stand", 4), SensorConfig(seed=3))
    source.listeners.append(hook.on_estimate)
    q_joints = b1z1.joint_positions(b1z1.q_nominal)
    for _ in range(600):  # 2 ms control ticks of two 1 ms physics steps
        q, v = source.measure()
        tau = 300.0 * (q_joints - b1z1.joint_positions(q)) - 5.0 * v[6:]
        plant.step(tau)
        plant.step(tau)
    assert hook.estimator.samples > 500  # one per tick after the first
    metrics = hook.metrics(errors)
    assert metrics["base_com_offset_estimate_error_m"] < 0.01, metrics["base_com_offset_estimate_m"]
