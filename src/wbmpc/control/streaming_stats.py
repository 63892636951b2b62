"""`StreamingStats`: count, mean, max, percentiles and a share over a threshold of a timing series, in fixed memory.

A real-time loop measures something on every 500 Hz tick (how late the plant's tick ran, the controller's work);
kept in a list that is 1.8 million floats an hour (~14 MB as Python floats). Here each value goes into a histogram
of `resolution_ms` bins up to `range_ms` (one overflow bin above it): the mean, max and the count over the threshold
are exact, a percentile is the upper edge of the bin holding it (at most `resolution_ms` above numpy's, never above
the max). The memory is the histogram's, however long the run.
"""

from __future__ import annotations

import math

import numpy as np

from wbmpc.errors import check_number


class StreamingStats:
    """`add(value)` per sample (ms, or any unit the bins are given in); `summary()` for the report."""

    def __init__(self, threshold: float | None = None, resolution: float = 0.01, range_max: float = 100.0):
        """`threshold`: `share_over()` counts the samples above it exactly; bins of `resolution` from 0 to `range_max`
        (samples below 0 go into the first, above `range_max` into an overflow bin)."""
        check_number("resolution", resolution, low=0.0, low_open=True)
        check_number("range_max", range_max, low=resolution)
        self.threshold = threshold
        self.resolution = float(resolution)
        self._bins = int(math.ceil(range_max / resolution))
        self._counts = np.zeros(self._bins + 1, dtype=np.int64)
        self.count = 0
        self.total = 0.0
        self.max = -math.inf
        self.min = math.inf
        self.over = 0

    def add(self, value: float) -> None:
        value = float(value)
        index = int(value / self.resolution) if value > 0 else 0
        self._counts[index if index < self._bins else self._bins] += 1
        self.count += 1
        self.total += value
        if value > self.max:
            self.max = value
        if value < self.min:
            self.min = value
        if self.threshold is not None and value > self.threshold:
            self.over += 1

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else math.nan

    def percentile(self, p: float) -> float:
        """The p-th percentile (0-100): the upper edge of the bin of the ceil(p n / 100)-th smallest sample, clipped
        to the max (a sample in the overflow bin: the max)."""
        if not self.count:
            return math.nan
        rank = max(1, math.ceil(p / 100.0 * self.count))
        index = int(np.searchsorted(np.cumsum(self._counts), rank))
        if index >= self._bins:
            return self.max
        return min((index + 1) * self.resolution, self.max)

    def share_over(self) -> float:
        """The share of samples above `threshold` (exact)."""
        return self.over / self.count if self.count else math.nan

    def summary(self) -> dict:
        """{"mean", "p50", "p99", "max"} (None for an empty series)."""
        if not self.count:
            return {"mean": None, "p50": None, "p99": None, "max": None}
        return {"mean": self.mean, "p50": self.percentile(50), "p99": self.percentile(99), "max": self.max}

    @property
    def nbytes(self) -> int:
        """The histogram's bytes: what the statistics hold, whatever the number of samples."""
        return int(self._counts.nbytes)
