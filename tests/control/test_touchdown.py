"""The contact schedule following measured touch-down: early feet stay down, late ones keep reaching."""

import numpy as np

from wbmpc.control.touchdown import LATE_WINDOW, follow_touchdown, measured_contacts
from wbmpc.gait import SwingProfile, make_gait
from wbmpc.ocp.grid import TimeGrid


def _schedule(gait, t):
    node_times = TimeGrid(n_intervals=14).node_times_s
    times = t + node_times
    progress = gait.swing_phase(times)
    return node_times, gait.contact(times), SwingProfile().vertical_velocity(progress, gait.swing_duration_s)


def test_an_early_foot_stays_down_and_a_late_one_reaches_for_the_ground():
    gait = make_gait("trot", 4, 0.8)
    swing = gait.swing_duration_s
    # FL/RR swing during the second half of the cycle: at 80 % of their swing FL already touches, RR does not
    t = 0.4 + 0.8 * swing
    node_times, contact, vz = _schedule(gait, t)
    assert contact[0].tolist() == [0, 1, 1, 0]
    measured = np.array([True, True, True, False])
    fixed_contact, fixed_vz = follow_touchdown(gait, t, node_times, contact, vz, measured)
    landing = t + 0.2 * swing
    before = t + node_times < landing - 1e-9
    assert np.all(fixed_contact[before, 0] == 1) and np.all(fixed_vz[before, 0] == 0)  # early FL: stance
    np.testing.assert_array_equal(fixed_contact[:, 3], contact[:, 3])  # RR swings on as planned
    np.testing.assert_array_equal(fixed_contact[~before], contact[~before])
    # just after the planned touch-down RR carries nothing: it keeps reaching down for the rest of the window
    t_late = 0.8 + 0.05 * swing
    node_times, contact, vz = _schedule(gait, t_late)
    assert contact[0].tolist() == [1, 0, 0, 1]
    fixed_contact, fixed_vz = follow_touchdown(gait, t_late, node_times, contact, vz, np.array([True, False, False, False]))
    window = t_late + node_times < 0.8 + LATE_WINDOW * swing - 1e-9
    assert window.sum() >= 2
    assert np.all(fixed_contact[window, 3] == 0) and np.all(fixed_vz[window, 3] < 0)
    np.testing.assert_array_equal(fixed_contact[~window, 3], contact[~window, 3])
    np.testing.assert_array_equal(fixed_contact[:, :3], contact[:, :3])  # the loaded FL and the swinging feet as planned
    # a foot unloaded long after its touch-down (a slip, not a late landing) is left to the plan
    t_mid = 0.8 + 0.6 * swing
    node_times, contact, vz = _schedule(gait, t_mid)
    out = follow_touchdown(gait, t_mid, node_times, contact, vz, np.array([True, False, False, False]))
    np.testing.assert_array_equal(out[0], contact)


def test_measured_contacts_take_a_share_of_the_weight():
    forces = np.array([[0, 0, 100.0], [5, 0, 4.0], [0, 0, 0.0], [0, 0, 60.0]])
    assert measured_contacts(forces, 1000.0).tolist() == [True, False, False, True]


def test_a_run_with_touchdown_events_reaches_the_mpc():
    from wbmpc.robots import load_robot
    from wbmpc.scenarios import RunConfig, make_scenario, run_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    robot = load_robot("go2")
    config = RunConfig(scenario="trot-in-place", duration_s=0.3, touchdown_events=True, nodes=6)
    assert mpc_config_for(make_scenario("trot-in-place", robot), config, robot).references.touchdown_events
    result = run_scenario(robot, config)
    assert not result.metrics["fell"] and result.metrics["mpc_failures"] == 0
