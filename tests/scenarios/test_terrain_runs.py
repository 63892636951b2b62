"""The closed loop on a terrain: the estimator and the fall check measure heights from it, a short slope run (default
suite) and whole courses (slow)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from wbmpc.cli import EXIT_BAD_INPUT, main
from wbmpc.control.loop import ClosedLoop, LoopConfig
from wbmpc.estimation import SensorConfig
from wbmpc.estimation.metrics import estimation_metrics
from wbmpc.estimation.source import EstimatedState
from wbmpc.gait import make_gait
from wbmpc.robots import load_robot
from wbmpc.sim import make_plant
from wbmpc.sim.mujoco_scene import MujocoPlantConfig
from wbmpc.terrain import Box, Terrain


@pytest.fixture(scope="module")
def go2():
    return load_robot("go2")


def _pd(robot, q, v, kp=60.0, kd=2.0):
    return kp * (robot.q_nominal[7:] - q[7:]) - kd * v[6:]


@pytest.mark.parametrize("knows_terrain", [True, False])
def test_the_estimator_puts_stance_feet_on_the_terrain(go2, knows_terrain):
    """go2 standing on a 30 cm platform in MuJoCo: with the terrain the estimated base height is MuJoCo's within 1 cm;
    assuming the flat floor it is off by the platform's height."""
    platform = Terrain((Box((0.0, 0.0), (1.5, 1.0), 0.3, name="platform"),))
    plant = make_plant("mujoco", go2, MujocoPlantConfig(terrain=platform))
    q0 = go2.q_nominal.copy()
    q0[2] += 0.3
    plant.reset(q0)
    source = EstimatedState(plant, make_gait("stand", 4), SensorConfig.noiseless(), terrain=platform if knows_terrain
                            else None)
    for _ in range(1000):
        q, v = plant.state()
        source.measure()
        plant.step(_pd(go2, q, v))
    error = abs(source.estimator.q[2] - plant.state()[0][2])
    if knows_terrain:
        assert error < 0.01 and estimation_metrics(source.log)["est_base_pos_rmse_m"] < 0.01
    else:
        assert error > 0.2


def test_the_fall_check_measures_from_the_terrain(go2):
    """A robot standing at the bottom of a pit 40 cm deep is up (its base over the pit's floor); with its base on that
    floor it fell; without the terrain the standing robot would count as fallen."""
    pit = Terrain((Box((3.0, 0.0), (0.5, 0.5), 0.0, name="far"),), floor_m=-0.4)
    standing = go2.q_nominal.copy()
    standing[2] -= 0.4
    lying = standing.copy()
    lying[2] = -0.35
    with_terrain = ClosedLoop(SimpleNamespace(robot=go2), None, LoopConfig(terrain=pit))
    flat = ClosedLoop(SimpleNamespace(robot=go2), None, LoopConfig())
    assert not with_terrain._fallen(standing) and with_terrain._fallen(lying)
    assert flat._fallen(standing)


def run_json(capsys, *argv):
    code = main(["run", *argv, "--json"])
    out = capsys.readouterr()
    return code, json.loads(out.out.strip().splitlines()[-1]), out.err


def test_a_short_run_onto_a_slope(capsys, tmp_path):
    """a1 trots from the floor onto a 10 deg ramp starting just ahead of its front toes (--terrain FILE): no fall, the
    front feet stand on the ramp, the terrain's metrics and file are written."""
    rise = 1.0 * np.tan(np.deg2rad(10.0))
    course = tmp_path / "ramp.yaml"
    course.write_text(yaml.safe_dump({"name": "ramp", "ramps": [
        {"name": "ramp", "start": [0.24, 0.0, 0.0], "end": [1.24, 0.0, float(rise)], "width": 1.0}]}))
    code, m, err = run_json(capsys, "trot-forward", "--robot", "a1", "--nodes", "6", "--duration", "1.2", "--speed", "0.3",
                            "--terrain", str(course), "--out", str(tmp_path / "run"))
    assert code == 0 and not m["fell"], err[-2000:]
    assert m["terrain"] == "ramp" and m["steps_total"] == 1 and m["pieces_stood_on"] == 1  # feet on the ramp
    assert m["body_terrain_contacts"] == 0 and m["edge_contacts"] == 0
    saved = yaml.safe_load((tmp_path / "run" / "terrain.yaml").read_text())
    assert saved["ramps"][0]["end"] == pytest.approx([1.24, 0.0, rise])


