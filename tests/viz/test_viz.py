"""Plots and the HTML replay, on a small synthetic run log (fast) and, marked slow, on a real run."""

import json
import re

import matplotlib.image as mpimg
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import Commands
from wbmpc.control.run_log import RunLog
from wbmpc.errors import ConfigError
from wbmpc.robots import load_robot
from wbmpc.robots.model import RobotModel
from wbmpc.robots.presets import custom_spec, example_robot_data_dir
from wbmpc.viz import (
    base_velocity_heading,
    frame_positions,
    replay_data,
    save_plots,
    save_replay,
)
from wbmpc.viz.plots import (
    EVENT_COLOR,
    FALL_COLOR,
    HIGHLIGHT_COLOR,
    RECOVERY_COLOR,
    RunMarks,
    base_velocity_figure,
    contact_forces_figure,
    ee_position_figure,
    ee_rmse_m,
    foot_heights_figure,
    joint_torques_figure,
    most_loaded_joints,
    save_figure,
    solver_figure,
)

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


def synthetic_log(robot, duration_s: float = 0.3, control_hz: float = 500.0, mpc_hz: float = 80.0, tau_scale: float = 1.0,
                  status=None, with_steps: bool = True, torque_peaks: dict | None = None) -> RunLog:
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
    solve_ms, iterations = rng.uniform(5, 20, mpc_t.size), rng.integers(3, 12, mpc_t.size)
    tau = tau_scale * tau
    for (row, joint), value in (torque_peaks or {}).items():
        tau[row, joint] = value
    if not with_steps:
        mpc_t = mpc_t[:0]
    return RunLog.from_columns(
        t, q, v, tau, 0.9 * tau, q[:, 7:], forces, mpc_t=mpc_t, solve_ms=solve_ms, iterations=iterations,
        success=[k != 5 for k in range(mpc_t.size)], status=status or ["ok"] * mpc_t.size, planned_contact=planned,
        commands=[Commands(base_velocity_m_s=np.array([0.2, 0.0, 0.0]), base_yaw_rate_rad_s=0.3) for _ in mpc_t],
        chunk_rows=64)  # several spilled chunks: the plots read them back


def bolt():
    """A biped (no arm, feet not named like a quadruped's) from example-robot-data."""
    root = example_robot_data_dir() / "bolt_description"
    spec = custom_spec(str(root / "robots/bolt.urdf"), ["FL_FOOT", "FR_FOOT"], srdf=str(root / "srdf/bolt.srdf"),
                       pose="standing", name="bolt")
    return RobotModel(spec)


def rgb(hex_color: str) -> np.ndarray:
    return np.array([int(hex_color[k:k + 2], 16) for k in (1, 3, 5)]) / 255.0


def color_mask(image: np.ndarray, hex_color: str, tol: float = 0.06, min_share: float = 0.6) -> np.ndarray:
    """Pixels of `image` (rows, cols, 3|4) painted with a colour over white: exactly, or blended by
    antialiasing with at least `min_share` of the colour (within `tol` per channel)."""
    ink = 1.0 - rgb(hex_color)
    paper = 1.0 - image[..., :3]
    share = paper @ ink / max(float(ink @ ink), 1e-12)
    blended = np.all(np.abs(paper - share[..., None] * ink) < tol, axis=-1) & (share > min_share)
    exact = np.all(np.abs(image[..., :3] - rgb(hex_color)) < tol, axis=-1)
    return blended | exact


def assert_pngs(paths, expected_names):
    """Every expected PNG exists, decodes, and shows plotted data: more than a few colours, and
    the first data line colour (matplotlib's C0) covers at least some pixels."""
    assert sorted(p.name for p in paths) == sorted(expected_names)
    for path in paths:
        assert path.read_bytes().startswith(PNG_SIGNATURE), path
        image = mpimg.imread(path)
        assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 500, (path, image.shape)
        packed = np.rint(255 * image[..., :3]).astype(np.uint32) @ np.array([65536, 256, 1], dtype=np.uint32)
        assert np.unique(packed).size > 50, f"{path} is nearly blank"
        assert color_mask(image, "#1f77b4").sum() > 200, f"{path}: no data line drawn"


