"""`Terrain`: the ground a robot walks on, as data both the simulator and the MPC read.

A terrain is a floor (a plane at `floor_m`) and pieces standing on it (`wbmpc.terrain.pieces`: boxes, ramps,
heightmaps) whose footprints do not overlap, so that the height at any (x, y) is that of the one piece there or
the floor's. MuJoCo builds the same geometry (`wbmpc.sim.terrain_geoms`); the MPC reads heights and normals from
here (`wbmpc.control.terrain_references`), never from the simulator. `raster()` samples it on a grid for the
queries of the controller (highest point under a swing, edges and safe footholds: `wbmpc.terrain.footholds`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.terrain.pieces import Box, Heightmap, Piece, Ramp, TerrainError

OVERLAP_TOLERANCE_M = 1e-6  # footprints may share an edge, not an area
RASTER_MAX_CELLS = 4_000_000


@dataclass(frozen=True)
class Terrain:
    """The floor at `floor_m` and `pieces` on it (their footprints must not overlap)."""

    pieces: tuple[Piece, ...] = ()
    floor_m: float = 0.0
    name: str = "flat"
    source: str | None = None  # the file it was read from (error messages name it)
    _raster_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _boxes: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)  # (pieces, 4) see below

    def __post_init__(self):
        pieces = tuple(self.pieces)
        if not np.isfinite(self.floor_m):
            raise TerrainError(self._where(f"the floor height must be a finite number, got {self.floor_m!r}"))
        named = []
        counts: dict[str, int] = {}
        for piece in pieces:
            if not isinstance(piece, (Box, Ramp, Heightmap)):
                raise TerrainError(self._where(f"a terrain piece must be a Box, Ramp or Heightmap, got {piece!r}"))
            if not piece.name:
                counts[piece.kind] = counts.get(piece.kind, 0) + 1
                piece = _renamed(piece, f"{piece.kind} {counts[piece.kind]}")
            named.append(piece)
        names = [p.name for p in named]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise TerrainError(self._where(f"terrain pieces need unique names; repeated: {', '.join(duplicates)}"))
        object.__setattr__(self, "pieces", tuple(named))
        # each piece's footprint's bounding box (x min, y min, x max, y max): a query tests only the pieces whose box
        # holds one of its points (the MPC asks for its footholds on every step)
        corners = [piece.corners() for piece in named]
        object.__setattr__(self, "_boxes", np.array([np.r_[c.min(axis=0), c.max(axis=0)] for c in corners])
                           .reshape(-1, 4) + np.array([-1e-9, -1e-9, 1e-9, 1e-9]))
        for piece in named:
            self._check_above_floor(piece)
        self._check_overlaps()

    def _where(self, message: str) -> str:
        return f"terrain {self.source}: {message}" if self.source else f"terrain: {message}"

    def _check_above_floor(self, piece: Piece) -> None:
        floor = self.floor_m
        if isinstance(piece, Box) and piece.top_m <= floor:
            raise TerrainError(self._where(f"box '{piece.name}' has its top at {piece.top_m:g} m, not above the floor "
                                           f"({floor:g} m): raise it or lower the floor"))
        if isinstance(piece, Box) and piece.bottom_m is not None and piece.bottom_m < floor:
            raise TerrainError(self._where(f"box '{piece.name}' reaches below the floor ({piece.bottom_m:g} < {floor:g} "
                                           "m): leave its bottom out (it then stands on the floor)"))
        if isinstance(piece, Ramp) and piece.top_min_m < floor:
            raise TerrainError(self._where(f"ramp '{piece.name}' starts or ends below the floor ({piece.top_min_m:g} < "
                                           f"{floor:g} m): the floor plane would cover it"))
        if isinstance(piece, Heightmap):
            low = np.unravel_index(np.argmin(piece.heights_m), piece.shape)
            if piece.heights_m[low] < floor - 1e-9:
                raise TerrainError(self._where(
                    f"heightmap '{piece.name}' has height {piece.heights_m[low]:g} m at row {low[0]}, column {low[1]}, "
                    f"below the floor ({floor:g} m), which would cover it: offset its heights or lower the floor"))

    def _check_overlaps(self) -> None:
        corners = [p.corners() for p in self.pieces]
        for a in range(len(self.pieces)):
            for b in range(a + 1, len(self.pieces)):
                depth = _overlap_depth(corners[a], corners[b])
                if depth > OVERLAP_TOLERANCE_M:
                    region = _overlap_box(corners[a], corners[b])
                    raise TerrainError(self._where(
                        f"{self.pieces[a].kind} '{self.pieces[a].name}' and {self.pieces[b].kind} '{self.pieces[b].name}' "
                        f"overlap by {100 * depth:.1f} cm around x {region[0]:.3f}..{region[2]:.3f} m, y "
                        f"{region[1]:.3f}..{region[3]:.3f} m: footprints may touch, not overlap (a step's height is "
                        "its own top; place the steps side by side)"))

    # ------------------------------------------------------------------ queries
    @property
    def is_flat(self) -> bool:
        """The flat floor at 0 and nothing on it (the MPC's references then are the flat-floor ones)."""
        return not self.pieces and self.floor_m == 0.0

    def height_normal(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """Heights (...,) and unit normals (..., 3) of the surface at points xy (..., 2)."""
        xy = np.asarray(xy, dtype=float)
        shape = xy.shape[:-1]
        height = np.full(shape, float(self.floor_m))
        normal = np.zeros(shape + (3,))
        normal[..., 2] = 1.0
        flat = xy.reshape(-1, 2)
        boxes = self._boxes
        near = np.flatnonzero(((flat[:, None, 0] >= boxes[:, 0]) & (flat[:, None, 1] >= boxes[:, 1])
                               & (flat[:, None, 0] <= boxes[:, 2]) & (flat[:, None, 1] <= boxes[:, 3])).any(axis=0))
        for piece in (self.pieces[k] for k in near):
            inside = piece.contains(xy)
            if not np.any(inside):
                continue
            points = xy[inside]
            h = piece.height(points)
            higher = h > height[inside]
            where = np.flatnonzero(inside.ravel())[higher]
            height.reshape(-1)[where] = h[higher]
            normal.reshape(-1, 3)[where] = piece.normal(points[higher])
        return height, normal

    def height(self, xy) -> np.ndarray:
        return self.height_normal(xy)[0]

    def normal(self, xy) -> np.ndarray:
        return self.height_normal(xy)[1]

    def piece_at(self, xy) -> list[str | None]:
        """The name of the piece under each point (None: the floor)."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        out: list[str | None] = [None] * len(xy)
        height = np.full(len(xy), float(self.floor_m))
        for piece in self.pieces:
            inside = piece.contains(xy)
            h = np.where(inside, piece.height(xy), -np.inf)
            for k in np.flatnonzero(h > height):
                out[k], height[k] = piece.name, h[k]
        return out

    def bounds(self) -> tuple[float, float, float, float] | None:
        """(x_min, y_min, x_max, y_max) of the pieces' footprints; None on a flat terrain."""
        if not self.pieces:
            return None
        points = np.concatenate([p.corners() for p in self.pieces])
        return (*points.min(axis=0), *points.max(axis=0))

    def raster(self, resolution_m: float = 0.01, margin_m: float = 0.5) -> "TerrainRaster":
        """The heights and normals sampled at the centres of a grid over the pieces' bounds plus `margin_m` (cached;
        coarser than asked if the grid would exceed RASTER_MAX_CELLS)."""
        key = (float(resolution_m), float(margin_m))
        if key not in self._raster_cache:
            self._raster_cache[key] = TerrainRaster.of(self, resolution_m, margin_m)
        return self._raster_cache[key]

    def to_dict(self) -> dict:
        """The YAML description (`wbmpc.terrain.spec.save_terrain`)."""
        out: dict = {"name": self.name, "floor": float(self.floor_m)}
        for kind, key in (("box", "boxes"), ("ramp", "ramps"), ("heightmap", "heightmaps")):
            items = [p.to_dict() for p in self.pieces if p.kind == kind]
            if items:
                out[key] = items
        return out

    def __getstate__(self):  # the raster is rebuilt on demand (pickled into the real-time solver process)
        state = dict(self.__dict__)
        state["_raster_cache"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)


@dataclass(frozen=True)
class TerrainRaster:
    """Heights (rows along y, columns along x) and normals at cell centres: cell (i, j) is centred at
    x = origin_x + (j + 1/2) resolution, y = origin_y + (i + 1/2) resolution; outside the grid, the floor."""

    heights_m: np.ndarray
    normals: np.ndarray
    origin_m: np.ndarray
    resolution_m: float
    floor_m: float

    @classmethod
    def of(cls, terrain: Terrain, resolution_m: float, margin_m: float) -> "TerrainRaster":
        bounds = terrain.bounds()
        if bounds is None:
            bounds = (-margin_m, -margin_m, margin_m, margin_m)
        x0, y0, x1, y1 = bounds[0] - margin_m, bounds[1] - margin_m, bounds[2] + margin_m, bounds[3] + margin_m
        cells = (x1 - x0) * (y1 - y0) / resolution_m**2
        if cells > RASTER_MAX_CELLS:
            resolution_m *= float(np.sqrt(cells / RASTER_MAX_CELLS))
        nx, ny = int(np.ceil((x1 - x0) / resolution_m)), int(np.ceil((y1 - y0) / resolution_m))
        xs = x0 + (np.arange(nx) + 0.5) * resolution_m
        ys = y0 + (np.arange(ny) + 0.5) * resolution_m
        grid = np.stack(np.meshgrid(xs, ys), axis=-1)  # (ny, nx, 2)
        heights, normals = terrain.height_normal(grid)
        return cls(heights, normals, np.array([x0, y0]), float(resolution_m), float(terrain.floor_m))

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights_m.shape

    def cell(self, xy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, column, inside the grid) of points xy (..., 2)."""
        g = np.floor((np.asarray(xy, dtype=float) - self.origin_m) / self.resolution_m).astype(np.intp)
        j, i = g[..., 0], g[..., 1]
        rows, cols = self.heights_m.shape
        inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
        # (np.minimum / np.maximum: np.clip's wrappers cost more than the lookup on the MPC's small arrays)
        return np.minimum(np.maximum(i, 0), rows - 1), np.minimum(np.maximum(j, 0), cols - 1), inside

    def centre(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return self.origin_m + (np.stack([j, i], axis=-1) + 0.5) * self.resolution_m

    def height(self, xy) -> np.ndarray:
        i, j, inside = self.cell(xy)
        return np.where(inside, self.heights_m[i, j], self.floor_m)

    def path_heights(self, start_xy, end_xy, radius_m: float = 0.0) -> np.ndarray:
        """The highest ground under a disc of `radius_m` (its centre, and `radius_m` ahead, behind and to either
        side) at samples every half cell along the segment start -> end (one pair of points (2,)): what a foot of
        that size passes over."""
        start, end = np.asarray(start_xy, dtype=float), np.asarray(end_xy, dtype=float)
        length = float(np.linalg.norm(end - start))
        direction = (end - start) / length if length > 1e-9 else np.array([1.0, 0.0])
        side = np.array([-direction[1], direction[0]])
        n = int(np.clip(np.ceil(length / (0.5 * self.resolution_m)), 1, 400)) + 1
        centres = start + np.linspace(0.0, 1.0, n)[:, None] * (end - start)
        offsets = radius_m * np.array([[0.0, 0.0], direction, -direction, side, -side])
        return self.height(centres[None] + offsets[:, None]).max(axis=0)

    def max_height_along(self, start_xy, end_xy, radius_m: float = 0.0) -> np.ndarray:
        """Highest sampled height on each segment start -> end (arrays (..., 2)), widened by `radius_m` on
        either side (three parallel lines) and at both ends."""
        start, end = np.asarray(start_xy, dtype=float), np.asarray(end_xy, dtype=float)
        length = np.linalg.norm(end - start, axis=-1)
        n = int(np.clip(np.ceil(np.max(length, initial=0.0) / (0.5 * self.resolution_m)), 1, 400)) + 1
        share = np.linspace(0.0, 1.0, n)
        direction = np.where(length[..., None] > 1e-9, (end - start) / np.maximum(length, 1e-9)[..., None], [1.0, 0.0])
        side = np.stack([-direction[..., 1], direction[..., 0]], axis=-1)
        best = np.full(start.shape[:-1], -np.inf)
        for offset in (-radius_m, 0.0, radius_m):  # three lines across the foot's width
            a = start - radius_m * direction + offset * side
            b = end + radius_m * direction + offset * side
            points = a[..., None, :] + share[:, None] * (b - a)[..., None, :]
            best = np.maximum(best, self.height(points).max(axis=-1))
        return best


def _renamed(piece: Piece, name: str) -> Piece:
    from dataclasses import replace

    return replace(piece, name=name)


def _overlap_depth(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest penetration of two convex polygons over the separating axes (<= 0: apart or touching)."""
    depth = np.inf
    for polygon in (a, b):
        edges = np.roll(polygon, -1, axis=0) - polygon
        for edge in edges:
            axis = np.array([-edge[1], edge[0]])
            norm = np.linalg.norm(axis)
            if norm < 1e-12:
                continue
            axis /= norm
            pa, pb = a @ axis, b @ axis
            depth = min(depth, min(pa.max(), pb.max()) - max(pa.min(), pb.min()))
    return float(depth)


def _overlap_box(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float, float]:
    low = np.maximum(a.min(axis=0), b.min(axis=0))
    high = np.minimum(a.max(axis=0), b.max(axis=0))
    return float(low[0]), float(low[1]), float(high[0]), float(high[1])
