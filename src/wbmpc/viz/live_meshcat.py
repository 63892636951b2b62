"""`wbmpc deploy --meshcat`: the controller's estimated state and its MPC plan, live in the browser.

A meshcat server (started here, `meshcat.Visualizer()`, on localhost) serves the page; pinocchio's
`MeshcatVisualizer` draws the robot with the meshes of the replay (`viz/replay.py`). The deploy loop only hands
over its newest estimate and plan (`on_tick`, a reference swap per tick); a thread of its own sends them at
`rate_hz` (25 Hz): the robot's pose and one line-segment object holding the plan (base path, foot paths, hand
path and the first node's contact forces). Frames sent and the rate achieved are reported
(`summary()["rate_hz"]`), so a page that lags the robot shows in the deploy report.
"""

from __future__ import annotations

import threading
import time

import numpy as np

DEFAULT_RATE_HZ = 25.0
FORCE_M_PER_WEIGHT = 0.3


class LiveMeshcat:
    def __init__(self, robot, rate_hz: float = DEFAULT_RATE_HZ, zmq_url: str | None = None):
        self.robot = robot
        self.rate_hz = rate_hz
        self._zmq_url = zmq_url
        self._latest = None  # (q, plan)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.frames = 0
        self.plan_frames = 0
        self._started_at: float | None = None
        self._ended_at: float | None = None
        self.url: str | None = None
        self._viewer = None
        self._viz = None
        self._feet = [robot.contact_frame(f) for f in robot.feet]
        self._frames = [*self._feet, *([robot.arm_ee] if robot.arm_ee else [])]
        self._weight_n = robot.mass_kg * 9.81

    def open(self) -> str:
        """Start the server and load the robot; returns the page's address."""
        import meshcat

        from wbmpc.viz.replay import _viewer_class, robot_geometry

        self._viewer = meshcat.Visualizer(zmq_url=self._zmq_url) if self._zmq_url else meshcat.Visualizer()
        geometry, _ = robot_geometry(self.robot)
        self._viz = _viewer_class()(self.robot.model, geometry, geometry)
        self._viz.initViewer(viewer=self._viewer)
        self._viz.loadViewerModel(rootNodeName="robot")
        self._viz.display(self.robot.q_nominal)
        self.url = self._viewer.url()
        self._thread = threading.Thread(target=self._serve, name="wbmpc-meshcat", daemon=True)
        self._thread.start()
        return self.url

    def on_tick(self, tick) -> None:
        """A deploy tick listener: keep the newest estimate and plan (the sending thread picks them up)."""
        self._latest = (tick.q, tick.plan)

    def _serve(self) -> None:
        import meshcat.geometry as mg

        period = 1.0 / self.rate_hz
        last_plan = None
        next_frame = time.perf_counter()
        while not self._stop.is_set():
            latest = self._latest
            if latest is not None:
                if self._started_at is None:  # the rate counts from the first state the robot sent
                    self._started_at = next_frame = time.perf_counter()
                q, plan = latest
                self._viz.display(q)
                if plan is not None and plan is not last_plan:
                    segments = self._plan_segments(plan)
                    if segments.size:
                        self._viewer["plan"].set_object(mg.LineSegments(
                            mg.PointsGeometry(segments.T, color=self._colors(len(segments))),
                            mg.LineBasicMaterial(vertexColors=True, linewidth=3)))
                    last_plan = plan
                    self.plan_frames += 1
                self.frames += 1
            next_frame += period
            wait = next_frame - time.perf_counter()
            if wait > 0:
                self._stop.wait(wait)
            else:
                next_frame = time.perf_counter()  # late: no catching up
        self._ended_at = time.perf_counter()

    def _plan_segments(self, plan) -> np.ndarray:
        """(2 k, 3) endpoints of the plan's line segments: base, feet and hand paths, then the force arrows."""
        q = np.asarray(plan.q)
        frames = self.robot.frame_trajectories(q, self._frames)
        paths = [q[:, :3], *(frames[f] for f in self._frames)]
        points = [np.repeat(path, 2, axis=0)[1:-1] for path in paths]  # consecutive pairs
        n_feet = len(self._feet)
        forces = np.asarray(plan.forces)[0, : 3 * n_feet].reshape(n_feet, 3)
        stance = np.asarray(plan.contact)[0] > 0.5
        scale = FORCE_M_PER_WEIGHT / self._weight_n
        for foot, force in enumerate(forces):
            if stance[foot]:
                start = frames[self._feet[foot]][0]
                points.append(np.array([start, start + scale * force]))
        self._kinds = [len(p) for p in points]
        return np.concatenate(points) if points else np.zeros((0, 3))

    def _colors(self, n: int) -> np.ndarray:
        """Per vertex: the base path blue, feet orange, hand green, forces red (as the MuJoCo viewer)."""
        palette = {"base": (0.15, 0.45, 1.0), "foot": (1.0, 0.55, 0.1), "hand": (0.1, 0.85, 0.25), "force": (0.95, 0.1, 0.1)}
        n_paths = 1 + len(self._frames)
        names = ["base"] + ["foot"] * len(self._feet) + (["hand"] if self.robot.arm_ee else [])
        colors = []
        for k, count in enumerate(self._kinds):
            colors += [palette[names[k] if k < n_paths else "force"]] * count
        return np.array(colors[:n]).T

    def summary(self) -> dict:
        end = self._ended_at or time.perf_counter()
        span = end - self._started_at if self._started_at is not None else 0.0
        return {"url": self.url, "frames": self.frames, "plan_frames": self.plan_frames,
                "rate_hz": self.frames / span if span > 0 else None, "target_rate_hz": self.rate_hz}

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        window = getattr(self._viewer, "window", None)
        server = getattr(window, "server_proc", None)
        if server is not None:
            server.terminate()
            try:
                server.wait(timeout=5)
            except Exception:  # noqa: BLE001
                server.kill()