def pixel_column(fig, ax, image, t: float) -> tuple[int, slice]:
    """Image column of time `t` on `ax` and the rows the axes span (after the figure was saved)."""
    x, _ = ax.transData.transform((t, 0.0))
    bbox = ax.get_window_extent()
    height = image.shape[0]
    return int(round(x)), slice(int(height - bbox.y1) + 3, int(height - bbox.y0) - 3)


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
    log = synthetic_log(robot, with_steps=False)
    paths = save_plots(robot, log, tmp_path)
    assert_pngs(paths, ["base_velocity.png", "joint_torques.png", "foot_heights.png", "contact_forces.png"])


def test_save_plots_rejects_a_log_of_another_robot(b1z1, tmp_path):
    with pytest.raises(ConfigError, match="does not match robot"):
        save_plots(load_robot("go2"), synthetic_log(b1z1), tmp_path)


def marked_log(robot):
    """A synthetic log with a push at 0.1 s, steps 3 and 7 recovered, step 5 failed and a fall at 0.25 s."""
    n_steps = len(np.arange(0.0, 0.3, 1.0 / 80.0))
    log = synthetic_log(robot, status=["Solve_Succeeded (recovery after fatrop: failed)" if k in (3, 7) else "ok"
                                       for k in range(n_steps)])
    log.events = [(0.1, "push")]
    log.fell, log.fell_at_s = True, 0.25
    return log


def saved_image(fig, path):
    save_figure(fig, path)
    return mpimg.imread(path)


