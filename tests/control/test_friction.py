"""The ground's friction coefficient: the option reaches the OCP's cone rows (eq. 6), the floor keeps its own."""

import numpy as np
import pytest

from wbmpc.control import MPC, Commands, MpcConfig
from wbmpc.ocp.grid import TimeGrid
from wbmpc.ocp.problem import OcpConfig

SMALL = OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.06))


def _tangential_share(mpc, robot, speed_m_s: float) -> float:
    """Largest |F_t| / F_z over the stance feet of a plan that starts a trot at `speed_m_s` from rest."""
    solution = mpc.solve(robot.q_nominal, np.zeros(robot.nv), Commands(base_velocity_m_s=np.array([speed_m_s, 0, 0])),
                         t_s=0.3)
    assert solution.success, solution.stats
    _, contact, _ = mpc.schedule(solution.t_s)
    n_feet = len(robot.feet)
    forces = solution.forces[:, : 3 * n_feet].reshape(-1, n_feet, 3)
    stance = contact[: len(forces)].astype(bool) & (forces[..., 2] > 0.05 * robot.mass_kg * 9.81 / n_feet)
    return float(np.max(np.linalg.norm(forces[stance][:, :2], axis=1) / forces[stance][:, 2]))


def test_the_friction_coefficient_bounds_the_planned_contact_forces(b1z1):
    """A plan that accelerates hard leans on the cone: with mu 0.15 its forces stay inside it (up to the cone's
    smoothing), with the default 0.7 the same plan pushes beyond 0.15."""
    wide = MPC(b1z1, MpcConfig(ocp=SMALL, gait="trot"))
    narrow = MPC(b1z1, MpcConfig(ocp=SMALL, gait="trot", friction_coefficient=0.15), problem=wide.problem,
                 solver=wide.solver)
    assert _tangential_share(wide, b1z1, 1.5) > 0.2
    assert _tangential_share(narrow, b1z1, 1.5) <= 0.15 + 0.01


def test_run_option_and_tuning_set_the_mpcs_coefficient_and_not_the_floors(b1z1):
    from wbmpc.control.tuning import tuning_for
    from wbmpc.scenarios import RunConfig, make_scenario
    from wbmpc.scenarios.runner import mpc_config_for

    scenario = make_scenario("trot-in-place", b1z1)
    assert mpc_config_for(scenario, RunConfig(), b1z1).friction_coefficient == tuning_for(b1z1).friction_coefficient
    assert mpc_config_for(scenario, RunConfig(friction_mu=0.45), b1z1).friction_coefficient == 0.45
    assert tuning_for(b1z1).report()["friction_coefficient"]["value"] == tuning_for(b1z1).friction_coefficient
    from wbmpc.errors import ConfigError

    with pytest.raises(ConfigError, match="friction_mu"):
        RunConfig(friction_mu=0.0)


def test_floor_friction_reaches_the_mujoco_floor_only():
    from wbmpc.robots import load_robot
    from wbmpc.scenarios import RunConfig, run_scenario

    robot = load_robot("go2")
    result = run_scenario(robot, RunConfig(scenario="stand", duration_s=0.05, floor_friction_mu=0.35, friction_mu=0.6))
    model = result.plant.model
    assert model.geom_friction[model.geom("floor").id][0] == pytest.approx(0.35)
    assert result.metrics["settings"]["values"]["friction_coefficient"] == 0.6
