"""Per-node trajectories re-sampled at other times (warm starts, held plans, the push detector)."""

from __future__ import annotations

import numpy as np


def interp_rows(new_times: np.ndarray, old_times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of per-node rows at new times, held constant beyond the ends."""
    out = np.empty((len(new_times), values.shape[1]))
    pos = np.clip(np.searchsorted(old_times, new_times) - 1, 0, len(old_times) - 2) if len(old_times) > 1 else None
    if pos is None:
        out[:] = values[0]
        return out
    t0, t1 = old_times[pos], old_times[pos + 1]
    w = np.clip((new_times - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)[:, None]
    out[:] = (1 - w) * values[pos] + w * values[pos + 1]
    return out
