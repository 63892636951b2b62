"""Terrain files: a YAML description of boxes, ramps and heightmaps (`load_terrain`, `save_terrain`).

```yaml
name: lab stairs            # optional
floor: 0.0                  # m, the ground where no piece stands (optional, 0)
boxes:                      # blocks from the floor (or `bottom`) up to `top`
  - {name: step 1, centre: [1.0, 0.0], size: [0.3, 2.0], top: 0.12}        # size: x, y lengths; yaw_deg: 0
ramps:                      # planes rising from start (x, y, z) to end, `width` wide
  - {name: ramp, start: [3.0, 0.0, 0.0], end: [4.5, 0.0, 0.4], width: 2.0}
heightmaps:                 # heights on a grid of `resolution` m, row 0 at origin y (the lowest), column 0 at origin x
  - {name: rubble, file: rubble.png, resolution: 0.02, origin: [5.0, -1.0], height_range: [0.0, 0.1]}
  - {name: bump, heights: [[0, 0, 0], [0, 0.05, 0], [0, 0, 0]], resolution: 0.1, origin: [7.0, 0.0]}
```

Heightmap files: `.npy` (a 2D array of heights in m, rows along y), `.csv`/`.txt` (the same as text) or a
grayscale image (`.png`, ...: black is the first of `height_range`, white the second; the image's top row is
the map's largest y, as the image is seen from above with x to the right). Relative paths are read from the
YAML file's folder. Every error names the file and the piece.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from wbmpc.terrain.pieces import Box, Heightmap, Ramp, TerrainError
from wbmpc.terrain.terrain import Terrain

TOP_KEYS = ("name", "floor", "boxes", "ramps", "heightmaps")
PIECE_KEYS = {
    "boxes": ({"centre", "size", "top"}, {"name", "bottom", "yaw_deg"}),
    "ramps": ({"start", "end", "width"}, {"name"}),
    "heightmaps": ({"resolution"}, {"name", "file", "heights", "origin", "height_range"}),
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")


def load_terrain(path: str | Path) -> Terrain:
    """The terrain of a YAML file (see the module docstring); `TerrainError` names what is wrong and where."""
    path = Path(path)
    if not path.is_file():
        raise TerrainError(f"terrain file {path} does not exist" + (" (a folder)" if path.is_dir() else ""))
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise TerrainError(f"terrain {path}: not valid YAML: {exc}") from None
    return terrain_from_dict(data if data is not None else {}, source=str(path), folder=path.parent)


def terrain_from_dict(data, source: str = "(dict)", folder: Path | None = None) -> Terrain:
    """A terrain from its description as nested dicts and lists (a parsed YAML file)."""
    if not isinstance(data, dict):
        raise TerrainError(f"terrain {source}: the file must hold a mapping with {', '.join(TOP_KEYS)}, got "
                           f"{type(data).__name__}")
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise TerrainError(f"terrain {source}: unknown key(s) {', '.join(map(str, unknown))}; known: {', '.join(TOP_KEYS)}")
    pieces = []
    for key, build in (("boxes", _box), ("ramps", _ramp), ("heightmaps", _heightmap)):
        items = data.get(key) or []
        if not isinstance(items, list):
            raise TerrainError(f"terrain {source}: '{key}' must be a list of mappings, got {type(items).__name__}")
        for k, item in enumerate(items):
            label = f"terrain {source}: {key}[{k}]" + (f" ({item['name']})" if isinstance(item, dict) and "name" in item
                                                       else "")
            if not isinstance(item, dict):
                raise TerrainError(f"{label} must be a mapping, got {item!r}")
            required, optional = PIECE_KEYS[key]
            missing = sorted(required - set(item))
            if missing:
                raise TerrainError(f"{label}: missing {', '.join(missing)}")
            extra = sorted(set(item) - required - optional)
            if extra:
                raise TerrainError(f"{label}: unknown key(s) {', '.join(map(str, extra))}; known: "
                                   f"{', '.join(sorted(required | optional))}")
            try:
                pieces.append(build(item, folder))
            except TerrainError as exc:
                raise TerrainError(f"{label}: {exc}") from None
            except (TypeError, ValueError) as exc:
                raise TerrainError(f"{label}: {exc}") from None
    floor = data.get("floor", 0.0)
    if not isinstance(floor, (int, float)) or isinstance(floor, bool):
        raise TerrainError(f"terrain {source}: floor must be a number (m), got {floor!r}")
    return Terrain(tuple(pieces), float(floor), name=str(data.get("name") or Path(source).stem), source=source)


def save_terrain(terrain: Terrain, path: str | Path) -> Path:
    """Write `terrain` as YAML (heightmaps read from a file keep its path; others are written inline)."""
    path = Path(path)
    path.write_text("# wbmpc terrain (docs/terrain.md)\n" + yaml.safe_dump(terrain.to_dict(), sort_keys=False))
    return path


def _number(item: dict, key: str) -> float:
    value = item[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TerrainError(f"{key} must be a number, got {value!r}")
    return float(value)


def _box(item: dict, folder) -> Box:
    return Box(centre_m=item["centre"], size_m=item["size"], top_m=_number(item, "top"),
               bottom_m=_number(item, "bottom") if "bottom" in item else None,
               yaw_deg=_number(item, "yaw_deg") if "yaw_deg" in item else 0.0, name=str(item.get("name", "")))


def _ramp(item: dict, folder) -> Ramp:
    return Ramp(start_m=item["start"], end_m=item["end"], width_m=_number(item, "width"), name=str(item.get("name", "")))


def _heightmap(item: dict, folder) -> Heightmap:
    if ("file" in item) == ("heights" in item):
        raise TerrainError("give either 'file' (an image, .npy or .csv) or 'heights' (a list of rows)")
    source = None
    if "heights" in item:
        heights = _array(item["heights"])
    else:
        source = str(item["file"])
        file = Path(source) if folder is None or Path(source).is_absolute() else Path(folder) / source
        heights = read_heightmap(file, item.get("height_range"))
    if "height_range" in item and "file" in item and Path(str(item["file"])).suffix.lower() not in IMAGE_SUFFIXES:
        raise TerrainError("height_range scales images only; a .npy or .csv file holds heights in m")
    return Heightmap(heights, _number(item, "resolution"), origin_m=item.get("origin", (0.0, 0.0)),
                     name=str(item.get("name", "")), source=source)


def _array(rows) -> np.ndarray:
    try:
        return np.asarray(rows, dtype=float)
    except (TypeError, ValueError):
        lengths = sorted({len(r) for r in rows if isinstance(r, list)}) if isinstance(rows, list) else []
        hint = f" (rows of {', '.join(map(str, lengths))} values)" if len(lengths) > 1 else ""
        raise TerrainError(f"heights must be a 2D array of numbers, rows of equal length{hint}") from None


def read_heightmap(file: Path, height_range=None) -> np.ndarray:
    """Heights (rows along y, row 0 the lowest y) from a .npy, .csv/.txt or grayscale image file."""
    if not file.is_file():
        raise TerrainError(f"heightmap file {file} does not exist")
    suffix = file.suffix.lower()
    if suffix == ".npy":
        return np.load(file, allow_pickle=False)
    if suffix in (".csv", ".txt"):
        return np.loadtxt(file, delimiter="," if suffix == ".csv" else None, ndmin=2)
    if suffix in IMAGE_SUFFIXES:
        from PIL import Image

        with Image.open(file) as image:
            if image.mode not in ("L", "I", "I;16", "F", "1", "P", "LA"):
                raise TerrainError(f"heightmap image {file} is {image.mode}, not grayscale: save it as 8- or 16-bit "
                                   "gray (RGB pixels hold no single height)")
            pixels = np.asarray(image.convert("F") if image.mode not in ("I;16", "I") else image, dtype=float)
            full = {"I;16": 65535.0, "I": 65535.0}.get(image.mode, 255.0)
        if height_range is None:
            raise TerrainError(f"heightmap image {file} needs height_range: [black m, white m]")
        low, high = _pair(height_range)
        return (low + (high - low) * pixels / full)[::-1]  # the image's top row is the largest y
    raise TerrainError(f"heightmap file {file}: unknown kind '{suffix}'; use .npy, .csv, .txt or a grayscale image "
                       f"({', '.join(IMAGE_SUFFIXES)})")


def _pair(value) -> tuple[float, float]:
    array = np.asarray(value, dtype=float).ravel()
    if array.size != 2 or not np.all(np.isfinite(array)):
        raise TerrainError(f"height_range needs two numbers [black m, white m], got {value!r}")
    return float(array[0]), float(array[1])
