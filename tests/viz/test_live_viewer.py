"""The live viewer under a virtual display (Xvfb): it opens, draws the robot and the plan, turns a mouse
perturbation into a force on the plant and an event, and closes cleanly. Skipped without Xvfb
(`apt-get install -y xvfb`)."""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (apt-get install -y xvfb)")

SRC = str(Path(__file__).resolve().parents[2] / "src")


@pytest.fixture(scope="module")
def display(tmp_path_factory):
    """A virtual display whose screen Xvfb keeps in a file (`-fbdir`, XWD format) that the tests read back."""
    number = 90 + os.getpid() % 400
    screen_dir = tmp_path_factory.mktemp("xvfb")
    server = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", "1024x768x24", "-nolisten", "tcp",
                               "-fbdir", str(screen_dir)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while not os.path.exists(f"/tmp/.X11-unix/X{number}") and time.monotonic() < deadline:
        time.sleep(0.1)
    saved = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{number}"
    yield Display(f":{number}", screen_dir / "Xvfb_screen0")
    import glfw  # MuJoCo's viewer leaves GLFW's connection open (closed at exit): gone with the server, Xlib exits 1

    glfw.terminate()
    if saved is None:
        os.environ.pop("DISPLAY", None)
    else:
        os.environ["DISPLAY"] = saved
    server.terminate()
    server.wait(timeout=10)


class Display(str):
    """The display's name, with the file holding its screen."""

    def __new__(cls, name: str, screen_file: Path):
        display = super().__new__(cls, name)
        display.screen_file = screen_file
        return display


def _screenshot_pixels(display: Display) -> np.ndarray:
    """(height, width, 3) RGB of the virtual screen, read from Xvfb's XWD frame buffer file: a header of 25
    big-endian 32-bit fields (its size, ..., width, height, ..., byte order, ..., bits per pixel, bytes per line,
    ..., colour map entries), the window name, the colour map (12 bytes an entry), then the pixels."""
    data = display.screen_file.read_bytes()
    header = np.frombuffer(data[:100], dtype=">u4")
    size, width, height, byte_order = int(header[0]), int(header[4]), int(header[5]), int(header[7])
    bits_per_pixel, bytes_per_line, colours = int(header[11]), int(header[12]), int(header[19])
    assert bits_per_pixel == 32, bits_per_pixel  # a 24-bit screen keeps 4 bytes a pixel
    start = size + 12 * colours
    rows = np.frombuffer(data[start : start + height * bytes_per_line], dtype=np.uint8).reshape(height, bytes_per_line)
    pixels = rows[:, : 4 * width].reshape(height, width, 4)
    return (pixels[..., 2::-1] if byte_order == 0 else pixels[..., 1:]).astype(int)  # LSB first: B G R x


def test_viewer_opens_draws_the_plan_logs_a_push_and_closes(display, forward_plan):
    import mujoco

    from wbmpc.robots import load_robot
    from wbmpc.sim import make_plant
    from wbmpc.viz.live_viewer import LiveViewer, check_display

    check_display()
    robot = load_robot("a1")
    plant = make_plant("mujoco", robot)
    plant.reset(robot.q_nominal)
    viewer = LiveViewer(robot, plant, session=None, sync_period_s=0.0)
    plant.add_step_hook(viewer)
    viewer.open()
    try:
        viewer.on_plan(0.0, forward_plan(robot))
        for _ in range(20):
            plant.step(np.zeros(robot.n_joints))
        assert viewer.is_running() and viewer.syncs >= 20 and viewer.plans_drawn == 1
        # 7 base segments, 4 x 7 foot segments, 4 force arrows
        assert viewer.geoms_drawn == 7 + 4 * 7 + 4
        counts = None
        for _ in range(10):  # the render thread draws the synced scene (slowly on a loaded machine)
            time.sleep(1.0)
            viewer.sync()
            pixels = _screenshot_pixels(display)
            red = (pixels[..., 0] > 200) & (pixels[..., 1] < 80) & (pixels[..., 2] < 80)
            blue = (pixels[..., 2] > 200) & (pixels[..., 0] < 120) & (pixels[..., 1] < 170)
            bright = pixels.sum(axis=-1) > 450  # the trunk's lit top (the floor's tiles stay below)
            counts = (red.sum(), blue.sum(), bright.sum())
            if counts[0] > 30 and counts[1] > 30 and counts[2] > 500:  # the forces, the base path, the robot
                break
        assert counts[0] > 30 and counts[1] > 30 and counts[2] > 500, counts
        # the mouse's perturbation as the GUI sets it (Ctrl + right drag on the trunk): a force on the next steps
        trunk = 1  # the floating base
        base_name = mujoco.mj_id2name(plant.model, mujoco.mjtObj.mjOBJ_BODY, trunk)
        with viewer.handle.lock():
            pert = viewer.handle.perturb
            pert.select = trunk
            pert.localpos = np.zeros(3)  # as mjv_initPerturb leaves it for a click on the body's origin
            pert.localmass = float(plant.model.body_subtreemass[trunk])
            pert.scale = 1.0
            pert.refselpos = plant.data.xpos[trunk] + np.array([0.0, 0.3, 0.0])  # dragged 30 cm to the left
            pert.active = int(mujoco.mjtPertBit.mjPERT_TRANSLATE)
        for _ in range(10):
            plant.step(np.zeros(robot.n_joints))
        assert np.linalg.norm(plant.data.xfrc_applied[trunk, :3]) > 1.0  # the viewer's sync applied the push
        with viewer.handle.lock():
            viewer.handle.perturb.active = 0
        for _ in range(5):
            plant.step(np.zeros(robot.n_joints))
        assert len(viewer.events) == 1 and viewer.events[0][1].startswith(f"mouse push on {base_name}")
    finally:
        viewer.close()
    deadline = time.monotonic() + 10
    while viewer.handle.is_running() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not viewer.handle.is_running()


