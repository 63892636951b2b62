"""`EstimatedState`: where the closed loop reads its state when `--state estimated`.

It samples the plant's sensors, runs the estimator at most once per simulated instant (the loop
measures at every control tick and again for each MPC solve) and keeps a log of estimate and
truth for the metrics and the plot.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.estimation.estimator import EstimatorConfig, StateEstimator
from wbmpc.estimation.sensors import SensorConfig, Sensors
from wbmpc.gait import Gait


@dataclass
class EstimationLog:
    """Estimate and truth (pinocchio layout) at every estimator update."""

    t: list = field(default_factory=list)
    q_est: list = field(default_factory=list)
    v_est: list = field(default_factory=list)
    q_true: list = field(default_factory=list)
    v_true: list = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.array(getattr(self, name)) for name in ("t", "q_est", "v_est", "q_true", "v_true")}


class EstimatedState:
    """State source of `ClosedLoop`: sensors of `plant` -> `StateEstimator` -> (q, v)."""

    def __init__(self, plant, gait: Gait, sensor_config: SensorConfig = SensorConfig(),
                 estimator_config: EstimatorConfig = EstimatorConfig()):
        self.plant = plant
        self.sensors = Sensors(plant, sensor_config)
        self.estimator = StateEstimator(plant.robot, gait, estimator_config)
        self.log = EstimationLog()
        self._time_s: float | None = None
        self._start_xy = plant.state()[0][:2].copy()  # the estimate starts where the robot is placed

    def measure(self) -> tuple[np.ndarray, np.ndarray]:
        t = self.plant.time_s
        if t != self._time_s:
            self._time_s = t
            q, v = self.estimator.update(self.sensors.read(), self._start_xy)
            q_true, v_true = self.plant.state()
            log = self.log
            log.t.append(t)
            log.q_est.append(q)
            log.v_est.append(v)
            log.q_true.append(q_true)
            log.v_true.append(v_true)
        return self.estimator.q.copy(), self.estimator.v.copy()
