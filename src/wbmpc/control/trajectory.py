"""Per-node trajectories re-sampled at other times (warm starts, held plans, the push detector)."""

from __future__ import annotations

import numpy as np


def interp_rows(new_times: np.ndarray, old_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of per-node rows at new times, held constant beyond the ends."""
    out = np.empty((len(new_times), values.shape[1]))
    # np.minimum/np.maximum, not np.clip: a few microseconds each on these short rows against ~10 (the MPC's hot path)
    pos = np.minimum(np.maximum(np.searchsorted(old_times, new_times) - 1, 0), len(old_times) - 2) \
        if len(old_times) > 1 else None
    if pos is None:
        out[:] = values[0]
        return out
    t0, t1 = old_times[pos], old_times[pos + 1]
    w = np.minimum(np.maximum((new_times - t0) / np.maximum(t1 - t0, 1e-12), 0.0), 1.0)[:, None]
    out[:] = (1 - w) * values[pos] + w * values[pos + 1]
    return out


class Resampler:
    """`interp_rows(new_times[:n], old_times[:n], values)` for several parts and lengths n on the same two grids,
    the search and the weights computed once per length (the warm start re-samples every part of the last plan)."""

    def __init__(self, new_times: np.ndarray, old_times: np.ndarray):
        self.new_times, self.old_times = new_times, old_times
        self._after = np.searchsorted(old_times, new_times)  # searchsorted on old_times[:n] is min(this, n)
        self._weights: dict[int, tuple] = {}

    def __call__(self, values: np.ndarray) -> np.ndarray:
        n = len(values)
        if n < 2:
            return interp_rows(self.new_times[:n], self.old_times[:n], values)
        if n not in self._weights:
            pos = np.minimum(np.maximum(self._after[:n] - 1, 0), n - 2)
            t0, t1 = self.old_times[pos], self.old_times[pos + 1]
            w = np.minimum(np.maximum((self.new_times[:n] - t0) / np.maximum(t1 - t0, 1e-12), 0.0), 1.0)[:, None]
            self._weights[n] = pos, w
        pos, w = self._weights[n]
        return (1 - w) * values[pos] + w * values[pos + 1]
