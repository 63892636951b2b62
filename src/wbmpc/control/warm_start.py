"""The warm start of an MPC step (section V-A2): the last plan's variables re-sampled at the new node times.

Each part of the NLP vector (configuration increments, velocities, accelerations, torques, slacks...) is linear
interpolation over its own nodes (`control/trajectory.py`'s `Resampler`, values held beyond the last old node).
`ShiftedGuess` lays every re-sampled variable out once as (node, column) of one table, so a step re-samples the
whole vector in a few gathers (the same arithmetic, bit for bit), instead of unpacking, re-sampling and packing it
part by part. `ShiftedDuals` does the same for the last plan's multipliers, for a solver that takes them.

Flat feet's wrenches are re-sampled by contact pattern (`shifted_sole_wrenches`): a new node takes the last plan's
wrenches from the old nodes around its time that had the same stance feet, not across a contact switch.
"""

from __future__ import annotations

import numpy as np

from wbmpc.ocp.multipliers import MultiplierShift


class ShiftedGuess:
    """Re-samples an NLP vector of `problem` from old to new node times (`__call__`); parts in `exclude` are left
    zero (the MPC sets them: the contact forces it re-initialises). With `packer` (`solvers.step_pack.library()`)
    the same arithmetic runs in one C call."""

    def __init__(self, problem, exclude: tuple[str, ...] = ("F",), packer=None):
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
        self._packer = packer
        if packer is not None:  # the C call's tables (int64), its inputs, output and scratch, kept with their addresses
            tables = (self._lengths, self._group_node, self._by_column, self._column_start, self._target)
            self._tables = tuple(np.ascontiguousarray(table, dtype=np.int64) for table in tables)
            groups = len(self._lengths)
            self._buffers = (np.zeros(self._size), np.zeros(2 * n_nodes), np.zeros(self._size),
                             np.zeros(groups * n_nodes, dtype=np.int64), np.zeros(groups * n_nodes))
            old_x, times, out, pos, weight = (a.ctypes.data for a in self._buffers)
            lengths, group_node, by_column, column_start, target = (a.ctypes.data for a in self._tables)
            self._call = (groups, lengths, n_nodes, times + 8 * n_nodes, n_nodes, times, len(self._target), group_node,
                          by_column, column_start, target, old_x, self._size, out, pos, weight)
        self._n_nodes, self.compiled_call = n_nodes, self._call if packer is not None else None  # (compiled_step.py)

    def __call__(self, old_x: np.ndarray, new_times: np.ndarray, old_times: np.ndarray) -> np.ndarray:
        """The vector `old_x` (NLP layout) at `new_times`: each variable of node k linearly interpolated
        between the old nodes around new_times[k] (among its part's own nodes), held beyond them."""
        if self._packer is not None and len(new_times) == len(old_times) == self._n_nodes and old_x.size == self._size:
            old_buffer, times, out = self._buffers[:3]
            old_buffer[:], times[: self._n_nodes], times[self._n_nodes :] = old_x, new_times, old_times
            self._packer.wbsp_shift(*self._call)
            return out.copy()
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


