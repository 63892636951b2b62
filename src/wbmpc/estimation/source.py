"""`EstimatedState`: where the closed loop reads its state when `--state estimated`.

It samples the plant's sensors, runs the estimator at most once per simulated instant (the loop
measures at every control tick and again for each MPC solve) and keeps a log of estimate and
truth for the metrics and the plot.
"""

from __future__ import annotations

import numpy as np

from wbmpc.chunked_table import DEFAULT_CHUNK_ROWS, ChunkedTable
from wbmpc.estimation.estimator import EstimatorConfig, StateEstimator
from wbmpc.estimation.sensors import SensorConfig, Sensors
from wbmpc.gait import Gait


class EstimationLog:
    """Estimate and truth (pinocchio layout) at every estimator update, in bounded memory: rows go to
    a `ChunkedTable` (full chunks spilled to disk) and `arrays()` reads the whole run back."""

    KEYS = ("t", "q_est", "v_est", "q_true", "v_true")

    def __init__(self, spill_dir=None, chunk_rows: int = DEFAULT_CHUNK_ROWS):
        self.spill_dir, self.chunk_rows = spill_dir, chunk_rows
        self._table: ChunkedTable | None = None

    def record(self, t: float, q_est, v_est, q_true, v_true) -> None:
        row = {"t": t, "q_est": q_est, "v_est": v_est, "q_true": q_true, "v_true": v_true}
        if self._table is None:
            self._table = ChunkedTable({key: (np.shape(value), float) for key, value in row.items()}, self.chunk_rows,
                                       self.spill_dir, "estimation")
        self._table.append(row)

    def __len__(self) -> int:
        return len(self._table) if self._table is not None else 0

    def arrays(self, every: int = 1) -> dict[str, np.ndarray]:
        if self._table is None:
            return {name: np.zeros(0) for name in self.KEYS}
        return {name: self._table.column(name, every) for name in self.KEYS}


class EstimatedState:
    """State source of `ClosedLoop`: sensors of `plant` -> `StateEstimator` -> (q, v)."""

    def __init__(self, plant, gait: Gait, sensor_config: SensorConfig = SensorConfig(),
                 estimator_config: EstimatorConfig = EstimatorConfig(), terrain=None):
        self.plant = plant
        self.sensors = Sensors(plant, sensor_config)
        self.estimator = StateEstimator(plant.robot, gait, estimator_config, terrain=terrain)
        self.log = EstimationLog()
        self._time_s: float | None = None
        self._start_xy = plant.state()[0][:2].copy()  # the estimate starts where the robot is placed
        self.listeners: list = []  # f(t_s, q, v) on every new estimate (e.g. the inertial identification)

    def measure(self) -> tuple[np.ndarray, np.ndarray]:
        t = self.plant.time_s
        if t != self._time_s:
            self._time_s = t
            q, v = self.estimator.update(self.sensors.read(), self._start_xy)
            q_true, v_true = self.plant.state()
            self.log.record(t, q, v, q_true, v_true)
            for listener in self.listeners:
                listener(t, q, v)
        return self.estimator.q.copy(), self.estimator.v.copy()
