"""Campaigns on a real Dask LocalCluster (tiny closed-loop runs), model errors in the plant, reports."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.campaign import CampaignSpec, ResultTable, expand, load_spec, run_campaign
from wbmpc.campaign.faults import KillWorkerOnce
from wbmpc.campaign.report import push_map, write_report
from wbmpc.campaign.spec import parse_grid_flag
from wbmpc.errors import ConfigError
from wbmpc.robots import load_robot
from wbmpc.sim.model_errors import ModelErrors
from wbmpc.sim.mujoco_plant import MujocoPlant


def _tiny_spec(**grid) -> CampaignSpec:
    # a1 (no arm), 5 nodes, 0.1 s runs with an early push: each case is ~1 s once the worker's MPC exists
    return CampaignSpec(name="tiny", scenario="push", robot="a1", duration_s=0.1, nodes=5,
                        fixed={"push_time_s": 0.02}, grid=grid or {"push_direction_deg": [0, 90], "push_speed_m_s": [0.2, 0.4]})


@pytest.fixture(scope="module")
def client():
    import logging

    from distributed import Client, LocalCluster

    from wbmpc.campaign.execution import worker_env

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR, env=worker_env())
    with Client(cluster) as c:
        yield c
    cluster.close()


def test_four_case_campaign_then_resume_skips_finished(client, tmp_path):
    spec = _tiny_spec()
    cases = expand(spec)
    assert len(cases) == 4 and len({c.id for c in cases}) == 4
    run = run_campaign(spec, tmp_path, client=client, progress=False)
    assert (run.recorded, run.skipped, run.unfinished, run.errors) == (4, 0, [], 0)
    rows = ResultTable(tmp_path).read().to_pylist()
    assert sorted(r["case_id"] for r in rows) == sorted(c.id for c in cases)
    for row in rows:
        case = next(c for c in cases if c.id == row["case_id"])
        assert row["push_direction_deg"] == case.values["push_direction_deg"]
        assert row["push_speed_m_s"] == case.values["push_speed_m_s"]
        assert row["duration_s"] == pytest.approx(0.1, abs=3e-3)  # a real 0.1 s closed loop ran
        assert row["mpc_solves"] >= 8 and row["recovered"] and not row["fell"]
    assert len({r["pid"] for r in rows}) >= 1
    assert (tmp_path / "results.parquet").is_file()
    # resume: nothing to run (no cluster work), the table unchanged
    again = run_campaign(spec, tmp_path, client=client, resume=True, progress=False)
    assert (again.recorded, again.skipped) == (0, 4)
    assert len(ResultTable(tmp_path).read()) == 4
    # a larger grid resumes only its new cases
    bigger = _tiny_spec(push_direction_deg=[0, 90, 180], push_speed_m_s=[0.2, 0.4])
    more = run_campaign(bigger, tmp_path, client=client, resume=True, progress=False)
    assert (more.recorded, more.skipped) == (2, 4)
    assert len(ResultTable(tmp_path).read()) == 6
    with pytest.raises(ConfigError, match="--resume"):
        run_campaign(spec, tmp_path, client=client, progress=False)
    paths = write_report(tmp_path)
    assert (tmp_path / "push_map.png").is_file() and (tmp_path / "summary.md").read_text().count("| 180 |") == 1
    assert any(p.name == "summary.json" for p in paths)


def test_case_that_kills_its_worker_is_retried_and_recorded_once(client, tmp_path):
    spec = _tiny_spec(push_direction_deg=[45, 135], push_speed_m_s=[0.3])
    cases = expand(spec)
    # killed as the case starts: a time into the case would race with how fast the machine runs it
    killer = KillWorkerOnce(str(tmp_path / "faults"), frozenset({cases[0].id}), after_s=0.0)
    run = run_campaign(spec, tmp_path / "out", client=client, runner=killer, progress=False)
    assert killer.killed() == [cases[0].id]  # the worker really was killed mid-case
    assert (run.recorded, run.unfinished, run.errors) == (2, [], 0)
    rows = ResultTable(tmp_path / "out").read().to_pylist()
    assert sorted(r["case_id"] for r in rows) == sorted(c.id for c in cases)  # nothing lost, nothing twice
    killed_pid = int((tmp_path / "faults" / f"{cases[0].id}.killed").read_text())
    retried = next(r for r in rows if r["case_id"] == cases[0].id)
    assert retried["pid"] != killed_pid and retried["duration_s"] == pytest.approx(0.1, abs=3e-3)


def test_spec_files_and_grid_flags(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_text("scenario: push\nseeds: [0, 1]\ngrid:\n  push_speed_m_s: [0.5, 1.0]\n  gait_phase: [0, 0.5]\n")
    spec = load_spec(path, grid=dict([parse_grid_flag("push_direction_deg=0:90:45")]))
    cases = expand(spec)
    assert len(cases) == 2 * 2 * 3 * 2
    toml = tmp_path / "spec.toml"
    toml.write_text('scenario = "push"\n[grid]\npush_speed_m_s = [0.5, 1.0]\n')
    assert len(expand(load_spec(toml))) == 2
    # the gait phase shifts the push time by a share of the trot period (0.8 s)
    phased = [c for c in cases if c.values["gait_phase"] == 0.5][0]
    assert phased.run_config().options.push_time_s == pytest.approx(2.0 + 0.4)
    # ... the robot's own period (derived from its size: a1 trots at 0.58 s)
    from wbmpc.control.tuning import tuning_for

    a1_spec = CampaignSpec(scenario="push", robot="a1", grid={"gait_phase": [0.5]})
    a1_period_s = tuning_for("a1").gait_period_s
    assert 0.55 < a1_period_s < 0.6
    assert expand(a1_spec)[0].run_config().options.push_time_s == pytest.approx(2.0 + 0.5 * a1_period_s)
    # the push cadence is an axis: 1 is the paper's fixed schedule, the default otherwise
    cadence = expand(CampaignSpec(scenario="push", grid={"push_gait_period_scale": [1.0, 0.5]}))
    assert sorted(c.run_config().push_gait_period_scale for c in cadence) == [0.5, 1.0]
    assert expand(_tiny_spec())[0].run_config().push_gait_period_scale is None  # the solver's default
    with pytest.raises(ConfigError, match="push_gait_period_scale"):  # before any cluster or row exists
        run_campaign(CampaignSpec(scenario="push", grid={"push_gait_period_scale": [0.5, 1.5]}), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()
    with pytest.raises(ConfigError, match="unknown campaign axis 'push_sped'; available campaign axes: "):
        load_spec(None, grid={"push_sped": [1.0]})
    with pytest.raises(ConfigError, match="unknown keys"):
        (tmp_path / "bad.json").write_text(json.dumps({"scenaro": "push"}))
        load_spec(tmp_path / "bad.json")


def test_text_and_whole_number_scenario_options_are_campaign_axes():
    """Scenario options declared as text (arm_target_path, stairs_direction, ...) take names, whole numbers
    (steps) reach the scenario as int; a number for a text axis names the problem."""
    spec = CampaignSpec(scenario="arm-track", grid={"arm_target_path": ["sine", "behind-base"]}, fixed={"steps": 3.0})
    options = [case.run_config().options for case in expand(spec)]
    assert sorted(o.arm_target_path for o in options) == ["behind-base", "sine"]
    assert all(o.steps == 3 and isinstance(o.steps, int) for o in options)
    stairs = expand(CampaignSpec(scenario="stairs", fixed={"stairs_direction": "up"}))[0].run_config()
    assert stairs.options.stairs_direction == "up"
    with pytest.raises(ConfigError, match="axis arm_target_path takes names"):
        expand(CampaignSpec(scenario="arm-track", fixed={"arm_target_path": 2.0}))


def test_push_map_takes_the_largest_speed_recovered_in_every_phase():
    rows = [{"push_direction_deg": 90.0, "push_speed_m_s": s, "recovered": ok}
            for s, ok in ((0.2, True), (0.2, True), (0.4, True), (0.4, False), (0.6, True), (0.6, True))]
    rows += [{"push_direction_deg": 450.0, "push_speed_m_s": 0.8, "recovered": True}]  # 450 deg = 90 deg
    info = push_map(rows)[90.0]
    assert info["largest_recovered_m_s"] == 0.2  # 0.4 failed in one phase
    assert info["largest_recovered_any_case_m_s"] == 0.8
    assert info["recovered_share"][0.4] == 0.5


def _com_and_mass(robot, errors):
    plant = MujocoPlant(robot, errors.plant_config(robot))
    mujoco.mj_forward(plant.model, plant.data)
    return plant.data.subtree_com[1].copy(), float(plant.model.body_mass.sum()), plant


def test_model_errors_change_the_plant_not_the_model():
    robot = load_robot("b1_z1")
    data = robot.model.createData()
    com_model = pin.centerOfMass(robot.model, data, robot.q_nominal)
    com, mass, _ = _com_and_mass(robot, ModelErrors())
    assert np.allclose(com, com_model, atol=1e-9) and mass == pytest.approx(robot.mass_kg)
    # base CoM 5 cm rearward: whole-body CoM moves by 5 cm x (base mass / total mass)
    base_mass = robot.model.inertias[1].mass
    com, mass, _ = _com_and_mass(robot, ModelErrors(base_com_offset_m=(-0.05, 0.0, 0.0)))
    assert com - com_model == pytest.approx([-0.05 * base_mass / robot.mass_kg, 0, 0], abs=1e-9)
    # a 2 kg payload at the end-effector frame: mass and CoM as pinocchio computes with a point mass there
    pin.framesForwardKinematics(robot.model, data, robot.q_nominal)
    ee = data.oMf[robot.frame_id(robot.arm_ee)].translation
    com, mass, _ = _com_and_mass(robot, ModelErrors(ee_payload_kg=2.0))
    assert mass == pytest.approx(robot.mass_kg + 2.0)
    assert com == pytest.approx((robot.mass_kg * com_model + 2.0 * ee) / (robot.mass_kg + 2.0), abs=1e-6)
    _, mass, plant = _com_and_mass(robot, ModelErrors(link_mass_scale=1.1, joint_armature_kg_m2=0.01, floor_friction_mu=0.4,
                                                      joint_frictionloss_nm=0.5))
    assert mass == pytest.approx(1.1 * robot.mass_kg)
    assert plant.model.dof_armature[-1] == pytest.approx(0.01) and plant.model.geom_friction[0, 0] == pytest.approx(0.4)
    assert np.all(plant.model.dof_frictionloss[6:] == 0.5) and np.all(plant.model.dof_frictionloss[:6] == 0)
    case = expand(CampaignSpec(scenario="stand", grid={"joint_frictionloss_nm": [0.5]}))[0]
    assert case.run_config().model_errors.joint_frictionloss_nm == 0.5
    assert robot.mass_kg == pytest.approx(pin.computeTotalMass(robot.model))  # the controller's model is untouched
    with pytest.raises(ConfigError, match="ee_payload_kg"):
        ModelErrors(ee_payload_kg=-1.0)


def _slow_case(case):
    import time

    time.sleep(30)
    return {}


def test_campaign_without_workers_stops_instead_of_hanging(tmp_path):
    """Workers gone for good (killed, never restarted): the run ends after the timeout with every case
    unfinished and no row, so `--resume` reruns them; it does not wait forever."""
    import logging
    import time

    from distributed import Client, LocalCluster

    from wbmpc.campaign.execution import worker_env

    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR, env=worker_env())
    with Client(cluster) as lonely:
        spec = _tiny_spec(push_direction_deg=[0, 90], push_speed_m_s=[0.2])
        cluster.scale(0)  # the only worker leaves before the cases start
        deadline = time.monotonic() + 30
        while lonely.scheduler_info()["workers"] and time.monotonic() < deadline:
            time.sleep(0.1)
        start = time.monotonic()
        run = run_campaign(spec, tmp_path, client=lonely, runner=_slow_case, progress=False, no_worker_timeout_s=2.0)
        assert time.monotonic() - start < 25
    cluster.close()
    assert run.recorded == 0 and sorted(run.unfinished) == sorted(c.id for c in expand(spec))
    assert not list(tmp_path.glob("rows/*.parquet"))
