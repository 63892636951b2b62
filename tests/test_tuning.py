"""Per-robot control tuning reaches the MPC and the PD of a run; explicit options win."""

import dataclasses

import pytest

from wbmpc.cli import _gains, build_parser
from wbmpc.control.interpolator import PdGains
from wbmpc.control.mpc import CostWeights
from wbmpc.control.tuning import TUNINGS, RobotTuning, scaled_weights, tuning_for
from wbmpc.robots import load_robot
from wbmpc.scenarios import RunConfig, make_scenario
from wbmpc.scenarios.runner import mpc_config_for


def test_robots_without_an_entry_get_the_paper_robot_defaults(b1z1):
    assert "b1_z1" not in TUNINGS
    assert tuning_for(b1z1) == RobotTuning()
    config = mpc_config_for(make_scenario("trot-in-place", b1z1, RunConfig().options), RunConfig(), b1z1)
    assert config.weights == CostWeights() and config.gait_period_s is None


@pytest.mark.parametrize("name", sorted(TUNINGS))
def test_tuned_presets_reach_the_mpc_config_and_gains(name):
    robot, tuning = load_robot(name), TUNINGS[name]
    config = mpc_config_for(make_scenario("trot-in-place", robot, RunConfig().options), RunConfig(), robot)
    assert (config.weights, config.swing, config.gait_period_s) == (tuning.weights, tuning.swing, tuning.gait_period_s)
    args = build_parser().parse_args(["run", "trot-in-place", "--robot", name])
    assert _gains(args, robot) == tuning.gains
    args = build_parser().parse_args(["run", "trot-in-place", "--robot", name, "--kd", "7.5"])
    assert _gains(args, robot) == dataclasses.replace(tuning.gains, kd_leg=7.5)


def test_scaled_weights_scale_tracking_only():
    weights = scaled_weights(0.5)
    assert weights.base_position == (250.0, 250.0, 5000.0) and weights.leg_joint_position == 25.0
    assert (weights.acceleration, weights.contact_force, weights.joint_torque) == (1e-2, 1e-3, 1e-3)
    assert PdGains() == RobotTuning().gains
