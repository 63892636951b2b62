"""`StreamingStats`: a real-time loop's per-tick timings in fixed memory, against NumPy on the whole series."""

import math

import numpy as np
import pytest

from wbmpc.control.streaming_stats import StreamingStats
from wbmpc.errors import ConfigError


def test_statistics_match_numpy_on_the_whole_series():
    rng = np.random.default_rng(0)
    # lateness-like: mostly small, a tail, a few spikes beyond the histogram's range
    values = np.concatenate([rng.exponential(0.05, 20_000), rng.uniform(0.5, 3.0, 300), [15.9, 120.0, 250.0]])
    rng.shuffle(values)
    stats = StreamingStats(threshold=1.0)
    for value in values:
        stats.add(value)
    assert stats.count == values.size
    assert stats.mean == pytest.approx(values.mean(), rel=1e-12)
    assert stats.max == values.max() and stats.min == values.min()
    assert stats.share_over() == np.mean(values > 1.0)  # exact
    for p in (50, 90, 99, 99.9):
        exact = np.percentile(values, p, method="inverted_cdf")
        assert exact <= stats.percentile(p) <= exact + stats.resolution
    assert stats.percentile(100) == values.max()  # in the overflow bin: the max
    summary = stats.summary()
    assert summary["p99"] == stats.percentile(99) and summary["max"] == 250.0


def test_memory_is_the_histograms_however_many_samples():
    stats = StreamingStats(resolution=0.01, range_max=100.0)
    before = stats.nbytes
    for k in range(200_000):
        stats.add((k % 997) * 0.001)
    assert stats.nbytes == before == 8 * 10_001


def test_empty_and_refused():
    stats = StreamingStats()
    assert math.isnan(stats.mean) and math.isnan(stats.percentile(99)) and stats.summary()["max"] is None
    stats.add(-0.5)  # below the range: counted in the first bin, kept exactly in mean and min
    assert stats.min == -0.5 and stats.percentile(50) == -0.5
    with pytest.raises(ConfigError, match="resolution"):
        StreamingStats(resolution=0.0)
