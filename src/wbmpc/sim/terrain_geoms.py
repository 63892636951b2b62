"""MuJoCo geometry of a `wbmpc.terrain.Terrain`: boxes, ramps as convex wedge meshes, heightmaps as height fields.

Each piece becomes one static geom named `terrain:<piece name>` (the contact metrics find the piece a robot geom
touches by that name); the floor plane moves to the terrain's floor height. A height field samples its heights
at the grid points and MuJoCo interpolates linearly on the triangles that split each cell along the diagonal
from (i, j) to (i + 1, j + 1), as `Heightmap.height` does.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from wbmpc.terrain import Box, Heightmap, Ramp, Terrain

TERRAIN_PREFIX = "terrain:"
HFIELD_BASE_M = 0.05  # thickness of a height field's solid base below its lowest point
COLORS = (".55 .5 .45 1", ".62 .57 .5 1")  # alternating, so that steps stand out from each other


def geom_name(piece_name: str) -> str:
    return TERRAIN_PREFIX + piece_name


def add_terrain(root: ET.Element, asset: ET.Element, world: ET.Element, terrain: Terrain) -> None:
    """The terrain's geoms into an MJCF tree (assets for meshes and height fields); the floor plane named "floor"
    is moved to `terrain.floor_m`."""
    for geom in world.iter("geom"):
        if geom.get("name") == "floor" and terrain.floor_m:
            geom.set("pos", _v([0.0, 0.0, terrain.floor_m]))
    for k, piece in enumerate(terrain.pieces):
        color = COLORS[k % 2]
        name = geom_name(piece.name)
        if isinstance(piece, Box):
            bottom = terrain.floor_m if piece.bottom_m is None else piece.bottom_m
            half = [0.5 * piece.size_m[0], 0.5 * piece.size_m[1], 0.5 * (piece.top_m - bottom)]
            yaw = np.deg2rad(piece.yaw_deg)
            ET.SubElement(world, "geom", name=name, type="box", size=_v(half), rgba=color,
                          pos=_v([*piece.centre_m, 0.5 * (piece.top_m + bottom)]),
                          quat=_v([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]))
        elif isinstance(piece, Ramp):
            mesh = f"terrain_mesh_{k}"
            ET.SubElement(asset, "mesh", name=mesh, vertex=_v(ramp_vertices(piece, terrain.floor_m)))
            ET.SubElement(world, "geom", name=name, type="mesh", mesh=mesh, rgba=color)
        elif isinstance(piece, Heightmap):
            field_name = f"terrain_hfield_{k}"
            heights = piece.heights_m
            low, high = float(heights.min()), float(heights.max())
            span = high - low
            normalised = (heights - low) / span if span > 0 else np.zeros_like(heights)
            lx, ly = piece.extent_m
            rows, cols = piece.shape
            base = max(HFIELD_BASE_M, low - terrain.floor_m)  # down to the floor: no gap under a raised map
            # MJCF's elevation lists the top row (largest y) first
            ET.SubElement(asset, "hfield", name=field_name, nrow=str(rows), ncol=str(cols),
                          size=_v([0.5 * lx, 0.5 * ly, max(span, 1e-6), base]),
                          elevation=" ".join(f"{x:.9g}" for x in normalised[::-1].ravel()))
            ET.SubElement(world, "geom", name=name, type="hfield", hfield=field_name, rgba=color,
                          pos=_v([piece.origin_m[0] + 0.5 * lx, piece.origin_m[1] + 0.5 * ly, low]))


def ramp_vertices(ramp: Ramp, floor_m: float) -> np.ndarray:
    """(n, 3) vertices of the ramp's convex wedge: its top surface's corners and their feet on the floor (the
    feet of a corner on the floor already are dropped, MuJoCo's hull needs distinct points)."""
    corners = ramp.corners()  # start - side, end - side, end + side, start + side
    heights = [ramp.start_m[2], ramp.end_m[2], ramp.end_m[2], ramp.start_m[2]]
    top = [[x, y, z] for (x, y), z in zip(corners, heights)]
    feet = [[x, y, floor_m] for (x, y), z in zip(corners, heights) if z > floor_m + 1e-9]
    return np.array(top + feet)


def _v(values) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(values, dtype=float).ravel())


START_TOLERANCE_M = 0.005  # shapes this deep in the terrain at the start count as inside it
START_FLOAT_M = 0.03  # a foot this far above the terrain at the start would drop onto it