def test_bad_terrain_input_exits_2_before_building(capsys, tmp_path):
    overlapping = tmp_path / "bad.yaml"
    overlapping.write_text("boxes:\n  - {name: a, centre: [1, 0], size: [1, 1], top: 0.1}\n"
                           "  - {name: b, centre: [1.5, 0], size: [1, 1], top: 0.2}\n")
    assert main(["run", "trot-forward", "--robot", "a1", "--terrain", str(overlapping), "--no-outputs"]) == EXIT_BAD_INPUT
    assert "box 'a' and box 'b' overlap" in capsys.readouterr().err
    under = tmp_path / "under.yaml"
    under.write_text("boxes:\n  - {name: step, centre: [0.2, 0], size: [0.3, 1], top: 0.05}\n")
    assert main(["run", "trot-forward", "--robot", "a1", "--terrain", str(under), "--no-outputs"]) == EXIT_BAD_INPUT
    assert "inside the terrain ('step')" in capsys.readouterr().err
    assert main(["run", "stairs", "--robot", "a1", "--plant", "pinocchio", "--no-outputs"]) == EXIT_BAD_INPUT
    assert "--plant mujoco" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("robot, scenario, extra", [
    ("go2", "stairs", []),
    ("b1_z1", "stairs", []),
    ("go2", "slope", []),
    ("b1_z1", "stepping-stones", []),
])
def test_whole_courses(capsys, tmp_path, robot, scenario, extra):
    """The issue's courses at 0.2 m/s, compiled converged Fatrop: crossed without a fall, a shin or knee on the
    terrain, or a foot on an edge (stepping stones: nor in a gap); b1_z1 carries its hand within 2 cm while
    climbing."""
    code, m, err = run_json(capsys, scenario, "--robot", robot, "--compiled", *extra, "--out", str(tmp_path / "run"))
    assert code == 0 and m["course_completed"], err[-2000:]
    if scenario == "stepping-stones":  # none in a gap; at least as many stones stood on as columns
        assert m["foot_floor_touches"] == 0 and m["pieces_stood_on"] >= 8 + 2
    else:
        assert m["steps_climbed"] == m["steps_total"]
    assert m["body_terrain_contacts"] == 0 and m["edge_contacts"] == 0
    if robot == "b1_z1":
        assert m["ee_pos_rmse_course_m"] < 0.02


@pytest.mark.slow
def test_g1_walks_up_three_steps_of_10_cm(capsys, tmp_path):
    """The issue's humanoid number: g1 (flat feet) walks up 3 steps of 10 cm / 30 cm, compiled converged Fatrop: on
    the landing without a fall, every step under both feet, no shin or knee on a step, few failed solves (the base
    ramped over its support's footholds, the walk 1.4 times slower off the floor). A foot's touch near a nose is
    allowed twice: the trailing heel, 1-2 cm from the nose of its tread, touched once as it lifted."""
    code, m, err = run_json(capsys, "stairs", "--robot", "g1", "--stairs", "up", "--steps", "3", "--step-rise", "0.10",
                            "--compiled", "--out", str(tmp_path / "run"))
    assert code == 0 and m["course_completed"] and not m["fell"], err[-2000:]
    assert m["steps_climbed"] == m["steps_total"] == 3
    assert m["body_terrain_contacts"] == 0 and m["edge_contacts"] <= 2
    assert m["mpc_failures"] <= 0.05 * m["mpc_solves"]


@pytest.mark.parametrize("robot_name", ["go2", "g1"])
def test_stairs_up_end_with_the_whole_robot_on_the_landing(robot_name):
    """`stairs --stairs up` runs until the rear feet are past the last riser: where the base is by then at the
    commanded speed (started after START_S), every foot's sole lies on the landing, clear of its far end (g1
    walked off the landing's end and fell when the run went on to pass it)."""
    from wbmpc.scenarios import ScenarioOptions
    from wbmpc.scenarios.terrain import START_S, Stairs, feet_extent

    robot = load_robot(robot_name)
    scenario = Stairs(ScenarioOptions(stairs_direction="up"))
    scenario.check(robot)
    terrain = scenario.terrain(robot)
    landing = next(p for p in terrain.pieces if p.name == "landing").corners()[:, 0]
    front, rear = feet_extent(robot)
    base_x = scenario.start_pose(robot)[0] + scenario.options.speed_m_s * (scenario.default_duration_s - START_S)
    assert landing.min() < base_x + rear and base_x + front < landing.max() - 0.1
