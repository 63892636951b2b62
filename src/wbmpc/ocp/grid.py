"""Horizon time grids: geometric steps dt_k = gamma^k dt_0 (section IV-C) or uniform steps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.errors import ConfigError


@dataclass(frozen=True)
class TimeGrid:
    """N intervals between N+1 nodes. Geometric by default: 10 ms growing to 100 ms over 14 steps."""

    n_intervals: int = 14
    dt_first_s: float = 0.01
    dt_last_s: float = 0.1
    uniform: bool = False

    def __post_init__(self):
        if self.n_intervals < 1:
            raise ConfigError(f"the horizon needs at least one interval, got {self.n_intervals}")
        if not (self.dt_first_s > 0 and self.dt_last_s > 0) or not np.isfinite(self.dt_first_s + self.dt_last_s):
            raise ConfigError(f"time steps must be positive and finite, got dt_first_s={self.dt_first_s}, dt_last_s={self.dt_last_s}")
        if not self.uniform and self.dt_last_s < self.dt_first_s:
            raise ConfigError("geometric steps grow along the horizon: dt_last_s must be >= dt_first_s")

    @classmethod
    def uniform_steps(cls, n_intervals: int, dt_s: float) -> "TimeGrid":
        return cls(n_intervals=n_intervals, dt_first_s=dt_s, dt_last_s=dt_s, uniform=True)

    @property
    def gamma(self) -> float:
        if self.uniform or self.n_intervals == 1:
            return 1.0
        return (self.dt_last_s / self.dt_first_s) ** (1.0 / (self.n_intervals - 1))

    @property
    def dt_s(self) -> np.ndarray:
        """Interval lengths dt_k, k = 0..N-1."""
        return self.dt_first_s * self.gamma ** np.arange(self.n_intervals)

    @property
    def node_times_s(self) -> np.ndarray:
        """Times of the N+1 nodes relative to the first."""
        return np.concatenate([[0.0], np.cumsum(self.dt_s)])

    @property
    def horizon_s(self) -> float:
        return float(self.dt_s.sum())
