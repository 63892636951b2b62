"""Horizon time grids: geometric steps dt_k = gamma^k dt_0 (section IV-C) or uniform steps, optionally with the far
nodes moved onto the gait's contact switches every step (`TimeGrid.on_switches`).

On a fixed grid a node's contact flag flips when a touchdown or lift-off passes its time, so the plan's switch
jumps by a whole interval (30-100 ms on the geometric grid's far nodes) and the optimum with it. With
`follow_contact_switches` each switch inside a far node's cell (half-way to either neighbour) moves that node onto
it and the nodes between spread out: the plan's contact timing is then the gait's, continuous in time, and only the
discretisation changes when a switch passes the middle between two nodes and hops to the next one.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wbmpc.errors import ConfigError, check_number

MAX_INTERVALS = 99  # 100 nodes: the NLP grows linearly and its build takes minutes beyond that
MAX_STEP_S = 0.5  # longer steps leave the gait and the dynamics unresolved (Fatrop stalls)
FIXED_NODES = 5  # node 0 and the next four keep their times: the bounds' early nodes (problem.EARLY_NODES) read them
MOVABLE_DT_S = 0.02  # a node moves onto a switch only after an interval this long (the fine first ones stay)
ON_SWITCH_AFTER_S = 1e-6  # a node on a switch sits this much after it: its contact flag is the next interval's


@dataclass(frozen=True)
class TimeGrid:
    """N intervals between N+1 nodes. Geometric by default: 10 ms growing to 100 ms over 14 steps."""

    n_intervals: int = 14
    dt_first_s: float = 0.01
    dt_last_s: float = 0.1
    uniform: bool = False
    follow_contact_switches: bool = False  # move the far nodes onto the gait's contact switches (`on_switches`)

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

    def on_switches(self, switch_times_s: np.ndarray) -> np.ndarray:
        """Node times (relative to node 0) with the movable nodes on the contact switches `switch_times_s` (relative
        to node 0, sorted) and the nodes between them spread out linearly (a piecewise-linear warp of the grid).

        Movable: nodes from `FIXED_NODES` to N-1 after an interval of at least `MOVABLE_DT_S`. A switch goes to the
        node whose cell holds it (half-way to either neighbour's grid time; node N-1's reaches to the last node less
        `dt_first_s`), so a switch sliding towards node 0 carries its node until the middle, then the node before
        takes it. Two switches in one cell: the nearer one; moved neighbours closer than `dt_first_s`: the farther
        goes back (its switch then flips a node, as on the fixed grid). A node on a switch sits `ON_SWITCH_AFTER_S`
        after it, so the flags sampled at node times are the interval's after it: stance at a touchdown node, swing
        at a lift-off node. Each other node keeps its place between the fixed and moved nodes around it: moved alone,
        a node on a switch stretched its neighbours' intervals by up to half of theirs at every hop (g1 walking
        forward at an 11 ms delay: 4.51 Fatrop iterations a step alone, 3.82 spread)."""
        times = self.node_times_s
        grid, edges, movable = self._cells  # (Python floats: a dozen nodes and a few switches per step)
        best: dict[int, tuple[float, float]] = {}  # node -> (its switch's distance from the node's grid time, time)
        for switch in np.asarray(switch_times_s, dtype=float).tolist():
            node = bisect.bisect_right(edges, switch)  # the node whose cell holds the switch
            if node < len(grid) and movable[node]:
                away = abs(switch - grid[node])
                if away < best.get(node, (math.inf,))[0]:
                    best[node] = (away, switch + ON_SWITCH_AFTER_S)
        for node in sorted(best):  # too close to a moved neighbour: the farther goes back
            if node in best and node + 1 in best and best[node + 1][1] - best[node][1] < self.dt_first_s:
                del best[node if best[node][0] > best[node + 1][0] else node + 1]
        if not best:
            return times
        anchors = sorted([(k, grid[k]) for k in range(len(grid)) if not movable[k]] +
                         [(k, time_s) for k, (_, time_s) in best.items()])
        moved = list(grid)
        for (k0, t0), (k1, t1) in zip(anchors, anchors[1:]):  # the nodes between spread linearly
            scale = (t1 - t0) / (grid[k1] - grid[k0])
            for k in range(k0 + 1, k1):
                moved[k] = t0 + (grid[k] - grid[k0]) * scale
            moved[k1] = t1
        return _read_only(np.array(moved))

    @cached_property
    def _cells(self) -> tuple[list[float], list[float], list[bool]]:
        """`on_switches`' grid times, cell edges (half-way, node N-1's to the last node less `dt_first_s`) and
        movable nodes, as Python lists."""
        grid = self.node_times_s.tolist()
        edges = [0.5 * (a + b) for a, b in zip(grid[:-1], grid[1:])]
        edges[-1] = grid[-1] - self.dt_first_s
        return grid, edges, self._movable_nodes.tolist()

    @cached_property
    def _movable_nodes(self) -> np.ndarray:
        """Per node: whether `on_switches` may move it."""
        movable = np.zeros(self.n_intervals + 1, dtype=bool)
        nodes = np.arange(FIXED_NODES, self.n_intervals)
        movable[nodes] = self.dt_s[nodes - 1] >= MOVABLE_DT_S
        return movable


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array
