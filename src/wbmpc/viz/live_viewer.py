"""`wbmpc run ... --viewer`: the run live in MuJoCo's own viewer, with the MPC's plan drawn and mouse pushes.

MuJoCo's passive viewer (`mujoco.viewer.launch_passive`) shows the plant's model and data; this module is a
plant step hook that syncs it with the simulation about 30 times per wall second and draws the newest plan
into the viewer's `user_scn` before each sync: the predicted base path (blue), foot paths (orange), hand path
(green) and the first node's planned contact forces as arrows (red, the robot's weight = 0.3 m), with the
operator's command as a label at the plan's start. MuJoCo's mouse perturbation (double-click a body, Ctrl + right-drag pushes it,
Ctrl + left-drag twists it) reaches the plant through `sync` as `xfrc_applied`; each push is logged as an event
("mouse push on trunk, 85 N peak, 0.6 s") that the plots mark. A robot with an arm gets a green target sphere
(a mocap body without collisions): dragging it sets the hand's target, as the other sources do.
"""

from __future__ import annotations

import os
import sys
import threading
import time

import mujoco
import numpy as np

from wbmpc.errors import ConfigError

SYNC_PERIOD_S = 1 / 30  # wall time between viewer syncs
HAND_TARGET_BODY = "wbmpc_hand_target"
FORCE_ARROW_M_PER_WEIGHT = 0.3
DRAG_THRESHOLD_M = 0.005
NO_DISPLAY = ("--viewer opens MuJoCo's viewer window, but there is no display{why}: leave --viewer out and open "
              "the run's replay afterwards (OUT/replay.html, written by every run), or give it a display (e.g. "
              "xvfb-run -a wbmpc run ... --viewer)")