def check_start_pose(robot, terrain: Terrain, q: np.ndarray) -> None:
    """Refuse a start configuration with a robot shape inside the terrain or a foot above it (a TerrainError naming
    the shape, the terrain piece and where): the robot's collision shapes (`sim/shapes.py`) are sampled (sphere
    bottoms, box corners and faces, capsule and cylinder axes) and compared with the terrain's height under them."""
    import pinocchio as pin

    from wbmpc.sim.shapes import robot_collision_shapes
    from wbmpc.terrain import TerrainError

    model, data = robot.model, robot.model.createData()
    pin.forwardKinematics(model, data, q)
    worst = None  # (depth, shape name, point)
    feet = set(robot.feet)
    for shape in robot_collision_shapes(robot):
        placement = data.oMi[shape.joint_id]
        rotation = placement.rotation @ shape.rotation
        centre = placement.translation + placement.rotation @ shape.pos
        points, radius = _shape_points(shape, centre, rotation)
        ground = terrain.height(points[:, :2])
        depth = ground - (points[:, 2] - radius)
        k = int(np.argmax(depth))
        if depth[k] > START_TOLERANCE_M and (worst is None or depth[k] > worst[0]):
            worst = (float(depth[k]), shape.name, points[k])
        if shape.name in feet and -float(depth.max()) > START_FLOAT_M:
            point = points[int(np.argmax(depth))]
            raise TerrainError(f"the start pose leaves {shape.name} {100 * -float(depth.max()):.1f} cm above the terrain "
                               f"({_piece(terrain, point)}) at x {point[0]:.3f}, y {point[1]:.3f} m: the ground under "
                               "the robot's start must be level; move the terrain's pieces or the start")
    if worst is not None:
        depth, name, point = worst
        raise TerrainError(f"the start pose puts {name} {100 * depth:.1f} cm inside the terrain ({_piece(terrain, point)}) "
                           f"at x {point[0]:.3f}, y {point[1]:.3f} m: the robot starts at x {q[0]:.2f}, y {q[1]:.2f} m "
                           "on the level ground there; move the terrain's pieces away from it")


def _piece(terrain: Terrain, point: np.ndarray) -> str:
    name = terrain.piece_at(point[:2])[0]
    return f"{name!r}" if name is not None else "the floor"


def _shape_points(shape, centre: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, float]:
    """Sample points of a collision shape in the world and the radius to take off their height."""
    if shape.kind == "sphere":
        return centre[None], float(shape.size[0])
    if shape.kind in ("capsule", "cylinder"):
        radius, half = float(shape.size[0]), float(shape.size[1])
        along = np.linspace(-half, half, 5)[:, None] * rotation[:, 2]
        return centre + along, radius
    grid = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 1])).reshape(3, -1).T * np.asarray(shape.size)
    return centre + grid @ rotation.T, 0.0


REPLAY_COLOR = "#8c8073"
REPLAY_MAX_CELLS = 60  # a heightmap is drawn as at most this many columns of boxes per side


def replay_shapes(terrain: Terrain) -> list[dict]:
    """The terrain as static boxes for the HTML replay (`wbmpc.viz.replay`): boxes as they are, a ramp as a slab
    under its surface, a heightmap as columns of boxes (coarsened to REPLAY_MAX_CELLS a side)."""
    shapes = []
    for piece in terrain.pieces:
        if isinstance(piece, Box):
            bottom = terrain.floor_m if piece.bottom_m is None else piece.bottom_m
            yaw = np.deg2rad(piece.yaw_deg)
            rotation = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
            shapes.append(_replay_box(piece.name, [0.5 * piece.size_m[0], 0.5 * piece.size_m[1], 0.5 * (piece.top_m - bottom)],
                                      [*piece.centre_m, 0.5 * (piece.top_m + bottom)], rotation))
        elif isinstance(piece, Ramp):
            axis = np.r_[piece.axis, piece.slope] / np.sqrt(1.0 + piece.slope**2)
            normal = piece.normal(np.zeros((1, 2)))[0]
            rotation = np.column_stack([axis, np.cross(normal, axis), normal])
            thickness = 0.02
            middle = 0.5 * (np.asarray(piece.start_m) + np.asarray(piece.end_m)) - 0.5 * thickness * normal
            length = piece.length_m * np.sqrt(1.0 + piece.slope**2)
            shapes.append(_replay_box(piece.name, [0.5 * length, 0.5 * piece.width_m, 0.5 * thickness], middle, rotation))
        elif isinstance(piece, Heightmap):
            rows, cols = piece.shape
            step = max(1, int(np.ceil(max(rows, cols) / REPLAY_MAX_CELLS)))
            size = step * piece.resolution_m
            for i in range(0, rows, step):
                for j in range(0, cols, step):
                    top = float(piece.heights_m[i: i + step, j: j + step].mean())
                    x, y = piece.origin_m[0] + (j + 0.5 * step) * piece.resolution_m, \
                        piece.origin_m[1] + (i + 0.5 * step) * piece.resolution_m
                    shapes.append(_replay_box(f"{piece.name} {i}.{j}", [0.5 * size, 0.5 * size, 0.5 * (top - terrain.floor_m)],
                                              [x, y, 0.5 * (top + terrain.floor_m)], np.eye(3)))
    return shapes


def _replay_box(name: str, half, position, rotation) -> dict:
    return {"name": f"terrain {name}", "kind": "box", "color": REPLAY_COLOR, "half_size_m": np.asarray(half, dtype=float),
            "position_m": np.asarray(position, dtype=float), "rotation": np.asarray(rotation, dtype=float)}
