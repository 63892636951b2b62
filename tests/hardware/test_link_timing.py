"""deploy's gains for the motor-law hold its link applies, measured from the LowStates before the MPC phase."""

import numpy as np
import pytest

from wbmpc.control.tuning import tuning_for
from wbmpc.hardware.link_timing import ROBOT_MOTOR_LAW_PERIOD_S, LinkTiming
from wbmpc.robots import load_robot


@pytest.mark.parametrize("link, interval_s", [("sim", 0.005), ("robot", 0.002)])
def test_deploy_takes_the_gains_of_the_links_hold_and_samples_mid_hold(link, interval_s):
    """Unitree's simulator holds eq. (10) one LowState period (5 ms by default): the hold is measured and Kd capped
    for it; a robot's motor drivers run the law at kHz: the tuned Kd stays. Eq. (9) is sampled mid-hold."""
    robot = load_robot("go2")
    tuning = tuning_for(robot)
    legs = robot.leg_joint_mask
    timing = LinkTiming(link)
    rng = np.random.default_rng(0)
    t = 0.0
    for _ in range(400):  # intervals 0-5 % late
        timing.note(t)
        t += interval_s * (1.0 + 0.05 * rng.random())
    kp0, kd0 = tuning.gains.vectors(~legs)
    kp, kd, lead_s, summary = timing.for_mpc_phase(tuning.gains_at, kp0, kd0, legs)
    hold = summary["hold_ms"] / 1e3
    expected = tuning.gains_at(hold if link == "sim" else ROBOT_MOTOR_LAW_PERIOD_S).kd_leg
    assert kd[legs] == pytest.approx(expected) and summary["kd_leg"] == pytest.approx(expected)
    if link == "sim":
        assert interval_s <= hold <= 1.05 * interval_s and expected < tuning.gains.kd_leg
    else:
        assert hold == ROBOT_MOTOR_LAW_PERIOD_S and expected == tuning.gains.kd_leg
    assert lead_s == pytest.approx(0.5 * interval_s * 1.025, rel=0.02)
    assert summary["command_period_ms"] == pytest.approx(1e3 * interval_s * 1.025, rel=0.02)
    # without the robot's tuning to draw from, the gains stay as given
    assert timing.for_mpc_phase(None, kp0, kd0, legs)[1] is kd0


def test_a_link_that_sent_too_little_is_taken_at_the_robots_500_hz():
    timing = LinkTiming("sim")
    timing.note(0.0)
    assert timing.period_s == pytest.approx(0.002) and timing.hold_s == pytest.approx(0.002)
