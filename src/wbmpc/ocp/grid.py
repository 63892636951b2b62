"""Horizon time grids: geometric steps dt_k = gamma^k dt_0 (section IV-C) or uniform steps."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wbmpc.errors import ConfigError, check_number

MAX_INTERVALS = 99  # 100 nodes: the NLP grows linearly and its build takes minutes beyond that
MAX_STEP_S = 0.5  # longer steps leave the gait and the dynamics unresolved (Fatrop stalls)


@dataclass(frozen=True)
class TimeGrid:
    """N intervals between N+1 nodes. Geometric by default: 10 ms growing to 100 ms over 14 steps."""

    n_intervals: int = 14
    dt_first_s: float = 0.01
    dt_last_s: float = 0.1
    uniform: bool = False

    def __post_init__(self):
        if isinstance(self.n_intervals, bool) or not isinstance(self.n_intervals, int):
            raise ConfigError.for_field("n_intervals", f"must be an integer, got {self.n_intervals!r}")
        check_number("n_intervals", self.n_intervals, low=1, high=MAX_INTERVALS)
        check_number("dt_first_s", self.dt_first_s, low=0.0, high=MAX_STEP_S, low_open=True, unit="s")
        check_number("dt_last_s", self.dt_last_s, low=0.0, high=MAX_STEP_S, low_open=True, unit="s")
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

    @cached_property
    def dt_s(self) -> np.ndarray:
        """Interval lengths dt_k, k = 0..N-1 (computed once, read-only: the MPC reads them every step)."""
        return _read_only(self.dt_first_s * self.gamma ** np.arange(self.n_intervals))

    @cached_property
    def node_times_s(self) -> np.ndarray:
        """Times of the N+1 nodes relative to the first (computed once, read-only)."""
        return _read_only(np.concatenate([[0.0], np.cumsum(self.dt_s)]))

    @property
    def horizon_s(self) -> float:
        return float(self.dt_s.sum())


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array
