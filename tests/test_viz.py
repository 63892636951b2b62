"""Plots and the HTML replay, on a small synthetic run log (fast) and, marked slow, on a real run."""

import json
import re

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.loop import RunLog
from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError
from wbmpc.robots import load_robot
from wbmpc.robots.model import RobotModel
from wbmpc.robots.presets import custom_spec, example_robot_data_dir
from wbmpc.viz import base_velocity_heading, frame_positions, replay_data, save_plots, save_replay

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def synthetic_q(robot, t: np.ndarray, speed: float = 0.2) -> np.ndarray:
    """Base walking forward while turning slowly, joints oscillating around the nominal pose."""
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 0] += speed * t
    q[:, 2] += 0.01 * np.sin(2 * np.pi * 2.5 * t)
    for k, tk in enumerate(t):
        q[k, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.02 * np.sin(5 * tk), 0.03, 0.3 * tk)).coeffs()
    phases = np.arange(robot.n_joints)
    q[:, 7:] += 0.15 * np.sin(2 * np.pi * 1.25 * t[:, None] + phases[None, :])
    return q


def synthetic_log(robot, duration_s: float = 0.3, control_hz: float = 500.0, mpc_hz: float = 80.0) -> RunLog:
    rng = np.random.default_rng(0)
    t = np.arange(0.0, duration_s, 1.0 / control_hz)
    q = synthetic_q(robot, t)
    v = np.zeros((t.size, robot.nv))
    v[:, 0] = 0.2
    v[:, 5] = 0.3
    v[:, 6:] = rng.normal(0, 0.5, (t.size, robot.n_joints))
    tau = rng.uniform(-0.8, 0.8, (t.size, robot.n_joints)) * robot.tau_max
    n_feet = len(robot.feet)
    forces = np.zeros((t.size, n_feet, 3))
    forces[:, :, 2] = rng.uniform(0, 300, (t.size, n_feet))
    mpc_t = np.arange(0.0, duration_s, 1.0 / mpc_hz)
    phase = (mpc_t % 0.8) < 0.4
    planned = np.array([[float(p if i % 3 == 0 else not p) for i in range(n_feet)] for p in phase])
    log = RunLog()
    log.t, log.q, log.v = list(t), list(q), list(v)
    log.tau, log.tau_ff, log.q_des = list(tau), list(0.9 * tau), list(q[:, 7:])
    log.contact_forces = list(forces)
    log.mpc_t = list(mpc_t)
    log.solve_ms = list(rng.uniform(5, 20, mpc_t.size))
    log.iterations = list(rng.integers(3, 12, mpc_t.size))
    log.success = [k != 5 for k in range(mpc_t.size)]
    log.status = ["ok"] * mpc_t.size
    log.planned_contact = list(planned)
    log.commands = [Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), base_yaw_rate_rad_s=0.3) for _ in mpc_t]
    return log


def bolt():
    """A biped (no arm, feet not named like a quadruped's) from example-robot-data."""
    root = example_robot_data_dir() / "bolt_description"
    spec = custom_spec(str(root / "robots/bolt.urdf"), ["FL_FOOT", "FR_FOOT"], srdf=str(root / "srdf/bolt.srdf"),
                       pose="standing", name="bolt")
    return RobotModel(spec)


def assert_pngs(paths, expected_names):
    assert sorted(p.name for p in paths) == sorted(expected_names)
    for path in paths:
        content = path.read_bytes()
        assert content.startswith(PNG_SIGNATURE), path
        assert len(content) > 10_000, path


def embedded_json(html: str) -> dict:
    match = re.search(r'<script id="replay-data" type="application/json">(.*?)</script>', html, re.S)
    assert match, "no embedded replay data"
    return json.loads(match.group(1))


