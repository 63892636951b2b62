"""The ground under a robot's support: a plane fitted to the terrain around its feet.

`SupportFootprint` samples the terrain at each foot's nominal place around the base (in the heading frame)
and `reach_m` ahead of and behind it, and fits the plane z = c0 + c1 x + c2 y (heading frame, about the base)
by least squares: c0 is the height under the base, c1 the slope along the heading. The MPC's base height and
pitch targets follow it (`wbmpc.control.terrain_references`), the fall check and the scenarios' hand
references measure heights from it. The fit's pseudo-inverse is the same for every pose (the samples are
fixed in the heading frame): one matrix product per query, vectorised over poses, on the terrain's 1 cm raster (the
fits run on every MPC step and, for the fall check, every control tick).
"""

from __future__ import annotations

import numpy as np

from wbmpc.terrain.terrain import Terrain

SAMPLES_ALONG = 11  # per foot, from -reach to +reach along the heading


class SupportFootprint:
    """Plane fits of the terrain under a robot whose feet stand at `foot_offsets_m` ((n_feet, 2), heading frame,
    relative to the base) and step up to `reach_m` ahead or behind."""

    def __init__(self, terrain: Terrain, foot_offsets_m: np.ndarray, reach_m: float):
        self.terrain = terrain
        self._raster = terrain.raster()  # 1 cm cells: the fits run on every MPC step and every control tick
        offsets = np.asarray(foot_offsets_m, dtype=float).reshape(-1, 2)
        along = np.linspace(-reach_m, reach_m, SAMPLES_ALONG)
        self.samples_m = (offsets[:, None, :] + np.stack([along, np.zeros_like(along)], axis=-1)[None]).reshape(-1, 2)
        design = np.column_stack([np.ones(len(self.samples_m)), self.samples_m])
        self._design = design
        self._fit = np.linalg.pinv(design)  # (3, samples)

    def plane(self, xy, yaw) -> np.ndarray:
        """(..., 4) [c0, c1, c2, rms]: height under the base, slope along and across the heading and the RMS of the
        terrain about that plane (0 on a plane, about rise / (2 sqrt 3) on stairs), for base positions xy (..., 2)
        and headings yaw (...)."""
        xy, yaw = np.asarray(xy, dtype=float), np.asarray(yaw, dtype=float)
        c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
        dx, dy = self.samples_m[:, 0], self.samples_m[:, 1]
        points = np.stack([xy[..., None, 0] + c * dx - s * dy, xy[..., None, 1] + s * dx + c * dy], axis=-1)
        heights = self._raster.height(points)  # (..., samples)
        fit = heights @ self._fit.T
        residual = heights - fit @ self._design.T
        return np.concatenate([fit, np.sqrt(np.mean(residual**2, axis=-1, keepdims=True))], axis=-1)

    def height(self, xy, yaw) -> np.ndarray:
        """The support's height under the base (c0)."""
        return self.plane(xy, yaw)[..., 0]
