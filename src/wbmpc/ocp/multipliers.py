"""The last MPC step's multipliers moved to the next step by constraint identity, for a primal-dual warm start.

A row (or variable) is named by its tag, node and place within that node (`OcpProblem.rows`, `row_nodes`, `idx`),
not by its position among a stage's equality or inequality rows: a gait switch changes which rows of a stage are
equalities, inequalities or free, and a solver's own ordering of them with it (a multiplier copied by position lands
on another foot's or another kind of row). Like the primal warm start, each multiplier is re-sampled at the new node
times (linear between the two old nodes around a new node's time, held beyond the old horizon), from those of the
two whose bound kind (free, lower, upper, range, equality) is the row's now. Where a foot's rows change kind between
the two (touchdown, lift-off) the one of the same kind alone counts: requiring both zeroed a stance sole's active
centre-of-pressure multiplier next to every switch (g1 walking in place, with the sole wrenches shifted by contact
pattern: 4.70 -> 4.52 Fatrop iterations per step). A row whose kind neither has starts from 0, the solver's bound
multipliers then from the barrier's floor.
"""

from __future__ import annotations

import numpy as np

from wbmpc.ocp.problem import OcpProblem


def bound_kind(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Per row: 0 free, 1 lower bound only, 2 upper only, 3 both, 4 equality."""
    return np.where(lower == upper, 4, np.isfinite(lower) * 1 + np.isfinite(upper) * 2)


def _identity_table(groups: list[tuple[np.ndarray, np.ndarray]], n_nodes: int, n_items: int):
    """(table[group, node, place] = item index or -1; per item its group, node and place; which items have one)
    from each group's (items, nodes): items (n_blocks, size) with one node per block, or flat with one node each."""
    entries = []
    for g, (items, nodes) in enumerate(groups):
        items, nodes = np.asarray(items, dtype=int), np.asarray(nodes, dtype=int)
        if items.ndim == 2:
            nodes = np.repeat(nodes, items.shape[1])
        items = items.ravel()
        if not items.size:
            continue
        order = np.argsort(nodes, kind="stable")
        sorted_nodes = nodes[order]
        first = np.searchsorted(sorted_nodes, sorted_nodes)
        place = np.empty(items.size, dtype=int)
        place[order] = np.arange(items.size) - first
        entries.append((np.full(items.size, g), nodes, place, items))
    group, node, place, item = (np.concatenate(parts) for parts in zip(*entries))
    table = np.full((len(groups), n_nodes + 1, place.max() + 1), -1, dtype=int)
    table[group, node, place] = item
    of_item = np.zeros((3, n_items), dtype=int)
    of_item[:, item] = group, node, place
    covered = np.zeros(n_items, dtype=bool)
    covered[item] = True
    # each item's group's first and last node: a source node is clamped to them (the x0 rows exist at node 0 only)
    first_node, last_node = np.zeros(len(groups), dtype=int), np.zeros(len(groups), dtype=int)
    first_node[:] = [node[group == g].min() if (group == g).any() else 0 for g in range(len(groups))]
    last_node[:] = [node[group == g].max() if (group == g).any() else 0 for g in range(len(groups))]
    return table, of_item, covered, (first_node[of_item[0]], last_node[of_item[0]])


class MultiplierShift:
    """`shift(lam, kind_old, kind_new, dt_s)`: the multipliers of rows (or variables) one step later (see the
    module docstring), built once per problem."""

    def __init__(self, problem: OcpProblem):
        self.node_times_s = np.asarray(problem.config.grid.node_times_s, dtype=float)
        n_nodes = len(self.node_times_s) - 1
        starts = np.asarray(problem.stage_row_starts)  # a stage's rows are contiguous; some tags' are ragged (dynamics)
        self.rows = _identity_table([(rows, np.searchsorted(starts, rows, side="right") - 1) for rows in
                                     (np.asarray(problem.rows[tag], dtype=int).ravel() for tag in problem.rows)],
                                    n_nodes, problem.n_constraints)
        self.variables = _identity_table([(np.atleast_2d(idx), np.arange(len(idx))) for idx in problem.idx.values()],
                                         n_nodes, problem.n_variables)
        # with the compiled step packer (`OcpProblem.bounds_packer`, solvers/step_pack.py) `sources` is one C call,
        # bit for bit its NumPy code
        self._packer = problem.bounds_packer
        self._compiled = {kind: CompiledShift(problem.bounds_packer, self.node_times_s, identity) for kind, identity in
                          ((True, self.rows), (False, self.variables))} if problem.bounds_packer is not None else None

    def _sources(self, dt_s: float, new_times=None, old_times=None) -> tuple[np.ndarray, np.ndarray]:
        """Per new node: the old node before its time and the weight of the one after (node times relative to each
        plan's start: the grid's unless given)."""
        times = self.node_times_s if old_times is None else np.asarray(old_times, dtype=float)
        new = self.node_times_s if new_times is None else np.asarray(new_times, dtype=float)
        shifted = np.minimum(new + dt_s, times[-1])
        before = np.clip(np.searchsorted(times, shifted, side="right") - 1, 0, len(times) - 2)
        weight = np.clip((shifted - times[before]) / (times[before + 1] - times[before]), 0.0, 1.0)
        return before, weight

    def _plan_times(self, new_times, old_times) -> tuple | None:
        """(new, old) node times of the two plans, the grid's for one not given; None: both on the grid."""
        if new_times is None and old_times is None:
            return None
        return (self.node_times_s if new_times is None else new_times,
                self.node_times_s if old_times is None else old_times)

    def sources(self, dt_s: float, rows: bool = True, new_times=None,
                old_times=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per row (`rows`) or variable: the old ones it is re-sampled from `dt_s` later (src0, src1; -1: none),
        the weight w of src1 and whether it has an identity (covered); in C with the compiled step packer on the
        grid's node times (`new_times`, `old_times`: each plan's own, relative to its start, if they moved)."""
        table, (group, node, place), covered, (first, last) = self.rows if rows else self.variables
        if self._compiled is not None:
            return (*self._compiled[rows](dt_s, self._plan_times(new_times, old_times)), covered)
        before, weight = self._sources(dt_s, new_times, old_times)
        node0 = np.clip(before[node], first, last)
        src0 = table[group, node0, place]
        src1 = table[group, np.minimum(node0 + 1, last), place]
        w = np.where(node0 < last, weight[node], 0.0)
        w = np.where(src1 < 0, 0.0, np.where(src0 < 0, 1.0, w))
        src0, src1 = np.where(src0 < 0, src1, src0), np.where(src1 < 0, src0, src1)
        return src0, src1, w, covered

    def kinds(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """`bound_kind(lower, upper)`, in one C call with the compiled step packer."""
        if self._compiled is None:
            return bound_kind(lower, upper)
        lower, upper = np.ascontiguousarray(lower, dtype=float), np.ascontiguousarray(upper, dtype=float)
        kind = np.empty(lower.size, dtype=np.int64)
        self._packer.wbsp_bound_kind(kind.size, lower.ctypes.data, upper.ctypes.data, kind.ctypes.data)
        return kind

    def shift(self, lam: np.ndarray, kind_old: np.ndarray, kind_new: np.ndarray, dt_s: float,
              rows: bool = True, new_times=None, old_times=None) -> np.ndarray:
        """`lam` of the rows (`rows`) or variables of the last step, `kind_*` their `bound_kind` then and now,
        `dt_s` the time from the last step to this one (`new_times`, `old_times`: the plans' node times where they
        are not the grid's); in C with the compiled step packer (its sources too)."""
        if self._compiled is not None:
            return self._compiled[rows].shift(lam, kind_old, kind_new, dt_s, self._plan_times(new_times, old_times))
        src0, src1, w, covered = self.sources(dt_s, rows, new_times, old_times)
        lam = np.asarray(lam, dtype=float)
        # the sources of the row's own kind: both, interpolated; one, its multiplier (a switch lies between them)
        same0, same1 = kind_old[src0] == kind_new, kind_old[src1] == kind_new
        w = np.where(same0 & same1, w, np.where(same0, 0.0, 1.0))
        same = (same0 | same1) & (src0 >= 0) & covered
        return np.where(same, (1 - w) * lam[src0] + w * lam[src1], 0.0)


class CompiledShift:
    """`MultiplierShift.sources` for one identity table (rows or variables) in one call of the compiled step packer
    (`csrc/step_pack.c` `wbsp_dual_sources`), bit for bit the NumPy code; addresses taken once."""

    def __init__(self, packer, node_times_s: np.ndarray, identity):
        table, (group, node, place), covered, (first, last) = identity
        self._packer, size = packer, len(covered)
        self._out = (np.zeros(size, dtype=np.int64), np.zeros(size, dtype=np.int64), np.zeros(size))  # src0, src1, w
        self._arrays = [np.ascontiguousarray(a, dtype=np.int64) for a in (group, node, place, first, last, table)] + \
            [np.ascontiguousarray(node_times_s, dtype=float), np.zeros(len(node_times_s), dtype=np.int64),
             np.zeros(len(node_times_s))]
        addresses = [a.ctypes.data for a in self._arrays]
        self._head = (size, addresses[6], len(node_times_s))
        self._covered = np.ascontiguousarray(covered, dtype=np.uint8)
        self._shift_tail = (*(a.ctypes.data for a in self._out), self._covered.ctypes.data)
        self._tail = (*addresses[:6], table.shape[1], table.shape[2], *(a.ctypes.data for a in self._out),
                      *addresses[7:])
        self._times = (np.zeros(len(node_times_s)), np.zeros(len(node_times_s)))  # (new, old) off the grid

    def __call__(self, dt_s: float, times: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """src0, src1, w (fresh arrays); `times`: (new, old) node times of plans off the grid."""
        self._sources(dt_s, times)
        return tuple(a.copy() for a in self._out)

    def _sources(self, dt_s: float, times: tuple | None) -> None:
        """The sources into `_out`: on the grid (`wbsp_dual_sources`), or between the plans' own node times `times`
        (new, old: `wbsp_dual_sources_at`, csrc/step_pack.c)."""
        if times is None:
            self._packer.wbsp_dual_sources(*self._head, float(dt_s), *self._tail)
            return
        new, old = self._times
        new[:], old[:] = times
        self._packer.wbsp_dual_sources_at(self._head[0], new.ctypes.data, old.ctypes.data, self._head[2], float(dt_s),
                                          *self._tail)

    def shift(self, lam: np.ndarray, kind_old: np.ndarray, kind_new: np.ndarray, dt_s: float,
              times: tuple | None = None) -> np.ndarray:
        """`MultiplierShift.shift` (its sources and the kind rule) in two C calls (`wbsp_dual_shift`); `times`: (new,
        old) node times of plans off the grid."""
        self._sources(dt_s, times)
        lam = np.ascontiguousarray(lam, dtype=float)
        kind_old, kind_new = (np.ascontiguousarray(kind, dtype=np.int64) for kind in (kind_old, kind_new))
        out = np.empty(self._covered.size)
        self._packer.wbsp_dual_shift(out.size, lam.ctypes.data, kind_old.ctypes.data, kind_new.ctypes.data,
                                     *self._shift_tail, out.ctypes.data)
        return out
