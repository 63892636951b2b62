"""Centre of pressure of flat feet measured in MuJoCo, checked against the sole rectangle every tick.

The MPC keeps each stance sole's centre of pressure inside its rectangle by a hard constraint (the
wrench cone, ocp/problem.py); `SolePressureMonitor` checks what the simulated robot actually does:
after every physics step it reads each loaded sole's measured CoP (`MujocoPlant.sole_pressure`) and
counts the ticks on which one lies outside the rectangle (by more than a tolerance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

COP_TOLERANCE_M = 1e-3  # MuJoCo's contact points sit on the box corners: a CoP on an edge reads 1e-6 m out
MIN_LOAD_N = 1.0  # soles carrying less than this (touching, not standing) are not counted


@dataclass
class SolePressureMonitor:
    """Step hook of a MuJoCo plant with flat feet; `metrics()` summarises the run."""

    half_sizes_m: dict[str, np.ndarray]  # foot -> (half length, half width)
    ticks: int = 0
    loaded_ticks: int = 0
    outside_ticks: int = 0
    min_margin_m: float = np.inf  # smallest distance from a loaded sole's CoP to its rectangle's edge
    first_outside_s: float | None = None
    per_foot_outside: dict[str, int] = field(default_factory=dict)

    @classmethod
    def for_robot(cls, robot) -> SolePressureMonitor:
        return cls({foot: np.array([s.half_length_m, s.half_width_m]) for foot, s in robot.soles.items()})

    def before_step(self, plant) -> None:
        pass

    def after_step(self, plant) -> None:
        self.ticks += 1
        outside = False
        for foot, measured in plant.sole_pressure().items():
            if measured is None or measured[1] < MIN_LOAD_N:
                continue
            self.loaded_ticks += 1
            margin = float(np.min(self.half_sizes_m[foot] - np.abs(measured[0])))
            self.min_margin_m = min(self.min_margin_m, margin)
            if margin < -COP_TOLERANCE_M:
                outside = True
                self.per_foot_outside[foot] = self.per_foot_outside.get(foot, 0) + 1
        if outside:
            self.outside_ticks += 1
            if self.first_outside_s is None:
                self.first_outside_s = float(plant.time_s)

    def metrics(self) -> dict:
        return {
            "cop_outside_sole_ticks": self.outside_ticks,
            "cop_checked_ticks": self.ticks,
            "cop_min_margin_m": None if not np.isfinite(self.min_margin_m) else self.min_margin_m,
            "cop_first_outside_s": self.first_outside_s,
        }