def test_run_with_the_viewer_opens_draws_and_closes(display, tmp_path):
    env = {**os.environ, "PYTHONPATH": SRC, "MPLBACKEND": "Agg", "DISPLAY": display}
    result = subprocess.run([sys.executable, "-m", "wbmpc", "run", "stand", "--robot", "a1", "--nodes", "4",
                             "--duration", "0.5", "--viewer", "--json", "--no-outputs", "--out", str(tmp_path / "run")],
                            env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    import json

    viewer = json.loads(result.stdout)["operator"]["viewer"]
    assert viewer["syncs"] > 1 and viewer["plans_drawn"] > 1 and viewer["geoms_last_sync"] > 0


def test_dragging_the_hand_target_in_the_viewer_sets_the_hand_command(display):
    """b1_z1 in the viewer: the green target sphere dragged 10 cm forward (the GUI's perturbation of a mocap body)
    becomes a hand offset of 10 cm posted by the "viewer" source."""
    import mujoco

    from wbmpc.operator.command import OperatorCommand, OperatorLimits
    from wbmpc.operator.config import OperatorConfig
    from wbmpc.operator.run import OperatorRun
    from wbmpc.operator.session import OperatorSession
    from wbmpc.robots import load_robot
    from wbmpc.scenarios import ScenarioOptions, make_scenario
    from wbmpc.sim import make_plant
    from wbmpc.viz.live_viewer import HAND_TARGET_BODY, LiveViewer

    robot = load_robot("b1_z1")
    scenario = make_scenario("stand", robot, ScenarioOptions())
    run = OperatorRun(robot, OperatorConfig(viewer=True), scenario, [])
    plant = make_plant("mujoco", robot, run.plant_config(None))
    plant.reset(robot.q_nominal)
    session = OperatorSession(robot, OperatorLimits.for_robot(robot), [], OperatorCommand())
    viewer = LiveViewer(robot, plant, session, sync_period_s=0.0)
    plant.add_step_hook(viewer)
    viewer.open()
    try:
        target = mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_BODY, HAND_TARGET_BODY)
        for _ in range(3):
            plant.step(np.zeros(robot.n_joints))
        home = np.array(plant.data.mocap_pos[plant.model.body_mocapid[target]])
        hand = robot.frame_trajectories(robot.q_nominal[None, :], [robot.arm_ee])[robot.arm_ee][0]
        assert np.linalg.norm(home - hand) < 0.02  # the sphere sits on the hand's standing place
        with viewer.handle.lock():
            pert = viewer.handle.perturb
            pert.select = target
            pert.refpos = home + np.array([0.1, 0.0, 0.0])
            pert.refquat = np.array([1.0, 0.0, 0.0, 0.0])
            pert.active = int(mujoco.mjtPertBit.mjPERT_TRANSLATE)
        for _ in range(3):
            plant.step(np.zeros(robot.n_joints))
        posted = session.board.latest()
        assert posted.source == "viewer" and posted.command.hand_offset_m[0] == pytest.approx(0.1, abs=0.02)
        assert viewer.events == []  # dragging the target is not a push on the robot
    finally:
        viewer.close()
