"""End-effector feedback laws (scenarios/feedback.py) and arm-track's integral action."""

from __future__ import annotations

import numpy as np
import pytest

from wbmpc.robots import load_robot
from wbmpc.scenarios import ScenarioOptions, make_scenario
from wbmpc.scenarios.feedback import EeIntegral, InPlaneIntegral

GAIN_1_S = 4.0  # arm-track's proportional gain


def _track(integral: EeIntegral | None, disturbance_m_s: np.ndarray, duration_s: float = 6.0, dt_s: float = 0.0125):
    """A hand that moves at the commanded velocity plus a constant disturbance (a sag the model does not know),
    held at the reference 0 by v = K e (+ the integral): its final position."""
    p = np.zeros(3)
    for k in range(int(duration_s / dt_s)):
        error = -p
        command = GAIN_1_S * error + (integral.update(k * dt_s, error) if integral is not None else 0.0)
        p = p + dt_s * (command + disturbance_m_s)
    return p


def test_proportional_feedback_leaves_the_steady_offset_the_integral_removes():
    sag = np.array([0.0, 0.0, -0.04])  # m/s: b1_z1's hand 10 mm low with 10 % more mass, as K e balances it
    np.testing.assert_allclose(_track(None, sag), sag / GAIN_1_S, atol=1e-6)  # e = d / K: 10 mm
    assert np.linalg.norm(_track(EeIntegral(8.0, max_speed_m_s=0.1, within_m=0.02), sag)) < 1e-4


def test_the_integral_is_clipped_and_cleared_beyond_its_window():
    integral = EeIntegral(10.0, max_speed_m_s=0.1, within_m=0.02)
    for k in range(200):  # a constant 1.5 cm error for 2 s: 0.3 m/s unclipped
        term = integral.update(0.01 * k, np.array([0.015, 0.0, 0.0]))
    np.testing.assert_allclose(term, [0.1, 0.0, 0.0], atol=1e-12)
    # the hand held off its path (an obstacle, out of reach): proportional feedback alone, nothing wound up
    np.testing.assert_array_equal(integral.update(2.0, np.array([0.0, 0.05, 0.0])), np.zeros(3))
    np.testing.assert_allclose(integral.update(2.01, np.array([0.0, 0.005, 0.0])), [0.0, 5e-4, 0.0], atol=1e-15)


def test_in_plane_integral_ignores_the_error_along_the_normal():
    integral = InPlaneIntegral(np.array([0.0, 0.0, 1.0]), 30.0)
    integral.update(0.0, np.zeros(3))
    term = integral.update(0.01, np.array([1e-3, 0.0, 5e-3]))
    np.testing.assert_allclose(term, [30.0 * 1e-5, 0.0, 0.0])


@pytest.mark.parametrize("gain", [0.0, 8.0])
def test_arm_track_commands_integrate_a_sagging_hand(gain):
    """arm-track's command on a hand held 1 cm below its reference: the upward velocity grows with --arm-integral
    and stays K e without it."""
    robot = load_robot("b1_z1")
    scenario = make_scenario("arm-track", robot, ScenarioOptions(speed_m_s=0.0, arm_amplitude_m=0.0,
                                                                   arm_integral_gain_1_s2=gain))
    command = scenario.commands(robot)
    q = robot.q_nominal.copy()
    q[2] -= 0.01  # the base and the hand with it 1 cm below the reference (the start pose's hand)
    ups = [command(t, q, np.zeros(robot.model.nv)).ee_velocity_m_s[2] for t in np.arange(0.0, 1.0, 0.0125)]
    assert ups[0] == pytest.approx(GAIN_1_S * 0.01, rel=1e-6)
    if gain:
        assert ups[-1] == pytest.approx(GAIN_1_S * 0.01 + gain * 0.01 * (len(ups) - 1) * 0.0125, rel=1e-6)
    else:
        assert ups[-1] == pytest.approx(ups[0])
