"""Sensors in MuJoCo and the two-stage estimator (section V-B) against MuJoCo's true state."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.errors import ConfigError
from wbmpc.estimation import (
    EncoderConfig,
    ImuConfig,
    SensorConfig,
    Sensors,
    StateEstimator,
    contact_trust,
)
from wbmpc.estimation.metrics import estimation_metrics
from wbmpc.estimation.source import EstimatedState
from wbmpc.gait import make_gait
from wbmpc.robots import load_robot
from wbmpc.sim import make_plant


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def _pd(robot, q, v, kp=60.0, kd=2.0):
    return kp * (robot.q_nominal[7:] - q[7:]) - kd * v[6:]


def test_accelerometer_matches_mujoco_velocity_differences(go2):
    """Noiseless IMU: specific force = R^T (dv_world/dt - g) from finite differences of MuJoCo's state."""
    plant = make_plant("mujoco", go2)
    plant.reset()
    sensors = Sensors(plant, SensorConfig.noiseless(rate_hz=1000.0))
    plant.apply_base_velocity_kick(np.array([0.4, -0.2, 0.1]))
    errors, scale = [], []
    for _ in range(300):
        q0, v0 = plant.state()
        plant.step(_pd(go2, q0, v0))
        reading = sensors.read()
        q1, v1 = plant.state()
        r0 = pin.Quaternion(q0[3:7]).toRotationMatrix()
        r1 = pin.Quaternion(q1[3:7]).toRotationMatrix()
        accel_world = (r1 @ v1[:3] - r0 @ v0[:3]) / plant.dt_s
        expected = r1.T @ (accel_world - np.array([0, 0, -9.81]))
        errors.append(np.linalg.norm(reading.accel_m_s2 - expected))
        scale.append(np.linalg.norm(expected))
        np.testing.assert_allclose(reading.gyro_rad_s, v1[3:6], atol=1e-12)
        np.testing.assert_allclose(reading.joint_position_rad, q1[7:], atol=1e-12)
    assert np.median(errors) < 0.05 * np.median(scale)  # implicit integrator: differences lag by a step


def test_sensor_rate_noise_quantisation_and_dropouts(go2):
    plant = make_plant("mujoco", go2)
    plant.reset()
    quantum = 0.01
    config = SensorConfig(imu=ImuConfig(rate_hz=250.0, dropout_probability=0.3),
                          encoders=EncoderConfig(rate_hz=250.0, position_quantum_rad=quantum, dropout_probability=0.3))
    sensors = Sensors(plant, config)
    readings = []
    for _ in range(400):
        q, v = plant.state()
        readings.append(sensors.read())
        plant.step(_pd(go2, q, v))
    gyro = np.array([r.gyro_rad_s for r in readings])
    changed = np.any(np.diff(gyro, axis=0) != 0, axis=1)
    assert changed.sum() < 400 / 4  # 250 Hz on a 1 kHz plant, minus dropouts: held in between
    lost = np.mean([r.imu_lost for r in readings[::4]])
    assert 0.15 < lost < 0.45
    positions = np.array([r.joint_position_rad for r in readings])
    np.testing.assert_allclose(positions / quantum, np.round(positions / quantum), atol=1e-9)
    with pytest.raises(ConfigError, match="dropout_probability"):
        SensorConfig(imu=ImuConfig(dropout_probability=1.0))
    with pytest.raises(ConfigError, match="plant mujoco"):
        Sensors(make_plant("pinocchio", go2))


def test_contact_trust_follows_the_gait():
    gait = make_gait("trot", 4)
    trust = np.array([contact_trust(gait, t, 0.1) for t in np.linspace(0, gait.period_s, 200, endpoint=False)])
    contact = gait.contact(np.linspace(0, gait.period_s, 200, endpoint=False))
    assert np.all(trust[contact == 0] == 0)
    assert np.all(trust[contact == 1] > 0) or np.mean(trust[contact == 1] == 1.0) > 0.6


def test_estimator_error_bounded_on_a_known_trajectory(go2):
    """Standing go2 kicked forward and sideways: noisy sensors, estimate within cm and cm/s of MuJoCo."""
    plant = make_plant("mujoco", go2)
    plant.reset()
    source = EstimatedState(plant, make_gait("stand", 4), SensorConfig(seed=3))
    for k in range(3000):
        q, v = plant.state()
        if k % 2 == 0:
            source.measure()
        if k in (800, 1800):
            plant.apply_base_velocity_kick(np.array([0.4, 0.3 if k == 800 else -0.3, 0.0]))
        plant.step(_pd(go2, q, v))
    metrics = estimation_metrics(source.log)
    peak_speed = np.max(np.linalg.norm(source.log.arrays()["v_true"][:, :3], axis=1))
    assert peak_speed > 0.3  # the kicks moved the robot, so the estimate had to follow
    assert metrics["est_base_pos_rmse_m"] < 0.01
    assert metrics["est_base_vel_rmse_m_s"] < 0.05
    assert metrics["est_roll_pitch_rmse_rad"] < 0.01
    assert metrics["est_joint_vel_rmse_rad_s"] < 0.05  # 50 Hz filter on 0.02 rad/s noise


def test_estimator_needs_contacts(go2):
    with pytest.raises(ConfigError, match="gait schedule"):
        StateEstimator(go2, None)


def test_estimated_state_needs_the_mujoco_plant():
    from wbmpc.scenarios import RunConfig

    with pytest.raises(ConfigError, match="plant mujoco"):
        RunConfig(state="estimated", plant="pinocchio")
    with pytest.raises(ConfigError, match="state must be true or estimated"):  # the CLI names --state
        RunConfig(state="guessed")


def test_closed_loop_on_the_estimated_state(go2):
    """`--state estimated`: the MPC runs on the estimator; metrics compare it with MuJoCo's truth."""
    from wbmpc.scenarios import RunConfig, run_scenario

    result = run_scenario(go2, RunConfig(scenario="stand", duration_s=0.3, nodes=4, state="estimated"))
    m = result.metrics
    assert m["state"] == "estimated" and not m["fell"]
    assert m["est_base_vel_rmse_m_s"] < 0.05 and m["est_base_pos_rmse_m"] < 0.01
    assert len(result.estimation) >= 140  # one estimate per 500 Hz control tick
