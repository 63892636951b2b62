"""`wbmpc deploy --meshcat`: the controller's estimated state and its MPC plan, live in the browser.

A process of its own (spawned: no GIL shared with deploy's 500 Hz loop, which starved a drawing thread to 11 Hz on
a loaded machine) starts a meshcat server on localhost and draws the robot with pinocchio's `MeshcatVisualizer` and
the replay's meshes (`viz/replay.py`). The deploy loop hands over its newest estimate and plan (`on_tick`): at most
`rate_hz` (25 Hz) of them are queued (dropped when the drawer is busy, never waited for); the drawer sends the
robot's pose and one line-segment object with the plan (base path, foot paths, hand path, the first node's contact
forces). Frames drawn and the rate achieved are reported (`summary()["rate_hz"]`).
"""

from __future__ import annotations

import time

import numpy as np

DEFAULT_RATE_HZ = 25.0
FORCE_M_PER_WEIGHT = 0.3


class LiveMeshcat:
    """The deploy side: a drawing process fed from `on_tick`."""

    def __init__(self, robot, rate_hz: float = DEFAULT_RATE_HZ):
        self.robot, self.rate_hz = robot, rate_hz
        self.url: str | None = None
        self._process = None
        self._queue = None
        self._conn = None
        self._next_send = 0.0
        self._summary: dict | None = None
        self.dropped = 0

    def open(self, timeout_s: float = 120.0) -> str:
        """Start the drawing process and its meshcat server; returns the page's address."""
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        self._queue = context.Queue(maxsize=2)
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_draw, args=(self.robot.spec, self.rate_hz, self._queue, child),
                                        daemon=True)
        self._process.start()
        if not self._conn.poll(timeout_s):
            self.close()
            raise RuntimeError("the live page's process did not start")
        answer = self._conn.recv()
        if isinstance(answer, BaseException):
            self.close()
            raise answer
        self.url = answer
        return self.url

    def on_tick(self, tick) -> None:
        """A deploy tick listener: the newest estimate and plan, queued at most `rate_hz` times a second."""
        now = time.perf_counter()
        if self._queue is None or now < self._next_send:
            return
        self._next_send = now + 1.0 / self.rate_hz
        plan = tick.plan
        item = (np.asarray(tick.q, dtype=float),
                None if plan is None else (np.asarray(plan.q), np.asarray(plan.forces)[0], np.asarray(plan.contact)[0]))
        try:
            self._queue.put_nowait(item)
        except Exception:  # noqa: BLE001  (queue.Full: the drawer is busy; the next tick brings newer data)
            self.dropped += 1

    def summary(self) -> dict:
        out = dict(self._summary or {"frames": 0, "plan_frames": 0, "rate_hz": None})
        out.update(url=self.url, target_rate_hz=self.rate_hz, dropped=self.dropped)
        return out

    def close(self) -> None:
        if self._process is None:
            return
        try:
            self._queue.put(None, timeout=2.0)
            if self._conn.poll(20.0):
                self._summary = self._conn.recv()
        except Exception:  # noqa: BLE001
            pass
        self._process.join(timeout=10.0)
        if self._process.is_alive():
            self._process.terminate()
        self._process = None


def _draw(spec, rate_hz: float, queue, conn) -> None:
    """The drawing process: meshcat server, robot model, then frames from the queue until None."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the deploy's to handle
    import os
    import sys

    sys.stdout.flush()
    os.dup2(2, 1)  # meshcat prints its address on stdout (and so would its server): deploy's --json owns stdout
    try:
        import meshcat
        import meshcat.geometry as mg

        from wbmpc.robots import RobotModel
        from wbmpc.viz.replay import robot_geometry, viewer_class

        robot = RobotModel(spec)
        viewer = meshcat.Visualizer()
        geometry, _ = robot_geometry(robot)
        viz = viewer_class()(robot.model, geometry, geometry)
        viz.initViewer(viewer=viewer)
        viz.loadViewerModel(rootNodeName="robot")
        viz.display(robot.q_nominal)
        conn.send(viewer.url())
    except Exception as exc:  # noqa: BLE001
        conn.send(RuntimeError(f"the live page could not start: {type(exc).__name__}: {exc}"))
        return
    plan_drawer = _PlanSegments(robot)
    frames = plan_frames = 0
    started = None
    try:
        while True:
            item = queue.get()
            if item is None:
                break
            if started is None:
                started = time.perf_counter()
            q, plan = item
            viz.display(q)
            if plan is not None:
                points, colors = plan_drawer(*plan)
                if len(points):
                    viewer["plan"].set_object(mg.LineSegments(mg.PointsGeometry(points.T, color=colors.T),
                                                              mg.LineBasicMaterial(vertexColors=True, linewidth=3)))
                plan_frames += 1
            frames += 1
    finally:
        span = time.perf_counter() - started if started is not None else 0.0
        conn.send({"frames": frames, "plan_frames": plan_frames, "rate_hz": frames / span if span > 0 else None})
        server = getattr(viewer.window, "server_proc", None)
        if server is not None:
            server.terminate()
            try:
                server.wait(timeout=5)
            except Exception:  # noqa: BLE001
                server.kill()


PALETTE = {"base": (0.15, 0.45, 1.0), "foot": (1.0, 0.55, 0.1), "hand": (0.1, 0.85, 0.25), "force": (0.95, 0.1, 0.1)}


class _PlanSegments:
    """A plan -> (2 k, 3) segment endpoints and their colours: base, foot and hand paths, the force arrows."""

    def __init__(self, robot):
        self.robot = robot
        self.feet = [robot.contact_frame(f) for f in robot.feet]
        self.frames = [*self.feet, *([robot.arm_ee] if robot.arm_ee else [])]
        self.scale = FORCE_M_PER_WEIGHT / (robot.mass_kg * 9.81)

    def __call__(self, q: np.ndarray, forces0: np.ndarray, contact0: np.ndarray):
        frames = self.robot.frame_trajectories(q, self.frames)
        paths = [("base", q[:, :3])] + [("foot", frames[f]) for f in self.feet]
        if self.robot.arm_ee:
            paths.append(("hand", frames[self.robot.arm_ee]))
        points, colors = [], []
        for kind, path in paths:
            pairs = np.repeat(path, 2, axis=0)[1:-1]
            points.append(pairs)
            colors += [PALETTE[kind]] * len(pairs)
        n_feet = len(self.feet)
        for foot, force in enumerate(np.asarray(forces0)[: 3 * n_feet].reshape(n_feet, 3)):
            if contact0[foot] > 0.5:
                start = frames[self.feet[foot]][0]
                points.append(np.array([start, start + self.scale * force]))
                colors += [PALETTE["force"]] * 2
        return np.concatenate(points), np.array(colors)
