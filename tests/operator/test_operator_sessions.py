"""The issue's 60 s operator session (examples/session.yaml) on b1_z1, go2 and a walking g1 (session_walking.yaml),
and in real time: no
fall; per segment, after 1 s of settling, base velocity RMSE <= 0.05 m/s and yaw-rate RMSE <= 0.1 rad/s; from a stop
to standing still within two gait periods; every command at the MPC's next step. Minutes each: slow."""

from pathlib import Path

import pytest

from wbmpc.operator.config import OperatorConfig
from wbmpc.robots import load_robot
from wbmpc.scenarios import RunConfig, run_scenario

SESSION = str(Path(__file__).resolve().parents[2] / "examples" / "session.yaml")
WALKING_SESSION = str(Path(__file__).resolve().parents[2] / "examples" / "session_walking.yaml")


def _check(metrics: dict) -> None:
    assert not metrics["fell"], metrics["fell_at_s"]
    operator = metrics["operator"]
    scored = [s for s in operator["segments"] if s["base_vel_rmse"] is not None]
    assert len(scored) >= 7
    for segment in scored:
        assert segment["base_vel_rmse"] <= 0.05, segment
        assert segment["yaw_rate_rmse"] <= 0.1, segment
    assert len(operator["stops"]) == 2 and all(stop["within_2_periods"] for stop in operator["stops"])
    assert operator["command_latency_ms"]["max"] <= operator["command_latency_ms"]["mpc_period_ms"] + 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["b1_z1", "go2"])
def test_the_sixty_second_session(robot):
    result = run_scenario(load_robot(robot), RunConfig(scenario="stand", compiled=True,
                                                       operator=OperatorConfig(commands_file=SESSION)))
    _check(result.metrics)


@pytest.mark.slow
def test_the_sixty_second_walking_session_on_a_humanoid():
    """The issue's "(walking) g1": the session without the hand's entries (standing with its hand 20 cm forward g1
    leans after it and falls: docs/operator.md)."""
    result = run_scenario(load_robot("g1"), RunConfig(scenario="stand", compiled=True,
                                                      operator=OperatorConfig(commands_file=WALKING_SESSION)))
    _check(result.metrics)


@pytest.mark.slow
def test_the_sixty_second_session_in_real_time():
    """Wall-clock paced, the MPC in its own process (a quiet machine: other load makes plans late)."""
    result = run_scenario(load_robot("b1_z1"), RunConfig(scenario="stand", compiled=True, delay="realtime",
                                                         operator=OperatorConfig(commands_file=SESSION)))
    _check(result.metrics)
