"""Safe footholds: the terrain's cells away from edges, and the nearest safe cell of any target.

A foot landing on a step's nose slips off it; one landing at the foot of a riser stubs its toe on the way up.
`FootholdMap` marks as edges the raster cells whose height differs from a neighbour's by more than
`edge_height_m` (a step, a stone's side; a slope's gentle rise is not one), keeps every cell within
`keep_out_m` of an edge out (the band on both sides of the edge), cells steeper than `max_slope_deg` and the
bottoms of holes and gaps (more than `max_drop_m` below the ground around them: a gap between stepping stones
wider than twice the band still has no foothold). A landing target on an unsafe cell moves to the nearest safe cell (`adapt`, a Euclidean distance transform
computed once: no search per step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from wbmpc.errors import check_number
from wbmpc.terrain.pieces import TerrainError
from wbmpc.terrain.terrain import Terrain

HOLE_REACH_M = 0.1


@dataclass(frozen=True)
class FootholdConfig:
    """Where a foot may land (units in the names)."""

    keep_out_m: float = 0.06  # band kept free on both sides of an edge
    edge_height_m: float = 0.02  # a height jump between neighbouring cells larger than this is an edge
    max_slope_deg: float = 35.0  # steeper cells are no foothold
    # ground more than this below the highest ground within keep_out_m + HOLE_REACH_M is the bottom of a hole or a gap
    max_drop_m: float = 0.25
    resolution_m: float = 0.01  # raster of the map

    def __post_init__(self):
        check_number("keep_out_m", self.keep_out_m, low=0.0, high=1.0, unit="m")
        check_number("edge_height_m", self.edge_height_m, low=0.0, low_open=True, high=1.0, unit="m")
        check_number("max_slope_deg", self.max_slope_deg, low=0.0, low_open=True, high=90.0, unit="deg")
        check_number("max_drop_m", self.max_drop_m, low=0.0, low_open=True, high=10.0, unit="m")
        check_number("resolution_m", self.resolution_m, low=0.001, high=0.2, unit="m")


class FootholdMap:
    """Edges, safe cells and the nearest safe cell of each cell of a terrain (see the module docstring)."""

    def __init__(self, terrain: Terrain, config: FootholdConfig = FootholdConfig()):
        self.terrain, self.config = terrain, config
        raster = terrain.raster(config.resolution_m, margin_m=max(config.keep_out_m + 0.2, 0.5))
        self.raster = raster
        heights = raster.heights_m
        edges = np.zeros(heights.shape, dtype=bool)
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):  # each neighbour pair once
            a = heights[max(di, 0):, max(dj, 0): heights.shape[1] + min(dj, 0)]
            b = heights[: heights.shape[0] - di, max(-dj, 0): heights.shape[1] - max(dj, 0)]
            jump = np.abs(a - b) > config.edge_height_m
            edges[max(di, 0):, max(dj, 0): heights.shape[1] + min(dj, 0)] |= jump
            edges[: heights.shape[0] - di, max(-dj, 0): heights.shape[1] - max(dj, 0)] |= jump
        self.edges = edges
        self.edge_distance_m = ndimage.distance_transform_edt(~edges) * raster.resolution_m if edges.any() else \
            np.full(heights.shape, np.inf)
        steep = raster.normals[..., 2] < np.cos(np.deg2rad(config.max_slope_deg))
        window = 2 * int(np.ceil((config.keep_out_m + HOLE_REACH_M) / raster.resolution_m)) + 1
        hole = ndimage.maximum_filter(heights, size=window, mode="nearest") - heights > config.max_drop_m
        self.safe = (self.edge_distance_m > config.keep_out_m) & ~steep & ~hole
        if not self.safe.any():
            raise TerrainError(f"terrain '{terrain.name}' has no foothold {100 * config.keep_out_m:.0f} cm from every "
                               f"edge and flatter than {config.max_slope_deg:g} deg: widen its steps or lower keep_out_m")
        self._nearest = ndimage.distance_transform_edt(~self.safe, return_distances=False,
                                                       return_indices=True).astype(np.int32)

    def is_safe(self, xy) -> np.ndarray:
        """Whether each point (..., 2) lies on a safe cell (outside the raster: the floor, safe)."""
        i, j, inside = self.raster.cell(xy)
        return ~inside | self.safe[i, j]

    def adapt(self, xy) -> np.ndarray:
        """Points (..., 2) on unsafe cells moved to the centre of the nearest safe cell; safe ones unchanged."""
        xy = np.asarray(xy, dtype=float)
        i, j, inside = self.raster.cell(xy)
        unsafe = inside & ~self.safe[i, j]
        if not np.any(unsafe):
            return xy.copy()
        moved = self.raster.centre(self._nearest[0][i, j], self._nearest[1][i, j])
        return np.where(unsafe[..., None], moved, xy)