# ----------------------------------------------------------------------------- plots
def test_heading_frame_velocity_undoes_yaw_but_keeps_pitch():
    q = np.zeros((2, 7))
    q[0, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0, 0, np.pi / 2)).coeffs()
    q[1, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0, np.pi / 6, 1.0)).coeffs()
    v = np.zeros((2, 6))
    v[:, 0] = 1.0  # forward in the base frame
    v[:, 5] = 0.5  # yaw rate about base z
    v_heading, yaw_rate = base_velocity_heading(q, v)
    np.testing.assert_allclose(v_heading[0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(v_heading[1], [np.cos(np.pi / 6), 0, -np.sin(np.pi / 6)], atol=1e-12)
    np.testing.assert_allclose(yaw_rate, [0.5, 0.5 * np.cos(np.pi / 6)], atol=1e-12)


def test_save_plots_writes_every_figure(b1z1, tmp_path):
    log = synthetic_log(b1z1)
    p0 = frame_positions(b1z1, log.q[0], [b1z1.arm_ee])[b1z1.arm_ee][0]
    paths = save_plots(b1z1, log, tmp_path / "plots", ee_reference=lambda t: p0 + [0, 0.05 * t, 0])
    assert_pngs(paths, ["base_velocity.png", "ee_position.png", "joint_torques.png", "foot_heights.png",
                        "contact_forces.png", "solver.png"])
    assert all(p.parent == tmp_path / "plots" for p in paths)


def test_save_plots_without_arm_skips_the_end_effector(tmp_path):
    robot = load_robot("go2")
    paths = save_plots(robot, synthetic_log(robot), tmp_path)
    assert_pngs(paths, ["base_velocity.png", "joint_torques.png", "foot_heights.png", "contact_forces.png",
                        "solver.png"])


def test_save_plots_on_a_biped_without_mpc_steps(tmp_path):
    robot = bolt()
    log = synthetic_log(robot)
    log.mpc_t, log.solve_ms, log.iterations, log.success, log.planned_contact, log.commands = [], [], [], [], [], []
    paths = save_plots(robot, log, tmp_path)
    assert_pngs(paths, ["base_velocity.png", "joint_torques.png", "foot_heights.png", "contact_forces.png"])


def test_save_plots_rejects_a_log_of_another_robot(b1z1, tmp_path):
    with pytest.raises(ConfigError, match="does not match robot"):
        save_plots(load_robot("go2"), synthetic_log(b1z1), tmp_path)


# ----------------------------------------------------------------------------- replay
def test_replay_is_self_contained_and_matches_pinocchio(b1z1, tmp_path):
    log = synthetic_log(b1z1, duration_s=0.5)
    t, q = np.array(log.t), np.array(log.q)
    ee = frame_positions(b1z1, q, [b1z1.arm_ee])[b1z1.arm_ee]
    path = save_replay(b1z1, t, q, tmp_path / "replay.html", fps=30,
                       extras=[{"name": "EE reference", "positions": ee + [0, 0, 0.05]},
                               ("load", lambda s: np.array([1.0, 0.0, 0.2 + s]))])
    html = path.read_text(encoding="utf-8")
    assert "<canvas" in html and "requestAnimationFrame" in html
    assert not re.search(r"https?://", html), "the replay must not reference external resources"
    assert not re.search(r"<link\b|<script[^>]*\bsrc=|@import|url\(", html)

    data = embedded_json(html)
    direct = json.loads(json.dumps(replay_data(b1z1, t, q, fps=30)))
    assert {k: v for k, v in data.items() if k != "extras"} == {k: v for k, v in direct.items() if k != "extras"}
    expected_frames = round(0.5 * 30)
    assert data["n_frames"] == len(data["frames"]) == len(data["t"]) == expected_frames
    assert data["duration_s"] == pytest.approx(0.5)
    assert [e["name"] for e in data["extras"]] == ["EE reference", "load"]
    assert all(len(e["frames"]) == expected_frames for e in data["extras"])

    model, pdata = b1z1.model, b1z1.model.createData()
    names = data["names"]
    for k in (0, 7, expected_frames - 1):
        sample = int(np.argmin(np.abs(t - data["t"][k])))
        pin.framesForwardKinematics(model, pdata, q[sample])
        points = np.array(data["frames"][k], dtype=float).reshape(-1, 3) / 1e3
        for j in range(1, model.njoints):
            np.testing.assert_allclose(points[names.index(model.names[j])], pdata.oMi[j].translation, atol=1e-3)
        for frame in (*b1z1.feet, b1z1.arm_ee):
            np.testing.assert_allclose(points[names.index(frame)], pdata.oMf[b1z1.frame_id(frame)].translation, atol=1e-3)
        np.testing.assert_allclose(np.array(data["extras"][0]["frames"][k]) / 1e3, ee[sample] + [0, 0, 0.05], atol=1e-3)
        # the base box moves with the base
        corners = points[[i for i, kind in enumerate(data["kinds"]) if kind == "box"]]
        assert np.linalg.norm(corners.mean(axis=0) - pdata.oMi[1].translation) < 0.2
    for i, j, group in data["links"]:
        assert 0 <= i < len(names) and 0 <= j < len(names) and 0 <= group < len(data["groups"])


def test_replay_of_a_long_run_stays_small(tmp_path):
    robot = load_robot("b1_z1")
    t = np.arange(0.0, 20.0, 0.002)
    q = synthetic_q(robot, t)
    path = save_replay(robot, t, q, tmp_path / "long.html", fps=30, extras=[("trail", q[:, :3] + [0, 0, 0.3])])
    data = embedded_json(path.read_text(encoding="utf-8"))
    assert data["n_frames"] == 600
    assert path.stat().st_size < 5e6


def test_replay_of_a_biped(tmp_path):
    robot = bolt()
    t = np.arange(0.0, 0.2, 0.002)
    data = embedded_json(save_replay(robot, t, synthetic_q(robot, t), tmp_path / "bolt.html", fps=50).read_text())
    assert data["n_frames"] == 10 and data["ee"] is None and len(data["feet"]) == 2


def test_replay_rejects_bad_input(b1z1, tmp_path):
    t = np.arange(0.0, 0.1, 0.002)
    q = synthetic_q(b1z1, t)
    with pytest.raises(ConfigError, match="expected"):
        save_replay(b1z1, t, q[:, :-1], tmp_path / "x.html")
    with pytest.raises(ConfigError, match="fps"):
        save_replay(b1z1, t, q, tmp_path / "x.html", fps=0)
    with pytest.raises(ConfigError, match="extra trajectory 'bad'"):
        save_replay(b1z1, t, q, tmp_path / "x.html", extras=[("bad", np.zeros((3, 3)))])


# ----------------------------------------------------------------------------- a real run
@pytest.mark.slow
def test_plots_and_replay_of_a_real_run(tmp_path):
    from wbmpc.control import MPC, MpcConfig
    from wbmpc.control.loop import ClosedLoop, LoopConfig
    from wbmpc.ocp.grid import TimeGrid
    from wbmpc.ocp.problem import OcpConfig
    from wbmpc.sim import make_plant

    robot = load_robot("b1_z1")
    mpc = MPC(robot, MpcConfig(gait="trot", ocp=OcpConfig(grid=TimeGrid(n_intervals=8, dt_first_s=0.01, dt_last_s=0.06))))
    plant = make_plant("mujoco", robot)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    log = ClosedLoop(mpc, plant, LoopConfig()).run(
        0.2, commands=lambda t, q, v: Commands(base_velocity_m_s=np.array([0.2, 0, 0])))
    assert_pngs(save_plots(robot, log, tmp_path), ["base_velocity.png", "ee_position.png", "joint_torques.png",
                                                    "foot_heights.png", "contact_forces.png", "solver.png"])
    arrays = log.arrays()
    data = embedded_json(save_replay(robot, arrays["t"], arrays["q"], tmp_path / "r.html").read_text())
    assert data["n_frames"] == round(0.2 * 30)
