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


def _swing_runs(swinging: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index runs where `swinging` is True."""
    padded = np.r_[False, swinging, False].astype(int)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2], edges[1::2]))


@pytest.mark.parametrize("gait_name,n_feet", [("trot", 4), ("walk", 4), ("walk", 2)])
def test_stand_walk_switches_never_cut_a_swing(gait_name, n_feet):
    """Commanded stand <-> walk at random MPC steps (80 Hz), with a push cadence retime among them: in the schedule
    as executed every swing lasts its full duration (no foot asked to swing and stand at once), each step's plan on
    the MPC's node times holds every swing it starts until it lands, and a stop stands within one swing."""
    from wbmpc.gait import GaitClock

    rng = np.random.default_rng(3)
    clock = GaitClock(make_gait(gait_name, n_feet, leg_length_m=0.65))
    grid = TimeGrid().node_times_s
    dt, fine = 1 / 80, 5e-4
    steps = np.arange(0.0, 12.0, dt)
    walking, switches = False, []
    executed = []
    for k, t in enumerate(steps):
        if k == 0 or rng.random() < 0.02:
            walking = not walking if k else False
            switches.append((t, walking))
        if k == 400:
            clock.retime(t, 0.5625 * clock.nominal_period_s)
        clock.follow(t, walking)
        # this step's plan: a swing in the horizon runs on until its landing (progress rises continuously)
        times = t + grid
        progress = clock.swing_phase(times)
        for foot in range(n_feet):
            for start, end in _swing_runs(progress[:, foot] >= 0):
                p = progress[start:end, foot]
                assert np.all(np.diff(p) > 0), (t, foot, p)  # one swing per run, never reset mid-way
                if end < len(times):  # it lands inside the horizon: at its full duration
                    assert p[-1] + (times[end] - times[end - 1]) / clock.swing_duration_s >= 1 - 1e-6
        executed.append(clock.contact(np.arange(t, t + dt - 1e-12, fine)))
    contact = np.concatenate(executed)
    swing_samples = clock.swing_duration_s / fine
    for foot in range(n_feet):
        runs = _swing_runs(contact[:, foot] < 0.5)
        retimed = round(steps[400] / fine)  # the swing in progress there changes pace: excluded
        inner = [(a, b) for a, b in runs if a > 0 and b < len(contact) and not a <= retimed < b]
        assert inner, "the feet stepped"
        lengths = np.array([b - a for a, b in inner])
        nominal = clock.nominal_period_s * (1 - clock.duty_factor) / fine
        assert np.all((np.abs(lengths - swing_samples) <= 2) | (np.abs(lengths - nominal) <= 2)), lengths
    # each stop: all feet down within one swing duration (+ one MPC step) of the request
    for (t_request, t_switch, mode), later in zip(clock.transitions, clock.transitions[1:] + [(np.inf, np.inf, "")]):
        if mode == "stand":
            assert t_request <= t_switch <= t_request + clock.nominal_period_s * (1 - clock.duty_factor) + 1e-6
            standing = np.arange(t_switch, min(t_switch + 0.3, later[1] - fine / 2), fine)
            assert np.all(clock.contact(standing) == 1)
        else:
            assert t_switch == pytest.approx(t_request + clock.start_lead_s)


def test_walk_starts_at_the_patterns_first_lift_off_and_stands_at_a_landing():
    from wbmpc.gait import GaitClock

    clock = GaitClock(make_gait("trot", 4))
    clock.follow(0.0, False)
    assert np.all(clock.contact(np.linspace(0, 5, 50)) == 1)  # standing until told
    clock.follow(1.0, True)
    assert clock.start_lead_s == 0.0  # a trot has no moment with all feet down: it starts with a lift-off
    np.testing.assert_array_equal(clock.contact(np.array([0.999, 1.0 + 1e-6])), [[1, 1, 1, 1], [1, 0, 0, 1]])
    clock.follow(1.5, False)  # FL+RR swing from 1.4 to 1.8: the stop waits for their landing
    assert clock.transitions[-1] == (1.5, pytest.approx(1.8), "stand")
    np.testing.assert_array_equal(clock.contact(np.array([1.79, 1.81, 3.0])), [[0, 1, 1, 0], [1, 1, 1, 1], [1, 1, 1, 1]])
    biped = GaitClock(make_gait("walk", 2, leg_length_m=0.65))
    assert biped.start_lead_s == pytest.approx(0.2 * biped.period_s)  # its double support: the CoM moves first
    biped.follow(0.0, False)
    biped.follow(2.0, True)
    start = 2.0 + biped.start_lead_s
    np.testing.assert_array_equal(biped.contact(np.array([start - 1e-6, start + 1e-6])), [[1, 1], [0, 1]])
    with pytest.raises(ConfigError, match="gait has no swing"):
        GaitClock(make_gait("stand", 4)).walk_from(0.0)
