"""The HTML replay in a real headless browser (Debian's chromium; skipped where it is not installed):
the page loads offline, shows the robot, and its animation advances.

By hand: `chromium --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader
--window-size=1200,800 --virtual-time-budget=2500 --screenshot=shot.png file://$PWD/runs/trot-in-place/replay.html`
"""

from __future__ import annotations

import re
import shutil
import subprocess

import matplotlib.image as mpimg
import numpy as np
import pytest

from wbmpc.robots import load_robot
from wbmpc.viz import save_replay

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.slow, pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed "
                                                   "(apt-get install chromium)")]
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=1200,800"]


def browse(page, tmp_path, virtual_ms: int, *what: str) -> subprocess.CompletedProcess:
    profile = tmp_path / f"profile-{virtual_ms}-{len(list(tmp_path.iterdir()))}"
    return subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", f"--virtual-time-budget={virtual_ms}",
                           *what, page.as_uri()], capture_output=True, text=True, timeout=300)


def screenshot(page, tmp_path, virtual_ms: int) -> np.ndarray:
    png = tmp_path / f"{page.stem}-{virtual_ms}.png"
    browse(page, tmp_path, virtual_ms, f"--screenshot={png}")
    assert png.is_file(), f"chromium wrote no screenshot of {page}"
    return mpimg.imread(png)[80:760, :940, :3]  # the 3D view left of meshcat's control panel, below the title


def changed_pixels(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a - b).max(axis=-1) > 0.1).sum())


def test_replay_loads_shows_the_robot_and_plays(tmp_path):
    robot = load_robot("a1")
    t = np.arange(0.0, 2.0, 0.002)
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 0] = 0.2 * t
    q[:, 7:] += 0.4 * np.sin(2 * np.pi * 1.5 * t)[:, None] * (np.arange(robot.nq - 7) % 3 == 1)  # thighs swing
    page = save_replay(robot, t, q, tmp_path / "replay.html", scenario="trot-in-place")
    far = q.copy()
    far[:, 0] += 100.0  # the same page with the robot out of sight
    empty = save_replay(robot, t, far, tmp_path / "empty.html", scenario="trot-in-place")

    dom = browse(page, tmp_path, 1500, "--dump-dom").stdout
    assert "wbmpc replay: trot-in-place (a1)" in dom
    frame = re.search(r'<span id="clock" data-frame="(\d+)">t = ([\d.]+) s', dom)
    assert frame, dom[-2000:]
    assert int(frame.group(1)) > 0 and float(frame.group(2)) > 0  # the animation plays on its own

    early, late, nothing = (screenshot(page, tmp_path, 300), screenshot(page, tmp_path, 1100),
                            screenshot(empty, tmp_path, 300))
    assert changed_pixels(early, nothing) > 3000  # the robot is drawn (its meshes cover thousands of pixels)
    assert changed_pixels(early, late) > 300  # and it moves between two times