def check_display() -> None:
    """ConfigError (exit 2) unless a window can be opened: a display, and GLFW able to reach it."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ConfigError(NO_DISPLAY.format(why=" (DISPLAY is not set)"))
    backend = os.environ.get("MUJOCO_GL", "").lower()
    if backend in ("egl", "osmesa"):
        raise ConfigError(NO_DISPLAY.format(why=f" for it (MUJOCO_GL={backend} selects headless rendering; unset it)"))
    try:
        import glfw
    except ImportError:
        raise ConfigError(NO_DISPLAY.format(why=" (the glfw package that MuJoCo's viewer needs is missing: pip "
                                            "install glfw)")) from None
    if not glfw.init():
        raise ConfigError(NO_DISPLAY.format(why=f" that GLFW can open (DISPLAY={os.environ.get('DISPLAY')!r})"))


def hand_target_mjcf(position) -> str:
    """The draggable hand target: a mocap body with a translucent sphere that collides with nothing."""
    x, y, z = (float(c) for c in position)
    return (f'<body name="{HAND_TARGET_BODY}" mocap="true" pos="{x:.4f} {y:.4f} {z:.4f}">'
            '<geom type="sphere" size="0.035" rgba="0.1 0.9 0.2 0.45" contype="0" conaffinity="0" mass="0.001"/>'
            '</body>')


class LiveViewer:
    """Plant step hook + plan listener (`on_plan`) around MuJoCo's passive viewer."""

    def __init__(self, robot, plant, session=None, sync_period_s: float = SYNC_PERIOD_S):
        self.robot, self.plant, self.session = robot, plant, session
        self.model, self.data = plant.model, plant.data
        self.sync_period_s = sync_period_s
        self.handle = None
        self.plan = None
        self.events: list[tuple[float, str]] = []  # (simulated s, text) of each mouse push
        self.syncs = 0
        self.geoms_drawn = 0  # in the last sync
        self.plans_drawn = 0
        self._last_sync = -np.inf
        self._push = None  # (start time, body name, peak force) of the push in progress
        self._feet = [robot.contact_frame(f) for f in robot.feet]
        self._frames = [*self._feet, *([robot.arm_ee] if robot.arm_ee else [])]
        self._weight_n = robot.mass_kg * 9.81
        self._target_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, HAND_TARGET_BODY)
        self._target_shown: np.ndarray | None = None
        self._plan_points: dict | None = None
        self._closed = False

    # ------------------------------------------------------------------ life cycle
    def open(self) -> None:
        import mujoco.viewer

        try:
            self.handle = mujoco.viewer.launch_passive(self.model, self.data, show_left_ui=False, show_right_ui=False)
        except Exception as exc:  # noqa: BLE001  (GLFW could not make its window)
            raise ConfigError(NO_DISPLAY.format(why=f" ({type(exc).__name__}: {exc})")) from None
        with self.handle.lock():
            self.handle.cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
            self.handle.cam.trackbodyid = 1  # the floating base, first body after the world
            self.handle.cam.distance = 4.0 * float(self.robot.q_nominal[2]) + 1.0
            self.handle.cam.elevation = -20.0
            self.handle.cam.azimuth = 135.0
        self.sync()

    def is_running(self) -> bool:
        return self.handle is None or self.handle.is_running()

    def close(self) -> None:
        """Close the window and wait for the viewer's thread to end: if the process exits while it still renders,
        GLFW's exit handler destroys the window under it (GLXBadDrawable) and Xlib's error exit hangs the process."""
        if self.handle is not None and not self._closed:
            self._end_push(self.data.time)
            self._closed = True
            self.handle.close()
            for thread in threading.enumerate():
                if thread.name.endswith("(_launch_internal)"):
                    thread.join(timeout=10.0)

    # ------------------------------------------------------------------ hooks
    def on_plan(self, t: float, solution) -> None:
        if solution.success or getattr(solution, "held_previous", False):
            self.plan = solution
            self._plan_points = None

    def before_step(self, plant) -> None:
        pass

    def after_step(self, plant) -> None:
        now = time.perf_counter()
        if now - self._last_sync >= self.sync_period_s:
            self.sync()

    # ------------------------------------------------------------------ drawing and syncing
    def sync(self) -> None:
        """Now: the plan drawn, the scene handed to the window, the GUI's perturbation and a dragged hand target read
        (the plant's steps call it every `sync_period_s`)."""
        handle = self.handle
        if handle is None or not handle.is_running():
            return
        self._last_sync = time.perf_counter()
        with handle.lock():
            self._show_hand_target()
            self._draw(handle.user_scn)
        handle.sync()  # the GUI's perturbation -> xfrc_applied (and a dragged mocap body) for the next steps
        self.syncs += 1
        self._watch_push()
        self._read_hand_target()

    def _points(self) -> dict | None:
        plan = self.plan
        if plan is None:
            return None
        if self._plan_points is None:
            frames = self.robot.frame_trajectories(plan.q, self._frames)
            n_feet = len(self._feet)
            forces = np.asarray(plan.forces)[0, : 3 * n_feet].reshape(n_feet, 3)
            self._plan_points = {"base": np.asarray(plan.q)[:, :3], "feet": [frames[f] for f in self._feet],
                                 "hand": frames[self.robot.arm_ee] if self.robot.arm_ee else None,
                                 "forces": forces, "contact": np.asarray(plan.contact)[0] > 0.5}
            self.plans_drawn += 1
        return self._plan_points

    def _draw(self, scene) -> None:
        scene.ngeom = 0
        points = self._points()
        if points is None:
            return
        width = 0.006 * max(float(self.robot.q_nominal[2]) / 0.5, 0.5)
        _polyline(scene, points["base"], (0.15, 0.45, 1.0, 1.0), width)
        if scene.ngeom and self.session is not None:  # the operator's command, written at the plan's start
            text = f"{self.data.time:.1f} s: {self.session.board.latest().command.describe()}"
            scene.geoms[0].label = text[:99]
        for path in points["feet"]:
            _polyline(scene, path, (1.0, 0.55, 0.1, 1.0), 0.7 * width)
        if points["hand"] is not None:
            _polyline(scene, points["hand"], (0.1, 0.85, 0.25, 1.0), 0.7 * width)
        scale = FORCE_ARROW_M_PER_WEIGHT / self._weight_n
        for foot, (force, stance) in enumerate(zip(points["forces"], points["contact"])):
            if stance and np.linalg.norm(force) > 1e-3 * self._weight_n:
                start = points["feet"][foot][0]
                _connector(scene, mujoco.mjtGeom.mjGEOM_ARROW, start, start + scale * force, (0.95, 0.1, 0.1, 1.0),
                           2.0 * width)
        self.geoms_drawn = scene.ngeom

    # ------------------------------------------------------------------ mouse
    def _watch_push(self) -> None:
        """A push in progress (the GUI's perturbation on a body other than the hand target) and its end."""
        pert = self.handle.perturb
        body = int(pert.select)
        active = bool(pert.active) and body > 0 and body != self._target_id
        t = float(self.data.time)
        if active:
            force = float(np.linalg.norm(self.data.xfrc_applied[body, :3]))
            if self._push is None:
                name = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY, body) or f"body {body}"
                self._push = [t, name, force]
            else:
                self._push[2] = max(self._push[2], force)
        elif self._push is not None:
            self._end_push(t)

    def _end_push(self, t: float) -> None:
        if self._push is None:
            return
        start, name, peak = self._push
        self.events.append((start, f"mouse push on {name}, {peak:.0f} N peak, {t - start:.1f} s"))
        self._push = None

    def _show_hand_target(self) -> None:
        """Place the target sphere where the hand is asked to be (or its standing place), unless it is dragged."""
        if self._target_id < 0 or self.session is None:
            return
        if bool(self.handle.perturb.active) and int(self.handle.perturb.select) == self._target_id:
            return
        q, _ = self.plant.state()
        shaper = self.session.shaper
        target = shaper.hand_target_world(q)
        if target is None:
            return
        mocap = self.model.body_mocapid[self._target_id]
        self.data.mocap_pos[mocap] = target
        self._target_shown = target.copy()

    def _read_hand_target(self) -> None:
        """A dragged target sphere becomes the hand's target (a post from the "viewer" source)."""
        if self._target_id < 0 or self.session is None or self._target_shown is None:
            return
        mocap = self.model.body_mocapid[self._target_id]
        where = np.array(self.data.mocap_pos[mocap])
        if np.linalg.norm(where - self._target_shown) < DRAG_THRESHOLD_M:
            return
        q, _ = self.plant.state()
        shaper = self.session.shaper
        from wbmpc.operator.shaper import heading_rotation

        heading = heading_rotation(q)
        offset = heading.T @ (where - q[:3]) - shaper.hand_home_m
        board = self.session.board
        board.post("viewer", {"hand": offset}, note="viewer: hand target dragged")
        self._target_shown = where

    def summary(self) -> dict:
        return {"syncs": self.syncs, "plans_drawn": self.plans_drawn, "geoms_last_sync": self.geoms_drawn,
                "pushes": len(self.events)}


def _connector(scene, kind, start, end, rgba, width: float) -> None:
    if scene.ngeom >= scene.maxgeom or np.linalg.norm(np.subtract(end, start)) < 1e-6:
        return
    geom = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(geom, kind, np.zeros(3), np.zeros(3), np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
    mujoco.mjv_connector(geom, kind, width, np.asarray(start, dtype=float), np.asarray(end, dtype=float))
    geom.emission = 0.6  # the plan stands out from the shaded robot
    scene.ngeom += 1


def _polyline(scene, points: np.ndarray, rgba, width: float) -> None:
    for a, b in zip(points[:-1], points[1:]):
        _connector(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, a, b, rgba, width)
