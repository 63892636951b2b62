"""The warm start of an MPC step (section V-A2): the last plan's variables re-sampled at the new node times.

Each part of the NLP vector (configuration increments, velocities, accelerations, torques, slacks...) is linear
interpolation over its own nodes (`control/trajectory.py`'s `Resampler`, values held beyond the last old node).
`ShiftedGuess` lays every re-sampled variable out once as (node, column) of one table, so a step re-samples the
whole vector in a few gathers (the same arithmetic, bit for bit), instead of unpacking, re-sampling and packing it
part by part.
"""

from __future__ import annotations

import numpy as np


class ShiftedGuess:
    """Re-samples an NLP vector of `problem` from old to new node times (`__call__`); parts in `exclude` are left
    zero (the MPC sets them: the contact forces it re-initialises)."""

    def __init__(self, problem, exclude: tuple[str, ...] = ("F",)):
        parts = [(name, index) for name, index in problem.idx.items() if name not in exclude]
        n_nodes = problem.N + 1
        columns = sum(index.shape[1] for _, index in parts)
        # table[k, j]: the variable of column j at node k (a part's last node repeated past its end: never weighted)
        table = np.zeros((n_nodes, columns), dtype=int)
        lengths = np.zeros(columns, dtype=int)
        start = 0
        for _, index in parts:
            width = index.shape[1]
            table[: len(index), start : start + width] = index
            table[len(index) :, start : start + width] = index[-1]
            lengths[start : start + width] = len(index)
            start += width
        self._lengths = np.unique(lengths)  # the parts' node counts (states N+1, inputs N, torque nodes...)
        group = np.searchsorted(self._lengths, lengths)
        node = np.concatenate([np.arange(n) for n in lengths])  # each variable's node and column, column by column
        column = np.repeat(np.arange(columns), lengths)
        # flat (one-dimensional) lookups only: a gather with two index arrays costs several times one with one
        self._target = table[node, column]
        self._group_node = group[column] * n_nodes + node  # into the (lengths, nodes) weights, raveled
        self._by_column = table.T.ravel()  # [j * n_nodes + k]: the variable of column j at node k
        self._column_start = column * n_nodes
        self._column_next = self._column_start + 1
        self._size = problem.n_variables

    def __call__(self, old_x: np.ndarray, new_times: np.ndarray, old_times: np.ndarray) -> np.ndarray:
        """The vector `old_x` (NLP layout) at `new_times`: each variable of node k linearly interpolated
        between the old nodes around new_times[k] (among its part's own nodes), held beyond them."""
        lengths = self._lengths[:, None]
        after = np.searchsorted(old_times, new_times)[None, :]
        pos = np.minimum(np.maximum(after - 1, 0), np.maximum(lengths - 2, 0))  # (part lengths, nodes)
        t0, t1 = old_times[pos], old_times[np.minimum(pos + 1, len(old_times) - 1)]
        weight = np.minimum(np.maximum((new_times[None, :] - t0) / np.maximum(t1 - t0, 1e-12), 0.0), 1.0)
        weight[self._lengths < 2] = 0.0  # a part on one node: held
        pos_v, w_v = pos.ravel().take(self._group_node), weight.ravel().take(self._group_node)
        before = old_x.take(self._by_column.take(self._column_start + pos_v))
        after_ = old_x.take(self._by_column.take(self._column_next + pos_v))
        out = np.zeros(self._size)
        out[self._target] = (1 - w_v) * before + w_v * after_
        return out
