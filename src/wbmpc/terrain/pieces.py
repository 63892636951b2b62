"""The pieces a terrain is made of: boxes, ramps and heightmaps, each with its footprint, height and normal.

Every piece answers for points (x, y) inside its footprint (vectorised over any number of points):
`contains(xy)`, `height(xy)`, `normal(xy)`. Coordinates are world metres; heights are the top surface.

- `Box`: a block from `bottom_m` (the floor by default) up to `top_m` over a rectangle (centre, size, yaw):
  a step, a stepping stone, a platform.
- `Ramp`: a plane rising linearly from `start_m` (x, y, z of the middle of its first edge) to `end_m`, `width_m`
  wide, standing on the floor: a slope.
- `Heightmap`: heights on a regular grid (`heights_m[i, j]` at x = origin_x + j r, y = origin_y + i r, r the
  resolution), linear on the two triangles of each cell split along the diagonal from (i, j) to (i + 1, j + 1):
  the surface MuJoCo's height field collides with (`wbmpc.sim.terrain_geoms`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.errors import ConfigError

MAX_HEIGHTMAP_CELLS = 4_000_000  # a 2000 x 2000 grid: beyond it MuJoCo's height field and our queries get slow


class TerrainError(ConfigError):
    """A terrain description that cannot be built: the message names the piece (and the file) and the fix."""


def _vector(name: str, value, size: int, label: str) -> np.ndarray:
    array = np.asarray(value, dtype=float).ravel() if value is not None else np.zeros(0)
    if array.size != size or not np.all(np.isfinite(array)):
        raise TerrainError(f"{label}: {name} needs {size} finite numbers, got {value!r}")
    return array


def _floats(values) -> list[float]:
    return [float(v) for v in values]


def _rotation(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s], [s, c]])


def _up(count: tuple[int, ...]) -> np.ndarray:
    out = np.zeros(count + (3,))
    out[..., 2] = 1.0
    return out


@dataclass(frozen=True)
class Box:
    """A block over the rectangle `size_m` (length along its x, width along its y) centred at `centre_m`, turned
    by `yaw_deg`, from `bottom_m` (None: the terrain's floor) up to `top_m`."""

    centre_m: tuple[float, float]
    size_m: tuple[float, float]
    top_m: float
    bottom_m: float | None = None
    yaw_deg: float = 0.0
    name: str = ""

    kind = "box"

    def __post_init__(self):
        label = f"box '{self.name}'" if self.name else "box"
        object.__setattr__(self, "centre_m", tuple(_vector("centre", self.centre_m, 2, label)))
        size = _vector("size", self.size_m, 2, label)
        if np.any(size <= 0):
            raise TerrainError(f"{label}: size must be two positive lengths (x, y in m), got {tuple(size)}")
        object.__setattr__(self, "size_m", tuple(size))
        if not np.isfinite(self.top_m) or not np.isfinite(self.yaw_deg):
            raise TerrainError(f"{label}: top and yaw_deg must be finite numbers")
        if self.bottom_m is not None and not self.bottom_m < self.top_m:
            raise TerrainError(f"{label}: its bottom ({self.bottom_m:g} m) must lie below its top ({self.top_m:g} m)")

    @property
    def top_max_m(self) -> float:
        return float(self.top_m)

    def corners(self) -> np.ndarray:
        """(4, 2) footprint corners, counter-clockwise."""
        half = 0.5 * np.asarray(self.size_m)
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return local @ _rotation(np.deg2rad(self.yaw_deg)).T + np.asarray(self.centre_m)

    def _local(self, xy: np.ndarray) -> np.ndarray:
        return (xy - np.asarray(self.centre_m)) @ _rotation(np.deg2rad(self.yaw_deg))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        local = self._local(xy)
        half = 0.5 * np.asarray(self.size_m)
        return np.all(np.abs(local) <= half + 1e-12, axis=-1)

    def height(self, xy: np.ndarray) -> np.ndarray:
        return np.full(np.shape(xy)[:-1], float(self.top_m))

    def normal(self, xy: np.ndarray) -> np.ndarray:
        return _up(np.shape(xy)[:-1])

    def to_dict(self) -> dict:
        out = {"name": self.name, "centre": _floats(self.centre_m), "size": _floats(self.size_m), "top": float(self.top_m)}
        if self.bottom_m is not None:
            out["bottom"] = float(self.bottom_m)
        if self.yaw_deg:
            out["yaw_deg"] = float(self.yaw_deg)
        return out


@dataclass(frozen=True)
class Ramp:
    """A plane from `start_m` (x, y, z: the middle of its first edge) to `end_m`, `width_m` wide, standing on the
    floor: its surface height rises linearly along the axis from start to end."""

    start_m: tuple[float, float, float]
    end_m: tuple[float, float, float]
    width_m: float
    name: str = ""

    kind = "ramp"

    def __post_init__(self):
        label = f"ramp '{self.name}'" if self.name else "ramp"
        start = _vector("start", self.start_m, 3, label)
        end = _vector("end", self.end_m, 3, label)
        object.__setattr__(self, "start_m", tuple(start))
        object.__setattr__(self, "end_m", tuple(end))
        if not (np.isfinite(self.width_m) and self.width_m > 0):
            raise TerrainError(f"{label}: width must be a positive length in m, got {self.width_m!r}")
        if np.linalg.norm(end[:2] - start[:2]) < 1e-3:
            raise TerrainError(f"{label}: start and end lie at the same x, y ({start[:2]}): a ramp needs a length")

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.end_m[:2], self.start_m[:2])))

    @property
    def axis(self) -> np.ndarray:
        return np.subtract(self.end_m[:2], self.start_m[:2]) / self.length_m

    @property
    def slope(self) -> float:
        """Rise per metre along the axis."""
        return (self.end_m[2] - self.start_m[2]) / self.length_m

    @property
    def top_max_m(self) -> float:
        return float(max(self.start_m[2], self.end_m[2]))

    @property
    def top_min_m(self) -> float:
        return float(min(self.start_m[2], self.end_m[2]))

    def corners(self) -> np.ndarray:
        axis = self.axis
        side = 0.5 * self.width_m * np.array([-axis[1], axis[0]])
        start, end = np.asarray(self.start_m[:2]), np.asarray(self.end_m[:2])
        return np.array([start - side, end - side, end + side, start + side])

    def _local(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        axis = self.axis
        relative = xy - np.asarray(self.start_m[:2])
        return relative @ axis, relative @ np.array([-axis[1], axis[0]])

    def contains(self, xy: np.ndarray) -> np.ndarray:
        along, across = self._local(xy)
        return (along >= -1e-12) & (along <= self.length_m + 1e-12) & (np.abs(across) <= 0.5 * self.width_m + 1e-12)

    def height(self, xy: np.ndarray) -> np.ndarray:
        along, _ = self._local(xy)
        return self.start_m[2] + self.slope * np.clip(along, 0.0, self.length_m)

    def normal(self, xy: np.ndarray) -> np.ndarray:
        gradient = self.slope * self.axis
        n = np.array([-gradient[0], -gradient[1], 1.0]) / np.sqrt(1.0 + self.slope**2)
        return np.broadcast_to(n, np.shape(xy)[:-1] + (3,)).copy()

    def to_dict(self) -> dict:
        return {"name": self.name, "start": _floats(self.start_m), "end": _floats(self.end_m), "width": float(self.width_m)}


@dataclass(frozen=True, eq=False)
class Heightmap:
    """Heights on a grid: `heights_m[i, j]` at x = origin_x + j resolution, y = origin_y + i resolution (rows along
    y, columns along x; an image's top row is its largest y, see `wbmpc.terrain.spec`)."""

    heights_m: np.ndarray = field(repr=False)
    resolution_m: float
    origin_m: tuple[float, float] = (0.0, 0.0)
    name: str = ""
    source: str | None = None  # the file the heights came from (for messages and to_dict)

    kind = "heightmap"

    def __post_init__(self):
        label = f"heightmap '{self.name}'" if self.name else "heightmap"
        heights = np.asarray(self.heights_m)
        if heights.ndim != 2:
            raise TerrainError(f"{label}: the heights must be a 2D array (rows along y, columns along x), got an array "
                               f"of shape {heights.shape}" + (" (an RGB image? save it as grayscale)" if heights.ndim == 3
                                                              else ""))
        if min(heights.shape) < 2:
            raise TerrainError(f"{label}: needs at least 2 x 2 heights, got {heights.shape}")
        if heights.size > MAX_HEIGHTMAP_CELLS:
            raise TerrainError(f"{label}: {heights.shape[0]} x {heights.shape[1]} heights exceed {MAX_HEIGHTMAP_CELLS}; "
                               "resample it coarser")
        try:
            heights = heights.astype(float)
        except (TypeError, ValueError):
            raise TerrainError(f"{label}: the heights must be numbers") from None
        bad = np.argwhere(~np.isfinite(heights))
        if bad.size:
            raise TerrainError(f"{label}: height at row {bad[0][0]}, column {bad[0][1]} is not a finite number")
        heights.setflags(write=False)
        object.__setattr__(self, "heights_m", heights)
        if not (np.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise TerrainError(f"{label}: resolution must be a positive length in m (grid spacing), got "
                               f"{self.resolution_m!r}")
        object.__setattr__(self, "origin_m", tuple(_vector("origin", self.origin_m, 2, label)))

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights_m.shape

    @property
    def extent_m(self) -> tuple[float, float]:
        """Lengths along x and y."""
        rows, cols = self.shape
        return (cols - 1) * self.resolution_m, (rows - 1) * self.resolution_m

    @property
    def top_max_m(self) -> float:
        return float(self.heights_m.max())

    def corners(self) -> np.ndarray:
        x0, y0 = self.origin_m
        lx, ly = self.extent_m
        return np.array([[x0, y0], [x0 + lx, y0], [x0 + lx, y0 + ly], [x0, y0 + ly]])

    def contains(self, xy: np.ndarray) -> np.ndarray:
        x0, y0 = self.origin_m
        lx, ly = self.extent_m
        x, y = xy[..., 0] - x0, xy[..., 1] - y0
        return (x >= -1e-12) & (x <= lx + 1e-12) & (y >= -1e-12) & (y <= ly + 1e-12)

    def _cells(self, xy: np.ndarray):
        rows, cols = self.shape
        gx = (xy[..., 0] - self.origin_m[0]) / self.resolution_m
        gy = (xy[..., 1] - self.origin_m[1]) / self.resolution_m
        j = np.clip(np.floor(gx).astype(int), 0, cols - 2)
        i = np.clip(np.floor(gy).astype(int), 0, rows - 2)
        fx, fy = np.clip(gx - j, 0.0, 1.0), np.clip(gy - i, 0.0, 1.0)
        h = self.heights_m
        return fx, fy, h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]

    def height(self, xy: np.ndarray) -> np.ndarray:
        fx, fy, h00, h10, h01, h11 = self._cells(xy)
        lower = fx >= fy  # the triangle (0, 0), (1, 0), (1, 1); else (0, 0), (0, 1), (1, 1)
        return np.where(lower, h00 + fx * (h10 - h00) + fy * (h11 - h10), h00 + fy * (h01 - h00) + fx * (h11 - h01))

    def normal(self, xy: np.ndarray) -> np.ndarray:
        fx, fy, h00, h10, h01, h11 = self._cells(xy)
        lower = fx >= fy
        r = self.resolution_m
        dx = np.where(lower, h10 - h00, h11 - h01) / r
        dy = np.where(lower, h11 - h10, h01 - h00) / r
        n = np.stack([-dx, -dy, np.ones_like(dx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def to_dict(self) -> dict:
        out = {"name": self.name, "resolution": float(self.resolution_m), "origin": _floats(self.origin_m)}
        if self.source is not None and self.source.lower().endswith((".npy", ".csv", ".txt")):
            out["file"] = self.source  # heights in m, read again as they are
        else:
            out["heights"] = self.heights_m.tolist()
        return out


Piece = Box | Ramp | Heightmap
