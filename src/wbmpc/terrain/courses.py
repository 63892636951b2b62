"""Terrains of the `stairs`, `slope` and `stepping-stones` scenarios, built from a few numbers.

Each course runs along +x from `start_x_m` (where its first riser, ramp or gap begins), `width_m` wide and
centred on y = 0; the robot starts on the floor before it (or, stepping stones, on a platform at the
stones' height) and walks across.
"""

from __future__ import annotations

import numpy as np

from wbmpc.errors import check_number
from wbmpc.terrain.pieces import Box, Ramp, TerrainError
from wbmpc.terrain.terrain import Terrain

STAIRS_DIRECTIONS = ("up-down", "up", "down")


def stairs(steps: int, rise_m: float, tread_m: float, start_x_m: float, width_m: float = 2.0,
           landing_m: float = 1.2, direction: str = "up-down") -> Terrain:
    """`steps` risers of `rise_m` every `tread_m`: "up" ends on a landing `landing_m` long at the top; "up-down"
    continues down as many risers after that landing; "down" starts on a landing (the robot placed on it, ending
    at `start_x_m`) and goes down."""
    check_number("steps", steps, low=1, high=100)
    check_number("rise_m", rise_m, low=0.0, low_open=True, high=1.0, unit="m")
    check_number("tread_m", tread_m, low=0.05, high=5.0, unit="m")
    check_number("landing_m", landing_m, low=0.05, high=50.0, unit="m")
    if direction not in STAIRS_DIRECTIONS:
        raise TerrainError(f"stairs direction must be one of {', '.join(STAIRS_DIRECTIONS)}, got {direction!r}")
    pieces: list[Box] = []
    x = start_x_m

    def block(length: float, top: float, name: str) -> None:
        nonlocal x
        pieces.append(Box((x + 0.5 * length, 0.0), (length, width_m), top, name=name))
        x += length

    if direction == "down":
        x = start_x_m - landing_m
        block(landing_m, steps * rise_m, "landing")
        for k in range(steps - 1, 0, -1):
            block(tread_m, k * rise_m, f"down {steps - k}")
        return Terrain(tuple(pieces), name=f"stairs down {steps} x {100 * rise_m:g} cm")
    for k in range(1, steps):
        block(tread_m, k * rise_m, f"up {k}")
    block(landing_m, steps * rise_m, "landing")
    if direction == "up-down":
        for k in range(steps - 1, 0, -1):
            block(tread_m, k * rise_m, f"down {steps - k}")
    return Terrain(tuple(pieces), name=f"stairs {direction} {steps} x {100 * rise_m:g} / {100 * tread_m:g} cm")


def slope(angle_deg: float, start_x_m: float, run_m: float = 1.5, plateau_m: float = 1.0, width_m: float = 2.0) -> Terrain:
    """A ramp rising at `angle_deg` over `run_m` (horizontal), a plateau `plateau_m` long and a ramp down at the
    same angle."""
    check_number("angle_deg", angle_deg, low=0.0, low_open=True, high=45.0, unit="deg")
    check_number("run_m", run_m, low=0.1, high=50.0, unit="m")
    height = run_m * float(np.tan(np.deg2rad(angle_deg)))
    x0, x1, x2, x3 = start_x_m, start_x_m + run_m, start_x_m + run_m + plateau_m, start_x_m + 2 * run_m + plateau_m
    pieces = (Ramp((x0, 0.0, 0.0), (x1, 0.0, height), width_m, name="up"),
              Box((0.5 * (x1 + x2), 0.0), (plateau_m, width_m), height, name="plateau"),
              Ramp((x2, 0.0, height), (x3, 0.0, 0.0), width_m, name="down"))
    return Terrain(pieces, name=f"slope {angle_deg:g} deg")


def stepping_stones(gap_m: float, start_x_m: float, stone_m: float = 0.25, stones: int = 8, rows: int = 4,
                    depth_m: float = 0.4, platform_m: float = 1.5) -> Terrain:
    """A platform ending at `start_x_m`, `stones` columns of square stones `stone_m` wide with `gap_m` between them
    (in x and y; `rows` of them centred on y = 0), and a platform after: all tops at 0, the floor `depth_m` below."""
    check_number("gap_m", gap_m, low=0.0, high=1.0, unit="m")
    check_number("stone_m", stone_m, low=0.05, high=2.0, unit="m")
    check_number("depth_m", depth_m, low=0.05, high=5.0, unit="m")
    pitch = stone_m + gap_m
    width = rows * pitch - gap_m
    pieces = [Box((start_x_m - 0.5 * platform_m, 0.0), (platform_m, width), 0.0, name="start")]
    ys = (np.arange(rows) - 0.5 * (rows - 1)) * pitch
    for k in range(stones):
        x = start_x_m + gap_m + 0.5 * stone_m + k * pitch
        pieces += [Box((x, float(y)), (stone_m, stone_m), 0.0, name=f"stone {k + 1}.{r + 1}") for r, y in enumerate(ys)]
    end = start_x_m + stones * pitch + gap_m
    pieces.append(Box((end + 0.5 * platform_m, 0.0), (platform_m, width), 0.0, name="end"))
    return Terrain(tuple(pieces), floor_m=-depth_m, name=f"stepping stones, {100 * gap_m:g} cm gaps")


def course_end_x(terrain: Terrain) -> float:
    """Where the course's last piece ends along x."""
    bounds = terrain.bounds()
    return float(bounds[2]) if bounds is not None else 0.0
