"""Terrain as data: boxes, ramps and heightmaps on a floor (`Terrain`), read from YAML files (`load_terrain`) or
built for the scenarios (`stairs`, `slope`, `stepping_stones`); safe footholds (`FootholdMap`). MuJoCo builds the
same geometry (`wbmpc.sim.terrain_geoms`) and the MPC reads heights and normals from here (see docs/terrain.md)."""

from wbmpc.terrain.courses import STAIRS_DIRECTIONS, course_end_x, slope, stairs, stepping_stones
from wbmpc.terrain.footholds import FootholdConfig, FootholdMap
from wbmpc.terrain.pieces import Box, Heightmap, Ramp, TerrainError
from wbmpc.terrain.spec import load_terrain, read_heightmap, save_terrain, terrain_from_dict
from wbmpc.terrain.terrain import Terrain, TerrainRaster

__all__ = ["Box", "FootholdConfig", "FootholdMap", "Heightmap", "Ramp", "STAIRS_DIRECTIONS", "Terrain", "TerrainError",
           "TerrainRaster", "course_end_x", "load_terrain", "read_heightmap", "save_terrain", "slope", "stairs",
           "stepping_stones", "terrain_from_dict"]