def shifted_sole_wrenches(forces: np.ndarray, previous_forces: np.ndarray, previous_contact: np.ndarray,
                          contact: np.ndarray, new_times: np.ndarray, old_times: np.ndarray,
                          columns: dict[int, np.ndarray], torque_nodes: int = 0) -> np.ndarray:
    """The last plan's sole wrenches (force and moments; `columns[i]`: flat foot i's
    columns of F) at the new input nodes.

    Each new node's sources are the two old nodes around its time (the last old node alone past the old horizon)
    whose contact pattern (which feet stand) is the new node's: both, linear interpolation; one, its wrench (a
    contact switch lies between them); none, `forces` (the weight share re-initialised, section V-A2). Interpolating
    across a switch mixes two load distributions: at a lift-off the unloaded foot got half the weight (g1 walking in
    place, dynamics rows violated by up to 0.7 of the weight at the warm start, 5.42 Fatrop iterations per step;
    by pattern with the multipliers' kind rule in `ocp/multipliers.py`, 4.52). `contact`, `previous_contact`:
    (nodes, feet) stance flags of the new and old input nodes; only stance feet's columns are written.

    The first `torque_nodes` input nodes (the torque variables' nodes, whose RNEA joint rows tie the wrenches to the
    torques; eq. 5) take their sources among the old torque nodes only, the last one held past them: the plan's sole
    moments jump between its last torque node and the next (g1 walking: the pitch moment -1.6 -> -7.6 in
    scaled units), so interpolating a new torque node towards an old free node put the next node's wrench into it
    and violated its joint rows by up to half the torque limit at every warm start (4.64 -> 4.50 Fatrop iterations
    per step on 240 recorded walking-in-place steps)."""
    n_old = len(old_times)
    first, second = _sources(new_times, old_times)
    if torque_nodes > 0:
        head = min(torque_nodes, len(new_times), len(old_times))
        first[:head], second[:head] = _sources(new_times[:head], old_times[:head])
    span = old_times[second] - old_times[first]
    weight = np.where(span > 0, np.clip((new_times - old_times[first]) / np.where(span > 0, span, 1.0), 0.0, 1.0), 0.0)
    stance, before = contact > 0.5, previous_contact[:n_old] > 0.5
    same_first, same_second = (before[first] == stance).all(axis=1), (before[second] == stance).all(axis=1)
    weight = np.where(same_first & same_second, weight, np.where(same_first, 0.0, 1.0))[:, None]
    matched = same_first | same_second
    out = forces.copy()
    for foot, cols in columns.items():
        rows = np.flatnonzero(matched & stance[:, foot])
        out[np.ix_(rows, cols)] = (1 - weight[rows]) * previous_forces[np.ix_(first[rows], cols)] + \
            weight[rows] * previous_forces[np.ix_(second[rows], cols)]
    return out


def _sources(new_times: np.ndarray, old_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per new time: the old nodes before and after it (the last old node alone past the old ones)."""
    n_old = len(old_times)
    after = np.searchsorted(old_times, new_times)
    first = np.minimum(np.maximum(after - 1, 0), max(n_old - 2, 0))
    second = np.minimum(first + 1, n_old - 1)
    beyond = new_times > old_times[-1]
    return np.where(beyond, n_old - 1, first), np.where(beyond, n_old - 1, second)


class ShiftedDuals:
    """The last plan's multipliers moved to this step's rows by constraint identity (`ocp/multipliers.py`), for a
    solver that starts from given multipliers (fatrop-direct on flat feet)."""

    def __init__(self, problem):
        self._shift = MultiplierShift(problem)
        self._grid = problem.config.grid.node_times_s
        self._last: tuple | None = None  # (t_s, lam_g, lam_x, row kinds, variable kinds, node times) of the last plan
        self._kinds: tuple | None = None  # (bounds, row kinds, variable kinds) that `at` found for this step's bounds

    def reset(self) -> None:
        self._last = self._kinds = None

    def record(self, t_s: float, result, bounds, node_times_s=None) -> None:
        """Keep a successful step's multipliers with the kinds of its rows' and variables' bounds (and its node
        times, where they are not the grid's: `TimeGrid.follow_contact_switches`)."""
        kinds, self._kinds = self._kinds, None
        if kinds is None or kinds[0] is not bounds:
            kinds = (bounds, *self._bound_kinds(bounds))
        self._last = (t_s, result.lam_g, result.lam_x, kinds[1], kinds[2], self._moved(node_times_s))

    def _moved(self, node_times_s):
        return None if node_times_s is None or node_times_s is self._grid else node_times_s

    def _bound_kinds(self, bounds) -> tuple[np.ndarray, np.ndarray]:
        lbx, ubx, lbg, ubg = bounds
        return self._shift.kinds(lbg, ubg), self._shift.kinds(lbx, ubx)  # (`bound_kind`, in C where compiled)

    def at(self, t_s: float, bounds, previous_t_s: float | None, node_times_s=None) -> tuple:
        """(lam_g0, lam_x0) for the step at `t_s` with `bounds` (and its node times, if not the grid's), when the
        kept multipliers are the plan's at `previous_t_s` (the last good plan); () otherwise."""
        last = self._last
        if last is None or previous_t_s is None or last[0] != previous_t_s:
            return ()
        kind_rows, kind_variables = self._bound_kinds(bounds)
        self._kinds = (bounds, kind_rows, kind_variables)  # `record` of this step's plan takes them (same bounds)
        # re-sampled between the plans' own node times where either moved off the grid
        dt_s, times = t_s - last[0], {"new_times": self._moved(node_times_s), "old_times": last[5]}
        return (self._shift.shift(last[1], last[3], kind_rows, dt_s, **times),
                self._shift.shift(last[2], last[4], kind_variables, dt_s, rows=False, **times))