def test_event_marks_are_drawn_at_their_times(b1z1, tmp_path):
    log = marked_log(b1z1)
    marks = RunMarks.from_log(log)
    mpc_t = np.array(log.mpc_t)
    assert marks.events == ((0.1, "push"),) and marks.fell_at_s == pytest.approx(0.25)
    np.testing.assert_allclose(marks.recovered_s, mpc_t[[3, 7]])
    np.testing.assert_allclose(marks.failed_s, mpc_t[[5]])

    fig = base_velocity_figure(b1z1, log.arrays(), log, marks)
    image = saved_image(fig, tmp_path / "v.png")
    ax = fig.axes[0]
    push = color_mask(image, EVENT_COLOR)
    col, rows = pixel_column(fig, ax, image, 0.1)
    assert push[rows, col - 1 : col + 2].any(axis=1).mean() > 0.4, "no push line at t = 0.1 s"
    quiet, _ = pixel_column(fig, ax, image, 0.2)
    assert not push[rows, quiet - 2 : quiet + 3].any(), "push colour where no event happened"
    fall = color_mask(image, FALL_COLOR, 0.02)
    col, _ = pixel_column(fig, ax, image, 0.25)
    assert fall[rows, col - 1 : col + 2].any(axis=1).mean() > 0.4, "no fall line at t = 0.25 s"
    top = slice(rows.start, rows.start + (rows.stop - rows.start) // 8)  # markers sit at the top of the axes
    recovery, failed = color_mask(image, RECOVERY_COLOR), color_mask(image, HIGHLIGHT_COLOR)
    for t in mpc_t[[3, 7]]:
        col, _ = pixel_column(fig, ax, image, t)
        assert recovery[top, col - 2 : col + 3].sum() > 5, f"no recovery marker at {t:.4f} s"
    col, _ = pixel_column(fig, ax, image, mpc_t[5])
    assert failed[top, col - 2 : col + 3].sum() > 5, "no failed-step marker"
    col, _ = pixel_column(fig, ax, image, mpc_t[10])
    assert not recovery[top, col - 2 : col + 3].any() and not failed[top, col - 2 : col + 3].any()

    # every time plot of save_plots carries the marks
    for figure in (joint_torques_figure(b1z1, log.arrays(), marks), solver_figure(b1z1, log.arrays(), marks=marks),
                   foot_heights_figure(b1z1, log.arrays(), marks), contact_forces_figure(b1z1, log.arrays(), marks)):
        image = saved_image(figure, tmp_path / "m.png")
        col, rows = pixel_column(figure, figure.axes[0], image, 0.1)
        assert color_mask(image, EVENT_COLOR)[rows, col - 1 : col + 2].any(axis=1).mean() > 0.3


def test_the_highlighted_panel_shows_the_joints_nearest_their_limits(b1z1, tmp_path):
    names = list(b1z1.joint_names)
    front, arm = names.index("FL_hip_joint"), names.index("joint2")
    log = synthetic_log(b1z1, tau_scale=0.3, torque_peaks={(40, front): 0.99 * b1z1.tau_max[front],
                                                            (60, arm): -0.95 * b1z1.tau_max[arm]})
    tau = log.tau
    assert most_loaded_joints(b1z1, tau)[:2] == [front, arm]
    fig = joint_torques_figure(b1z1, log.arrays())
    highlighted = [ax for ax in fig.axes if ax.get_title().startswith("MOST LOADED")]
    assert len(highlighted) == 1 and "99%" in highlighted[0].get_title()
    labels = [line.get_label() for line in highlighted[0].get_lines() if not line.get_label().startswith("_")]
    assert labels[:2] == ["FL_hip (99%)", "joint2 (95%)"] and not any("calf" in label for label in labels)
    image = saved_image(fig, tmp_path / "tau.png")
    bbox = highlighted[0].get_window_extent()
    row = int(image.shape[0] - 0.5 * (bbox.y0 + bbox.y1))
    left = int(round(bbox.x0))
    assert color_mask(image, HIGHLIGHT_COLOR, 0.08)[row, left - 2 : left + 3].any(), "highlighted panel has no red frame"


def test_wipe_plot_rmse_is_the_metric(b1z1):
    from wbmpc.scenarios.base import ScenarioOptions
    from wbmpc.scenarios.wipe import Wipe

    wipe = Wipe(ScenarioOptions())
    t = np.arange(0.0, 3.0, 0.01)
    path = np.array([wipe.path(b1z1, tk)[0] for tk in t])
    normal = wipe.board(b1z1).normal
    ee = path + 0.004 * np.outer(np.sin(7 * t), [0, 1, 0]) + 0.006 * normal  # in-plane wobble, pressed off the plane
    error, use = wipe.ee_tracking_error(b1z1, t, ee)
    late = t >= wipe.PATTERN_START_S
    np.testing.assert_array_equal(use, late)
    expected = np.sqrt(np.mean((0.004 * np.sin(7 * t[late])) ** 2))  # the normal offset does not count
    assert ee_rmse_m(error, use) == pytest.approx(expected, rel=1e-9)

    q = np.tile(b1z1.q_nominal, (t.size, 1))
    fig = ee_position_figure(b1z1, {"t": t, "q": q}, wipe.ee_reference(b1z1),
                             ee_error=lambda tt, e: wipe.ee_tracking_error(b1z1, tt, e), error_label=wipe.ee_error_label)
    measured = b1z1.frame_trajectories(q, [b1z1.arm_ee])[b1z1.arm_ee]
    rmse = ee_rmse_m(*wipe.ee_tracking_error(b1z1, t, measured))
    assert f"RMSE {1e3 * rmse:.1f} mm" in fig.get_suptitle()


# ----------------------------------------------------------------------------- replay
def decoded_commands(data: dict) -> list[dict]:
    """The replay's meshcat commands (base64 msgpack) as dicts."""
    import base64

    import umsgpack

    return [umsgpack.unpackb(base64.b64decode(blob)) for blob in data["commands"]]


def animation_tracks(commands: list[dict]) -> dict[str, dict[str, list]]:
    """node path -> track name (".position", ".quaternion", ".scale") -> values per frame."""
    (animation,) = [c for c in commands if c["type"] == "set_animation"]
    return {a["path"]: {tr["name"]: [k["value"] for k in sorted(tr["keys"], key=lambda k: k["time"])]
                        for tr in a["clip"]["tracks"]} for a in animation["animations"]}


def test_replay_is_self_contained_and_matches_pinocchio(b1z1, tmp_path):
    """Every visual mesh of the robot placed where pinocchio's geometry placements put it, frame by frame."""
    log = synthetic_log(b1z1, duration_s=0.5)
    t, q = np.array(log.t), np.array(log.q)
    ee = frame_positions(b1z1, q, [b1z1.arm_ee])[b1z1.arm_ee]
    extras = [{"name": "EE reference", "positions": ee + [0, 0, 0.05]}, ("load", lambda s: np.array([1.0, 0.0, 0.2 + s]))]
    path = save_replay(b1z1, t, q, tmp_path / "replay.html", fps=30, extras=extras)
    html = path.read_text(encoding="utf-8")
    assert "MeshCat.Viewer" in html and "handle_command_bytearray" in html  # meshcat's own viewer, embedded
    assert set(re.findall(r"https?://[^\s\"')]+", html)) <= {"http://www.w3.org/1999/xhtml"}, "no external resources"
    assert not re.search(r"<link\b|<script[^>]*\bsrc=|@import", html)

    data = replay_data(b1z1, t, q, fps=30, extras=extras)
    meta = embedded_json(html)
    assert meta == {k: v for k, v in data.items() if k != "commands"}
    expected_frames = round(0.5 * 30)
    assert data["n_frames"] == len(data["t"]) == expected_frames and data["duration_s"] == pytest.approx(0.5)
    assert data["geometry"] == "visual meshes" and 0 < data["triangles"] < 300_000

    commands = decoded_commands(data)
    meshes = {c["path"] for c in commands if c["type"] == "set_object"}
    tracks = animation_tracks(commands)
    from wbmpc.viz.replay import robot_geometry

    geometry, _ = robot_geometry(b1z1)
    gdata = geometry.createData()
    model, pdata = b1z1.model, b1z1.model.createData()
    assert len(data["nodes"]) == geometry.ngeoms >= 20
    for k in (0, 7, expected_frames - 1):
        sample = int(np.argmin(np.abs(t - data["t"][k])))
        pin.updateGeometryPlacements(model, pdata, geometry, gdata, q[sample])
        for g, node in enumerate(data["nodes"]):
            path_name = f"/meshcat/{node}"
            assert path_name in meshes
            placement = gdata.oMg[g]
            np.testing.assert_allclose(tracks[path_name][".position"][k], placement.translation, atol=1e-6)
            x, y, z, w = tracks[path_name][".quaternion"][k]
            np.testing.assert_allclose(pin.Quaternion(w, x, y, z).toRotationMatrix(), placement.rotation, atol=1e-6)
        extra = tracks["/meshcat/wbmpc/extras/0"][".position"][k]
        np.testing.assert_allclose(extra, ee[sample] + [0, 0, 0.05], atol=1e-6)
    # the trunk of the B1 is a real mesh (Collada from example-robot-data), decimated, not a box
    trunk = next(c for c in commands if c["type"] == "set_object" and c["path"].endswith("/trunk_0"))
    assert trunk["object"]["geometries"][0]["type"] == "BufferGeometry"


def test_replay_draws_the_scene_objects_and_names_the_scenario(b1z1, tmp_path):
    """Load and cable, box and wall, a table: recorded in MuJoCo for 50 ms, then drawn in the replay
    where MuJoCo had them at each frame's time."""
    from wbmpc.sim.mujoco_plant import MujocoPlant
    from wbmpc.sim.objects import Board, BoxAtWall, CableLoad, Scene

    table = Board(orientation="horizontal", face_m=(0.9, 0.0, 0.5), size_m=(0.4, 0.6))
    scene = Scene(b1z1, [CableLoad(mass_kg=5.0, position_m=(-1.5, 0.0), cable_length_m=1.0),
                         BoxAtWall(near_face_x_m=1.4), table])
    plant = MujocoPlant(b1z1, scene.plant_config())
    scene.attach(plant)
    plant.reset(b1z1.q_nominal, np.zeros(b1z1.nv))
    t, q = [plant.time_s], [plant.state()[0]]
    for _ in range(50):
        plant.step(np.zeros(b1z1.n_joints))
        t.append(plant.time_s)
        q.append(plant.state()[0])
    objects = scene.replay_objects()
    html = save_replay(b1z1, np.array(t), np.array(q), tmp_path / "scene.html", fps=100,
                       objects=objects, scenario="pull").read_text()
    assert "<title>wbmpc replay: pull (b1_z1)</title>" in html
    data = replay_data(b1z1, np.array(t), np.array(q), fps=100, objects=objects, scenario="pull")
    assert embedded_json(html)["scenario"] == "pull"
    names = data["objects"]
    assert set(names) == {"load", "load cable", "box", "box wall", "board", "board stand"}
    commands = decoded_commands(data)
    tracks = animation_tracks(commands)
    node = {name: f"/meshcat/wbmpc/objects/{k}" for k, name in enumerate(names)}
    shapes = {c["path"]: c["object"]["geometries"][0] for c in commands if c["type"] == "set_object"}
    static = {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in commands if c["type"] == "set_transform"}
    n = data["n_frames"]
    assert all(len(tracks[node[k]][".position"]) == n for k in ("load", "load cable", "box"))
    assert node["board"] not in tracks  # static
    board = shapes[node["board"]]
    assert (board["type"], board["width"], board["height"], board["depth"]) == ("BoxGeometry", 0.4, 0.6, 0.04)
    # the table top's upper face is at the configured height
    assert static[node["board"]][2, 3] + 0.02 == pytest.approx(0.5 - table.contact_margin_m, abs=1e-3)
    rec_t, load_position = scene.recording.series("load", "object_position_m")
    _, cable = scene.recording.series("load", "cable_m")
    for k in (0, n // 2, n - 1):
        i = int(np.argmin(np.abs(rec_t - data["t"][k])))
        np.testing.assert_allclose(tracks[node["load"]][".position"][k], load_position[i], atol=1e-6)
        # the cable: a unit cylinder at the segment's middle, stretched to its length
        np.testing.assert_allclose(tracks[node["load cable"]][".position"][k], cable[i].mean(axis=0), atol=1e-6)
        length = np.linalg.norm(cable[i][1] - cable[i][0])
        assert tracks[node["load cable"]][".scale"][k][1] == pytest.approx(length, rel=1e-6)
    box = shapes[node["box"]]
    np.testing.assert_allclose([box["width"], box["height"], box["depth"]], [0.3, 0.5, 1.0])


def test_replay_of_a_long_run_stays_small(tmp_path):
    """20 s at the full 30 fps; 10 min with fewer frames per second, under 20 MB."""
    from wbmpc.viz.replay import MAX_NODE_FRAMES

    robot = load_robot("b1_z1")
    t = np.arange(0.0, 20.0, 0.002)
    q = synthetic_q(robot, t)
    path = save_replay(robot, t, q, tmp_path / "long.html", fps=30, extras=[("trail", q[:, :3] + [0, 0, 0.3])])
    data = embedded_json(path.read_text(encoding="utf-8"))
    assert data["n_frames"] == 600 and data["fps"] == 30
    assert path.stat().st_size < 8e6  # meshes ~3 MB (decimated), ~0.1 MB of animation per second
    t = np.arange(0.0, 600.0, 0.05)
    path = save_replay(robot, t, synthetic_q(robot, t), tmp_path / "ten_minutes.html", fps=30)
    data = embedded_json(path.read_text(encoding="utf-8"))
    assert data["n_frames"] * len(data["nodes"]) <= MAX_NODE_FRAMES and 2 < data["fps"] < 30
    assert data["t"][-1] > 599 and path.stat().st_size < 20e6


def test_replay_of_a_biped(tmp_path):
    robot = bolt()
    t = np.arange(0.0, 0.2, 0.002)
    data = embedded_json(save_replay(robot, t, synthetic_q(robot, t), tmp_path / "bolt.html", fps=50).read_text())
    assert data["n_frames"] == 10 and data["geometry"] == "visual meshes" and len(data["nodes"]) >= 5


def test_replay_without_meshes_falls_back_to_primitives_and_says_so(tmp_path, go2_without_meshes):
    robot = go2_without_meshes
    t = np.arange(0.0, 0.1, 0.002)
    with pytest.warns(UserWarning, match="primitive shapes"):
        path = save_replay(robot, t, synthetic_q(robot, t), tmp_path / "go2.html", fps=30)
    data = embedded_json(path.read_text())
    assert data["geometry"] == "primitive shapes" and data["triangles"] == 0 and len(data["nodes"]) >= 5
    assert "meshes missing" in path.read_text()


@pytest.fixture
def go2_without_meshes(tmp_path):
    """go2's URDF copied where its package:// meshes cannot be found."""
    import dataclasses
    import shutil

    from wbmpc.robots.presets import preset_spec

    spec = preset_spec("go2")
    urdf = tmp_path / "alone" / "go2.urdf"
    urdf.parent.mkdir()
    shutil.copy(spec.urdf, urdf)
    return RobotModel(dataclasses.replace(spec, urdf=urdf))


def test_replay_rejects_bad_input(b1z1, tmp_path):
    t = np.arange(0.0, 0.1, 0.002)
    q = synthetic_q(b1z1, t)
    with pytest.raises(ConfigError, match="expected"):
        save_replay(b1z1, t, q[:, :-1], tmp_path / "x.html")
    with pytest.raises(ConfigError, match="fps"):
        save_replay(b1z1, t, q, tmp_path / "x.html", fps=0)
    with pytest.raises(ConfigError, match="extra trajectory 'bad'"):
        save_replay(b1z1, t, q, tmp_path / "x.html", extras=[("bad", np.zeros((3, 3)))])
    with pytest.raises(ConfigError, match="the replay draws 'box' and 'line'"):
        save_replay(b1z1, t, q, tmp_path / "x.html", objects=[{"name": "cone", "kind": "cone"}])


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
