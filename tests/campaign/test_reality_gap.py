"""The reality-gap campaign: plants drawn around the model, reproducible from their row, and the per-axis report."""

import json

import mujoco
import numpy as np
import pytest

from wbmpc.campaign.cases import expand
from wbmpc.campaign.reality_gap import REALITY_GAP_FIXED, REALITY_GAP_RANGES, axis_effects
from wbmpc.campaign.spec import CampaignSpec
from wbmpc.robots import load_robot
from wbmpc.sim.model_errors import reference_drive_train
from wbmpc.sim.mujoco_plant import MujocoPlant
from wbmpc.sim.mujoco_scene import body_names


def _spec(**kw):
    return CampaignSpec(scenario="trot-forward", robot="go2", duration_s=1.0, randomize=True,
                        random={"samples": 6}, **kw)


def test_randomize_draws_every_factor_within_its_range_reproducibly():
    cases = expand(_spec())
    assert len(cases) == 6 and [c.id for c in cases] == [c.id for c in expand(_spec())]
    for case in cases:
        values = case.values
        for name, (low, high) in REALITY_GAP_RANGES.items():
            assert low <= values[name] <= high, name
        assert {k: values[k] for k in REALITY_GAP_FIXED} == REALITY_GAP_FIXED
        assert isinstance(values["plant_seed"], int)
    assert len({c.values["plant_seed"] for c in cases}) == 6
    # an axis on the grid or fixed is not drawn
    fixed = expand(_spec(fixed={"floor_friction_mu": 0.5}, grid={"delay_ms": [0.0, 5.0]}))
    assert len(fixed) == 12 and {c.values["floor_friction_mu"] for c in fixed} == {0.5}
    assert {c.values["delay_ms"] for c in fixed} == {0.0, 5.0}


def _plant(case):
    robot = load_robot(case.robot)
    config = case.run_config()
    return robot, config, MujocoPlant(robot, config.model_errors.plant_config(robot))


def test_a_drawn_plant_differs_from_the_model_as_its_row_records_and_rebuilds_identically():
    case = expand(_spec())[0]
    values = case.values
    robot, config, plant = _plant(case)
    nominal = MujocoPlant(robot)
    summary = config.model_errors.summary(robot)
    factors = summary["link_factors"]
    assert set(factors) == set(body_names(robot)) and all(0.9 <= f <= 1.1 for f in factors.values())
    for name, factor in factors.items():
        assert plant.model.body(name).mass[0] == pytest.approx(factor * nominal.model.body(name).mass[0], rel=1e-9)
        np.testing.assert_allclose(plant.model.body(name).inertia, factor * nominal.model.body(name).inertia, rtol=1e-6)
    base = body_names(robot)[0]
    offset = [values[f"base_com_offset_{a}_m"] for a in "xyz"]
    np.testing.assert_allclose(plant.model.body(base).ipos - nominal.model.body(base).ipos, offset, atol=1e-12)
    reference = reference_drive_train(robot)
    dofs = [plant.model.joint(n).dofadr[0] for n in robot.joint_names]
    np.testing.assert_allclose(plant.model.dof_armature[dofs], values["joint_armature_scale"] * reference["joint_armature_kg_m2"])
    np.testing.assert_allclose(plant.model.dof_damping[dofs],
                               values["joint_damping_scale"] * reference["joint_damping_nm_s_per_rad"])
    np.testing.assert_allclose(plant.model.dof_frictionloss[dofs],
                               values["joint_frictionloss_scale"] * reference["joint_frictionloss_nm"])
    assert plant.model.geom_friction[plant.model.geom("floor").id][0] == pytest.approx(values["floor_friction_mu"])
    from wbmpc.scenarios.runner import plant_mass_kg

    assert plant_mass_kg(plant) == pytest.approx(sum(plant.model.body(n).mass[0] for n in factors))
    assert config.state == "estimated" and (config.delay_mode, config.delay_ms) == ("fixed", values["delay_ms"])
    assert config.sensors.imu.gyro_noise_rad_s == pytest.approx(0.005 * values["sensor_noise_scale"])
    # the same row rebuilds the same plant
    again = _plant(case)[2]
    for name in ("body_mass", "body_inertia", "body_ipos", "dof_armature", "dof_damping", "dof_frictionloss", "geom_friction"):
        np.testing.assert_array_equal(getattr(plant.model, name), getattr(again.model, name))
    # and another draw differs
    other = _plant(expand(_spec())[1])[2]
    assert not np.array_equal(plant.model.body_mass, other.model.body_mass)
    assert isinstance(plant.model, mujoco.MjModel)


def test_axis_effects_find_the_factor_that_breaks_it():
    rng = np.random.default_rng(0)
    rows = []
    for k in range(100):
        mu, delay = float(rng.uniform(0.4, 1.0)), float(rng.uniform(0.0, 10.0))
        rows.append({"case_id": str(k), "recovered": not mu < 0.5 or rng.random() < 0.2, "fell_at_s": 1.0,
                     "floor_friction_mu": mu, "delay_ms": delay, "error": None,
                     "params_json": json.dumps({"floor_friction_mu": mu, "delay_ms": delay}),
                     "metrics_json": json.dumps({"mass_kg": 16.0, "plant_mass_kg": 16.0 + k / 100})})
    effects = axis_effects(rows, ["floor_friction_mu", "delay_ms"])
    friction = effects["floor_friction_mu"]["breaking_point"]
    assert friction["side"] == "below" and 0.45 <= friction["value"] <= 0.52 and friction["p_value"] < 1e-6
    assert effects["delay_ms"]["breaking_point"]["p_value"] > 0.01
    bins = effects["floor_friction_mu"]["bins"]
    assert bins[0]["stayed_up_share"] < 0.7 and bins[-1]["stayed_up_share"] == 1.0
    assert "plant_mass_ratio" in effects


def test_campaign_cli_lists_the_randomized_cases(capsys):
    from wbmpc.cli import main

    assert main(["campaign", "--scenario", "trot-forward", "--robot", "go2", "--randomize", "--samples", "4",
                 "--dry-run"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 4 and all("plant_seed=" in line and "state=estimated" in line for line in out)
