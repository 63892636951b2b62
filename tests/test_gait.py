import numpy as np
import pytest
from scipy.integrate import quad

from wbmpc.errors import ConfigError
from wbmpc.gait import GAIT_NAMES, SwingProfile, make_gait
from wbmpc.ocp.grid import TimeGrid


def test_trot_moves_diagonal_pairs_alternately():
    gait = make_gait("trot", 4)
    contact = gait.contact(np.array([0.1, 0.5]))
    np.testing.assert_array_equal(contact, [[1, 0, 0, 1], [0, 1, 1, 0]])  # FL+RR, then FR+RL
    assert gait.period_s == 0.8


def test_walk_lifts_one_foot_at_a_time():
    gait = make_gait("walk", 4)
    contact = gait.contact(np.linspace(0, 2 * gait.period_s, 400, endpoint=False))
    assert contact.sum(axis=1).min() == 3


def test_swing_spline_reaches_apex_and_lands():
    profile = SwingProfile(apex_height_m=0.08)
    duration = 0.4
    vz = lambda s: profile.vertical_velocity(np.array([s]), duration)[0]
    rise, _ = quad(lambda t: vz(t / duration), 0, duration / 2, points=[duration / 2])
    total, _ = quad(lambda t: vz(t / duration), 0, duration * 0.999999)
    assert rise == pytest.approx(0.08, rel=1e-6)
    assert total == pytest.approx(0.0, abs=1e-6)
    assert profile.height(np.array([0.5]))[0] == pytest.approx(0.08)


def test_geometric_grid_matches_paper():
    grid = TimeGrid()
    assert grid.dt_s[0] == pytest.approx(0.01) and grid.dt_s[-1] == pytest.approx(0.1)
    assert grid.horizon_s == pytest.approx(0.56, abs=0.01)
    assert len(grid.node_times_s) == 15


def test_bad_gait_and_grid_inputs():
    with pytest.raises(ConfigError, match="unknown gait 'gallop'.*trot"):
        make_gait("gallop", 4)
    with pytest.raises(ConfigError, match="dt_first_s must be > 0 s"):
        TimeGrid(dt_first_s=-0.01)
    with pytest.raises(ConfigError, match="dt_last_s must be <= 0.5 s"):
        TimeGrid(dt_last_s=1e6)  # Fatrop hangs on such steps
    with pytest.raises(ConfigError, match="n_intervals must be <= 99"):
        TimeGrid(n_intervals=100_000)
    for period in (0.0, float("nan"), -1.0):  # 0 used to fall back to the default period silently
        with pytest.raises(ConfigError, match="gait_period_s must be"):
            make_gait("trot", 4, period)
    assert set(GAIT_NAMES) == {"stand", "trot", "walk"}


def test_gait_clock_changes_its_period_with_every_phase_continuous():
    from wbmpc.gait import GaitClock

    gait = make_gait("trot", 4)
    clock = GaitClock(gait)
    times = np.linspace(0.0, 3.0, 301)
    np.testing.assert_array_equal(clock.swing_phase(times), gait.swing_phase(times))  # not retimed: the gait
    t_switch = 0.93  # mid-swing of FR and RL
    before = clock.phase(np.array([t_switch]))[0]
    clock.retime(t_switch, 0.45)
    np.testing.assert_allclose(clock.phase(np.array([t_switch]))[0], before)
    # a full cycle now takes 0.45 s, and a swing 0.225 s
    np.testing.assert_allclose(clock.phase(np.array([t_switch + 0.45]))[0], before, atol=1e-12)
    assert clock.swing_duration_s == pytest.approx(0.225)
    progress = clock.swing_phase(np.array([t_switch, t_switch + 0.01]))[:, 1]
    assert progress[1] - progress[0] == pytest.approx(0.01 / 0.225)
    clock.retime(1.5, 0.8)  # back to the gait's own period, still continuous
    np.testing.assert_allclose(clock.phase(np.array([1.5 - 1e-9]))[0], clock.phase(np.array([1.5]))[0], atol=1e-6)
    clock.reset()
    np.testing.assert_array_equal(clock.contact(times), gait.contact(times))
    with pytest.raises(ConfigError, match="period_s"):
        clock.retime(2.0, 0.0)
