"""Faster steps after a push (PushConfig.gait_period_scale, control/push.py): when the cadence changes,
what the OCP receives, and that the paper's fixed schedule stays available."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import MPC, Commands, MpcConfig, PushConfig, RecoveryConfig
from wbmpc.errors import ConfigError
from wbmpc.gait import GaitClock, make_gait
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig
from wbmpc.robots import load_robot

GRID = TimeGrid(n_intervals=6, dt_first_s=0.01, dt_last_s=0.06)


@pytest.fixture(scope="module")
def a1():
    return load_robot("a1")


def make_mpc(robot, **options):
    config = MpcConfig(ocp=OcpConfig(grid=GRID), gait="trot", gait_period_s=0.6,
                       recovery=RecoveryConfig(fallback_solver=None),
                       # steps re-solved from the nominal pose (no plant) plan up to ~0.35 m/s: not a push
                       push=PushConfig(hold_s=0.1, cadence_hold_s=0.2, velocity_error_m_s=0.6, **options))
    return MPC(robot, config)


def test_a_push_speeds_up_the_steps_and_the_gait_period_returns_after_the_hold(a1):
    mpc = make_mpc(a1, gait_period_scale=0.5)  # 0.3 s steps
    v = np.zeros(a1.nv)
    expected = GaitClock(make_gait("trot", 4, 0.6))
    mpc.solve(a1.q_nominal, v, Commands(), t_s=0.0)
    assert mpc.gait.period_s == 0.6
    kicked = v.copy()
    kicked[1] = 1.0  # lateral kick: 1 m/s off the plan and the command
    t_kick = 0.0125
    solution = mpc.solve(a1.q_nominal, kicked, Commands(), t_s=t_kick)
    assert mpc.gait.period_s == 0.3
    expected.retime(t_kick, 0.3)
    # the OCP of the kicked step already plans with the faster schedule (the same phases at t_kick)
    np.testing.assert_array_equal(solution.contact, expected.contact(t_kick + GRID.node_times_s))
    # quiet again (measured at rest): push mode ends push_hold_s after the last step that looked pushed
    # (the plan of the kicked step expects the robot to keep moving for a while), the fast cadence 0.2 s later
    last_push_end, t_back = None, None
    for t in t_kick + 0.0125 * np.arange(1, 60):
        mpc.solve(a1.q_nominal, v, Commands(), t_s=t)
        if mpc.gait.period_s == 0.6:
            t_back = t
            break
        last_push_end = mpc.push_mode.until_t_s
    assert t_back is not None and last_push_end + 0.2 <= t_back < last_push_end + 0.2 + 0.0125
    expected.retime(t_back, 0.6)
    np.testing.assert_allclose(mpc.gait.phase(np.array([t_back + 0.1])), expected.phase(np.array([t_back + 0.1])))
    mpc.reset()  # a new run starts from the gait's own period and phase
    assert mpc.gait.period_s == 0.6 and mpc.gait.phase(np.array([0.0]))[0, 0] == 0.0


def test_the_fixed_schedule_of_the_paper_keeps_its_period_after_a_push(a1):
    mpc = make_mpc(a1, gait_period_scale=None)
    kicked = np.zeros(a1.nv)
    kicked[1] = 1.0
    mpc.solve(a1.q_nominal, kicked, Commands(), t_s=0.0)
    assert mpc.push_mode.until_t_s is not None and mpc.gait.period_s == 0.6


def test_bad_cadence_options_are_refused_before_anything_is_built():
    with pytest.raises(ConfigError, match="push.gait_period_scale"):
        PushConfig(gait_period_scale=0.0)
    with pytest.raises(ConfigError, match="push.gait_period_scale"):
        PushConfig(gait_period_scale=1.5)
    with pytest.raises(ConfigError, match="push.cadence_hold_s"):
        PushConfig(cadence_hold_s=-1.0)


def _swings(result, robot, after_s):
    """Swings per foot after `after_s` in the MuJoCo run: the foot (pinocchio FK of the simulated q) rising
    through 2 cm above where it stood at the start (a1 steps 5 cm high)."""
    data = robot.model.createData()
    frames = [robot.model.getFrameId(foot) for foot in robot.feet]
    heights = []
    for q in result.log.q:
        pin.framesForwardKinematics(robot.model, data, q)
        heights.append([data.oMf[f].translation[2] for f in frames])
    up = np.array(heights) - heights[0] > 0.02
    rising = ~up[:-1] & up[1:]
    return rising[result.log.t[1:] >= after_s].sum(axis=0)


def test_in_mujoco_the_feet_step_faster_after_a_kick_and_at_the_gait_period_without_one(a1):
    from wbmpc.scenarios import RunConfig, ScenarioOptions, run_scenario

    def run(scale):
        options = ScenarioOptions(push_time_s=0.3, push_speed_m_s=0.6, push_direction_deg=90.0)
        return run_scenario(a1, RunConfig(scenario="push", duration_s=0.9, nodes=6, options=options,
                                          push_gait_period_scale=scale))

    fast, fixed = run(0.5), run(1.0)
    assert fast.metrics["push_gait_period_scale"] == 0.5 and fixed.metrics["push_gait_period_scale"] is None
    assert not fast.metrics["fell"] and not fixed.metrics["fell"]
    # a1 trots at 0.58 s (tuning.py): in the 0.6 s after the kick each foot swings once on the fixed schedule,
    # twice at half the period
    assert _swings(fixed, a1, 0.3).tolist() == [1, 1, 1, 1]
    assert _swings(fast, a1, 0.3).min() >= 2
    # before the kick both runs are the same closed loop
    before = fast.log.t < 0.3
    np.testing.assert_allclose(fast.log.q[before], fixed.log.q[before], atol=1e-9)


def test_each_solver_gets_its_default_cadence_and_an_estimator_that_cannot_see_the_clock_is_refused():
    from wbmpc.scenarios import RunConfig
    from wbmpc.scenarios.library import make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    scenario = make_scenario("push", None)

    def scale(**run):
        return mpc_config_for(scenario, RunConfig(scenario="push", **run)).push.gait_period_scale

    assert scale() == PushConfig.gait_period_scale == 0.5625
    assert scale(solver="rti") is None  # RTI keeps the fixed schedule unless asked
    assert scale(solver="rti", push_gait_period_scale=0.5) == 0.5
    assert scale(push_gait_period_scale=1.0) is None
    assert scale(state="estimated", delay_mode="realtime") is None
    with pytest.raises(ConfigError, match="--push-cadence"):
        RunConfig(state="estimated", delay_mode="realtime", push_gait_period_scale=0.5)
