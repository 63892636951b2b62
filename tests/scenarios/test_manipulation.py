"""Loco-manipulation (section VI-C): scene objects, short closed-loop runs that check the force
reaches the object, and bad input rejected before a run."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import mujoco
import numpy as np
import pytest

from wbmpc.errors import ConfigError
from wbmpc.robots import load_robot
from wbmpc.scenarios import RunConfig, ScenarioOptions, make_scenario, run_scenario
from wbmpc.scenarios.arm_statics import static_arm_torques
from wbmpc.scenarios.signals import low_pass
from wbmpc.scenarios.sweep import parse_loads
from wbmpc.sim.objects import (
    Board,
    CableLoad,
    CompliantPad,
    ExternalHand,
    HandPush,
    Scene,
)

CONTRACT_KEYS = ("scenario", "fell", "duration_s", "base_drift_cm_s", "base_vel_rmse", "ee_pos_rmse_m",
                 "ee_force_err_rel", "max_torque_ratio", "solve_ms", "mpc_failures")


@pytest.fixture(scope="module")
def robot():
    return load_robot("b1_z1")


def _run(robot, name, duration_s, **options):
    return run_scenario(robot, RunConfig(scenario=name, duration_s=duration_s, options=ScenarioOptions(**options)))


def _window_mean(series, start_s, end_s, key="measured_n"):
    use = (series["t"] >= start_s) & (series["t"] <= end_s)
    return float(np.mean(series[key][use]))


# --------------------------------------------------------------------------- scene objects
def test_slack_cable_has_no_tension_and_a_taut_one_pulls_the_end_effector(robot):
    from wbmpc.sim.mujoco_plant import MujocoPlant

    ee = robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]
    distance = float(np.hypot(1.5 - 0.15 - ee[0], ee[2] - 0.1))
    for length, taut in ((distance + 0.05, False), (distance - 0.05, True)):
        scene = Scene(robot, [CableLoad(mass_kg=5.0, position_m=(1.5, 0.0), cable_length_m=length)])
        plant = MujocoPlant(robot, scene.plant_config())
        scene.attach(plant)
        plant.reset(robot.q_nominal, np.zeros(robot.nv))
        for _ in range(20):
            plant.step(np.zeros(robot.n_joints))
        _, tension = scene.recording.series("load", "tension_n")
        _, force = scene.recording.series("load", "force_n")
        if taut:  # stretched at the start: the cable jerks the load (and then may go slack)
            k = int(np.argmax(tension))
            assert tension[k] > 1.0
            assert force[k][0] < 0  # the end-effector pulls the cable back towards itself
        else:
            assert np.all(tension == 0.0)


def test_hand_pulls_the_end_effector_along_its_script_with_a_capped_force():
    hand = ExternalHand(pushes=(HandPush(1.0, (-0.1, 0.0, 0.0), move_s=1.0, hold_s=0.0),), stiffness_n_m=100.0,
                        damping_n_s_m=0.0, max_force_n=8.0)
    p0 = np.array([0.4, 0.0, 0.9])
    assert np.allclose(hand.force_on_ee(0.5, p0, np.zeros(3)), 0)  # before the script
    assert np.allclose(hand.force_on_ee(1.0, p0, np.zeros(3)), 0)  # starts where the end-effector is
    assert np.allclose(hand.force_on_ee(1.5, p0, np.zeros(3)), [-5, 0, 0])  # 5 cm behind at 100 N/m
    assert np.allclose(hand.force_on_ee(2.0, p0, np.zeros(3)), [-8, 0, 0])  # capped
    assert np.allclose(hand.force_on_ee(2.5, p0, np.zeros(3)), 0)  # let go
    with pytest.raises(ConfigError, match="overlap"):
        ExternalHand(pushes=(HandPush(1.0, (0.1, 0, 0)), HandPush(1.5, (0.1, 0, 0))))


def test_board_and_load_reject_bad_settings():
    with pytest.raises(ConfigError):
        Board(orientation="diagonal")
    with pytest.raises(ConfigError, match="mass"):
        CableLoad(mass_kg=-1.0)


def test_low_pass_keeps_a_constant_and_damps_alternation():
    t = np.arange(0, 0.5, 1e-3)
    chatter = np.where(np.arange(t.size) % 2 == 0, 0.0, 20.0)
    out = low_pass(t, chatter, 30.0)
    assert abs(out[-100:].mean() - 10.0) < 0.5 and np.ptp(out[-100:]) < 2.0
    assert np.allclose(low_pass(t, np.full(t.size, 3.0), 30.0), 3.0)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("options, match", [
    (dict(load_kg=-2.0), "load_kg must be > 0 kg"),  # the CLI words it as --load-kg
    (dict(force_n=-5.0), "force_n must be > 0 N"),
    (dict(box_kg=0.0), "box_kg must be > 0 kg"),
    (dict(board="diagonal"), "board"),
    (dict(gait="gallop"), "gait"),
])
def test_bad_options_raise_before_a_run(options, match):
    with pytest.raises(ConfigError, match=match):
        ScenarioOptions(**options)


def test_force_beyond_the_arm_torque_limits_is_rejected_and_near_it_warned(robot):
    with pytest.raises(ConfigError, match="joint"):
        make_scenario("pull", robot, ScenarioOptions(load_kg=40.0))
    with pytest.raises(ConfigError, match="tip the robot"):
        make_scenario("push-box", robot, ScenarioOptions(force_n=300.0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        make_scenario("pull", robot, ScenarioOptions(load_kg=28.0))
    assert any("of the limit" in str(w.message) for w in caught)


def test_static_arm_torques_are_gravity_plus_jacobian_transpose_force(robot):
    base = static_arm_torques(robot, np.zeros(3))
    pulled = static_arm_torques(robot, np.array([-20.0, 0.0, 0.0]))
    pushed = static_arm_torques(robot, np.array([20.0, 0.0, 0.0]))
    assert np.allclose(pulled - base, -(pushed - base))
    assert not np.allclose(pulled, base)


def test_cli_rejects_negative_load_with_exit_2():
    proc = subprocess.run([sys.executable, "-m", "wbmpc.cli", "run", "pull", "--load-kg", "-3", "--no-outputs"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "--load-kg must be > 0 kg, got -3" in proc.stderr


def test_sweep_loads_are_parsed_and_checked():
    assert parse_loads("14,6,10") == [6.0, 10.0, 14.0]
    with pytest.raises(ConfigError):
        parse_loads("6,-1")
    with pytest.raises(ConfigError):
        parse_loads("six")


# --------------------------------------------------------------------------- short closed-loop runs
def test_pull_small_load_while_walking_tensions_the_cable_to_the_target(robot):
    result = _run(robot, "pull", 1.5, load_kg=4.0)
    m = result.metrics
    assert not m["fell"]
    assert all(k in m for k in CONTRACT_KEYS + ("tension_mean_n", "load_moved_m", "torque_ratio_joint3",
                                                "torque_margin_per_joint"))
    target = m["target_tension_n"]
    series = result.scenario.force_series(result.log)
    assert abs(_window_mean(series, 1.0, 1.5) - target) < 0.15 * target  # the cable carries the target force
    assert m["torque_margin_per_joint"]["joint3"] > 0.0


def test_push_box_presses_the_box_with_the_target_force(robot):
    result = _run(robot, "push-box", 1.5, force_n=15.0)
    m = result.metrics
    assert not m["fell"]
    assert m["ee_force_err_rel"] is not None and m["ee_force_err_rel"] < 0.15
    assert abs(m["ee_force_measured_mean_n"] - 15.0) < 1.5
    assert all(k in m for k in CONTRACT_KEYS)


def test_wipe_presses_the_board_and_follows_the_path(robot):
    result = _run(robot, "wipe", 1.5, force_n=8.0)
    m = result.metrics
    assert not m["fell"]
    series = result.scenario.force_series(result.log)
    assert abs(_window_mean(series, 1.0, 1.5) - 8.0) < 1.2  # normal force on the board
    assert m["ee_pos_rmse_m"] is not None and m["ee_pos_rmse_m"] < 0.01
    # the sprung pad keeps the sliding contact closed: the unfiltered force tracks the target too
    # (the rigid sphere's contact made and broke at ~200 Hz: 100 % raw error)
    assert m["ee_force_err_rel_raw"] < 0.1 and m["ee_force_err_rel"] < 0.1
    assert 2.0 < m["pad_deflection_mean_mm"] < 6.0  # about 8 N / 2000 N/m = 4 mm


def test_pad_replaces_the_rigid_end_effector_sphere_and_springs_back(robot):
    """The pad sits where the end-effector sphere was, its contacts count as the end-effector's, and
    its springs have the configured stiffness: a force on the pad deflects it by F / k (MuJoCo)."""
    from wbmpc.sim.mujoco_plant import MujocoPlant

    pad = CompliantPad(stiffness_n_m=2000.0)
    scene = Scene(robot, [pad])
    plant = MujocoPlant(robot, scene.plant_config())
    scene.attach(plant)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    m, d = plant.model, plant.data
    names = [m.geom(g).name for g in range(m.ngeom)]
    assert robot.arm_ee not in names and "pad" in names
    assert m.geom("pad").id in plant.ee_geoms
    ee = robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]
    np.testing.assert_allclose(d.geom("pad").xpos, ee, atol=1e-9)
    # the springs alone: no gravity, the robot made immovable (huge armature on its own dofs), a
    # 10 N push on the pad
    m.opt.gravity[:] = 0.0
    pad_dofs = [int(m.joint(f"pad_{a}").dofadr[0]) for a in "xyz"]
    m.dof_armature[[k for k in range(m.nv) if k not in pad_dofs]] = 1e9
    body = m.body("pad").id
    force = np.array([0.0, 6.0, -8.0])
    d.xfrc_applied[body, :3] = force
    for _ in range(600):
        mujoco.mj_step(m, d)
    rotation = d.body(plant.ee_body).xmat.reshape(3, 3)
    np.testing.assert_allclose(rotation @ np.array([d.joint(f"pad_{a}").qpos[0] for a in "xyz"]),
                               force / pad.stiffness_n_m, atol=2e-4)


def test_compliant_arm_yields_to_the_hand_and_the_robot_stays_up(robot):
    result = _run(robot, "compliant", 1.5)
    m = result.metrics
    assert not m["fell"] and m["kept_balance"]
    assert m["ee_yield_m"] and m["ee_yield_m"][0] > 0.03  # followed the hand back (6 cm by 1.5 s)
    assert m["hand_force_peak_n"][0] < m["hand_force_cap_n"]  # without the hand having to force it
    assert all(k in m for k in CONTRACT_KEYS)
    json.dumps(m, allow_nan=False)  # strict JSON as written: no NaN/Infinity in any metric
