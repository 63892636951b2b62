"""A self-contained HTML replay of a run with the robot's meshes: pinocchio's `MeshcatVisualizer` on
meshcat's offline viewer (three.js, shipped in the `meshcat` wheel), as Crocoddyl and aligator show
their trajectories.

`save_replay(robot, time_s, q, out_path)` loads the robot's geometry with pinocchio's URDF (or MJCF) parser
(visual meshes of example-robot-data; if they are missing: the file's collision geometry; if that is
missing too: the primitive shapes of the MuJoCo scene, `wbmpc.sim.shapes`, with a warning that says
so), draws it through `MeshcatVisualizer` into a recorder instead of a meshcat server, samples the
run at `fps` and records every geometry's placement (`pin.updateGeometryPlacements`) as one meshcat
animation frame. The page embeds the viewer's JavaScript and the recorded commands (msgpack, base64),
so it opens offline from the file; meshcat's "Animations" panel (top right) has play/pause, reset
and the time slider, and the mouse orbits (drag), pans (right drag) and zooms (wheel).

Meshes are decimated (vertex clustering, at most `MAX_TRIANGLES_PER_MESH` triangles each) and sent
as binary float32/uint32 buffers: the b1_z1 visual meshes are 60 MB of Collada text and 680k
triangles. The decimated meshes are cached next to the compiled solvers (`WBMPC_CACHE_DIR`).

Scene objects (`wbmpc.sim.objects.Scene.replay_objects`): boxes {"name", "kind": "box", "color",
"half_size_m", "position_m", "rotation"} and lines {"name", "kind": "line", "color", "points_m"},
static or over time ("t" with one pose per time), drawn as boxes and thin cylinders. `extras`: named
world-point trajectories drawn as small spheres.

Metadata (`<script id="replay-data" type="application/json">`, also `replay_data(...)`): robot,
scenario, fps (lower than asked for long runs, see `MAX_NODE_FRAMES`), n_frames, duration_s, t (the
frame times), geometry ("visual meshes", "collision geometry" or "primitive shapes"), nodes (the
animated node paths), triangles.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import warnings
from html import escape as html_escape
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError

MAX_TRIANGLES_PER_MESH = 5000
# animated node-frames (geometries x frames): ~70 bytes each; long runs get fewer frames per second so that
# the file stays under ~15 MB (b1_z1, 41 geometries: 30 fps up to 97 s, 4.9 fps for 10 min)
MAX_NODE_FRAMES = 120_000
EXTRA_COLORS = ("#e6194b", "#3cb44b", "#f58231", "#911eb4", "#4363d8", "#808000")
GEOMETRY_SOURCES = ("visual meshes", "collision geometry", "primitive shapes")
_ROOT = "wbmpc"


# ----------------------------------------------------------------------------- geometry
def _package_dirs(urdf: Path) -> list[str]:
    """`package://name/...` is looked up in every folder above the URDF (example-robot-data's layout)."""
    return [str(p) for p in urdf.resolve().parents]


def _mesh_files_exist(geometry: pin.GeometryModel) -> bool:
    return all(not o.meshPath or o.meshPath.upper() in ("BOX", "SPHERE", "CYLINDER", "CAPSULE", "CONE")
               or Path(o.meshPath).is_file() for o in geometry.geometryObjects)


def robot_geometry(robot) -> tuple[pin.GeometryModel, str]:
    """The robot's geometry for the replay and where it came from (one of `GEOMETRY_SOURCES`).

    Parsing the meshes is slow (b1_z1: 60 MB of Collada, ~5 s): once parsed, the geometry's layout is
    kept in the cache beside the decimated meshes and rebuilt from there while the URDF is unchanged.
    """
    index = _index_path(robot)
    if index is not None and index.is_file():
        try:
            return _geometry_from_index(json.loads(index.read_text()))
        except (OSError, ValueError, KeyError, TypeError):
            pass  # stale or broken: parse again
    geometry, source = _parse_geometry(robot)
    if index is not None:
        _write_index(index, geometry, source)
    return geometry, source


def _index_path(robot) -> Path | None:
    urdf = robot.model_file
    try:
        stat = urdf.stat()
    except OSError:
        return None
    model = robot.model
    layout = "|".join(f"{model.names[j]}:{model.parents[j]}" for j in range(model.njoints))
    key = f"{urdf.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{layout}|{MAX_TRIANGLES_PER_MESH}|1"
    return _cache_dir() / f"{robot.name}_{hashlib.sha256(key.encode()).hexdigest()[:20]}.json"


def _write_index(index: Path, geometry: pin.GeometryModel, source: str) -> None:
    """Each geometry's placement, colour and shape: a mesh (decimated and cached) or a primitive."""
    import coal

    objects = []
    for o in geometry.geometryObjects:
        shape = o.geometry
        entry = {"name": o.name, "joint": int(o.parentJoint), "frame": int(o.parentFrame),
                 "placement": o.placement.homogeneous.tolist(), "color": np.asarray(o.meshColor).tolist(),
                 "scale": np.asarray(o.meshScale).tolist(), "mesh": o.meshPath}
        if isinstance(shape, coal.BVHModelBase):
            if mesh_arrays(o) is None:
                return  # a mesh that could not be cached: parse every time
            entry["shape"] = ["mesh"]
        elif isinstance(shape, coal.Box):
            entry["shape"] = ["box", *(2 * np.asarray(shape.halfSide)).tolist()]
        elif isinstance(shape, coal.Sphere):
            entry["shape"] = ["sphere", float(shape.radius)]
        elif isinstance(shape, (coal.Cylinder, coal.Capsule)):
            entry["shape"] = [type(shape).__name__.lower(), float(shape.radius), 2 * float(shape.halfLength)]
        else:
            return  # another shape: parse every time
        objects.append(entry)
    try:
        index.parent.mkdir(parents=True, exist_ok=True)
        tmp = index.with_name(f"{index.stem}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"source": source, "objects": objects}))
        tmp.replace(index)
    except OSError:
        pass


def _geometry_from_index(index: dict) -> tuple[pin.GeometryModel, str]:
    import coal

    geometry = pin.GeometryModel()
    for entry in index["objects"]:
        kind, *size = entry["shape"]
        shape = {"mesh": lambda: coal.Sphere(1e-3), "box": lambda: coal.Box(*size), "sphere": lambda: coal.Sphere(*size),
                 "cylinder": lambda: coal.Cylinder(*size), "capsule": lambda: coal.Capsule(*size)}[kind]()
        obj = pin.GeometryObject(entry["name"], entry["joint"], entry["frame"], pin.SE3(np.array(entry["placement"])),
                                 shape)
        obj.meshPath, obj.meshScale, obj.meshColor = entry["mesh"], np.array(entry["scale"]), np.array(entry["color"])
        if kind == "mesh" and _cached_mesh(obj) is None:
            raise KeyError(entry["mesh"])  # the decimated mesh was removed: parse again
        geometry.addGeometryObject(obj)
    return geometry, index["source"]


def _parse_geometry(robot) -> tuple[pin.GeometryModel, str]:
    urdf = robot.model_file
    problems = []
    for kind, source in ((pin.GeometryType.VISUAL, GEOMETRY_SOURCES[0]), (pin.GeometryType.COLLISION, GEOMETRY_SOURCES[1])):
        try:
            if robot.mjcf is not None:  # an MJCF robot: its geoms as pinocchio reads them (and a mounted arm's)
                geometry = robot.geometry(kind)
            else:
                geometry = pin.buildGeomFromUrdf(robot.model, str(urdf), kind, package_dirs=_package_dirs(urdf))
        except (RuntimeError, ValueError, OSError) as exc:
            problems.append(f"{source}: {str(exc).splitlines()[0]}")
            continue
        if geometry.ngeoms and _mesh_files_exist(geometry):
            if problems:
                warnings.warn(f"replay of {robot.name}: {'; '.join(problems)}; drawn with its {source} instead",
                              stacklevel=3)
            return geometry, source
        problems.append(f"{source}: {'no geometry' if not geometry.ngeoms else 'mesh files missing'} in {urdf}")
    warnings.warn(f"replay of {robot.name}: {'; '.join(problems)}; drawn with primitive shapes (spheres, capsules, "
                  "boxes of the MuJoCo scene) instead of its meshes", stacklevel=3)
    return _primitive_geometry(robot), GEOMETRY_SOURCES[2]


def _primitive_geometry(robot) -> pin.GeometryModel:
    import coal

    from wbmpc.sim.shapes import robot_collision_shapes

    geometry = pin.GeometryModel()
    for k, shape in enumerate(robot_collision_shapes(robot)):
        size = shape.size
        if shape.kind == "sphere":
            coal_shape = coal.Sphere(size[0])
        elif shape.kind == "capsule":
            coal_shape = coal.Capsule(size[0], 2 * size[1])
        elif shape.kind == "cylinder":
            coal_shape = coal.Cylinder(size[0], 2 * size[1])
        else:
            coal_shape = coal.Box(*(2 * np.asarray(size)))
        parent_frame = robot.model.getFrameId(robot.model.names[shape.joint_id]) if shape.joint_id > 0 else 0
        obj = pin.GeometryObject(f"{shape.name}_{k}", shape.joint_id, parent_frame,
                                 pin.SE3(np.asarray(shape.rotation), np.asarray(shape.pos)), coal_shape)
        obj.meshColor = np.array([0.35, 0.38, 0.42, 1.0]) if not shape.is_foot else np.array([0.1, 0.1, 0.1, 1.0])
        geometry.addGeometryObject(obj)
    return geometry


def decimate(vertices: np.ndarray, faces: np.ndarray, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices merged on a grid (coarsened until at most `max_triangles` remain),
    collapsed and repeated triangles dropped. Keeps the outline within one grid cell."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) <= max_triangles:
        return vertices.astype(np.float32), faces.astype(np.uint32)
    low = vertices.min(axis=0)
    extent = float((vertices.max(axis=0) - low).max()) or 1.0
    cells = 256
    while True:
        cell = extent / cells
        key = np.floor((vertices - low) / cell).astype(np.int64)
        key = (key[:, 0] * (cells + 2) + key[:, 1]) * (cells + 2) + key[:, 2]
        _, inverse = np.unique(key, return_inverse=True)
        inverse = inverse.ravel()
        merged = inverse[faces]
        keep = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 0] != merged[:, 2])
        merged = merged[keep]
        _, first = np.unique(np.sort(merged, axis=1), axis=0, return_index=True)
        merged = merged[np.sort(first)]
        if len(merged) <= max_triangles or cells <= 4:
            break
        cells = int(cells * 0.75)
    counts = np.bincount(inverse)
    points = np.zeros((counts.size, 3))
    np.add.at(points, inverse, vertices)
    points /= counts[:, None]
    used, remap = np.unique(merged, return_inverse=True)  # drop vertices no triangle uses
    return points[used].astype(np.float32), remap.reshape(-1, 3).astype(np.uint32)


def _cache_dir() -> Path:
    from wbmpc.cache import default_cache_dir

    return default_cache_dir() / "replay_meshes"


def _mesh_cache_path(geometry_object: pin.GeometryObject, max_triangles: int) -> Path | None:
    path = Path(geometry_object.meshPath) if geometry_object.meshPath else None
    if path is None or not path.is_file():
        return None
    stat = path.stat()
    scale = np.asarray(geometry_object.meshScale, dtype=float)
    digest = hashlib.sha256(f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|{max_triangles}|"
                            f"{scale.tolist()}|1".encode()).hexdigest()[:20]
    return _cache_dir() / f"{path.stem}_{digest}.npz"


def _cached_mesh(geometry_object: pin.GeometryObject,
                 max_triangles: int = MAX_TRIANGLES_PER_MESH) -> tuple[np.ndarray, np.ndarray] | None:
    cached = _mesh_cache_path(geometry_object, max_triangles)
    if cached is None or not cached.is_file():
        return None
    try:
        with np.load(cached) as stored:
            return stored["vertices"], stored["faces"]
    except (OSError, ValueError, KeyError):
        return None


def mesh_arrays(geometry_object: pin.GeometryObject,
                max_triangles: int = MAX_TRIANGLES_PER_MESH) -> tuple[np.ndarray, np.ndarray] | None:
    """Decimated (vertices, faces) of a mesh geometry, scale applied (cached by file, size, time, budget)."""
    import coal

    hit = _cached_mesh(geometry_object, max_triangles)
    if hit is not None:
        return hit
    mesh = geometry_object.geometry
    if not isinstance(mesh, coal.BVHModelBase) or mesh.num_tris == 0:
        return None
    scale = np.asarray(geometry_object.meshScale, dtype=float)
    cached = _mesh_cache_path(geometry_object, max_triangles)
    vertices = np.asarray(mesh.vertices(), dtype=float) * scale
    faces = np.empty((mesh.num_tris, 3), dtype=np.int64)
    for k in range(mesh.num_tris):
        triangle = mesh.tri_indices(k)
        faces[k] = (triangle[0], triangle[1], triangle[2])
    if np.prod(np.sign(scale)) < 0:  # a mirrored mesh: keep the triangles facing out
        faces = faces[:, ::-1]
    vertices, faces = decimate(vertices, faces, max_triangles)
    if cached is not None:
        try:
            cached.parent.mkdir(parents=True, exist_ok=True)
            tmp = cached.with_name(f"{cached.stem}.{os.getpid()}.tmp.npz")
            np.savez(tmp, vertices=vertices, faces=faces)
            tmp.replace(cached)
        except OSError:
            pass  # a read-only cache only costs time
    return vertices, faces


# ----------------------------------------------------------------------------- recording
class _Recorder:
    """Stands in for meshcat's server window: keeps the last command per node and property, in order."""

    def __init__(self):
        self.commands: dict[tuple, bytes] = {}

    def send(self, command) -> None:
        import umsgpack

        data = command.lower()
        kind, path = data["type"], data.get("path", "")
        key = (kind, path, data.get("property")) if kind == "set_property" else (kind, path)
        self.commands[key] = umsgpack.packb(data)

    def blobs(self) -> list[str]:
        return [base64.b64encode(blob).decode("ascii") for blob in self.commands.values()]


class _Animation:
    """meshcat's animation clips (three.js keyframe tracks) built from arrays: one clip per node path.

    Packed with the C msgpack in single precision (sub-micrometre at a few metres): meshcat's own
    `Animation` computes each quaternion with an eigen-decomposition and packs in pure Python,
    10 s per 20 s of b1_z1 run, and doubles the size.
    """

    def __init__(self, fps: float):
        self.fps = fps
        self.tracks: dict[str, dict[str, tuple[str, list]]] = {}

    def add(self, node: str, frames: Sequence[int], name: str, kind: str, values: np.ndarray) -> None:
        keys = [{"time": int(f), "value": [float(x) for x in v]} for f, v in zip(frames, np.asarray(values))]
        self.tracks.setdefault(node, {})[name] = (kind, keys)

    def add_pose(self, node: str, frames: Sequence[int], positions: np.ndarray, rotations: np.ndarray) -> None:
        """Position and orientation tracks; `rotations` (n, 3, 3)."""
        quaternions = np.array([pin.Quaternion(np.asarray(r, dtype=float).reshape(3, 3)).coeffs()  # x, y, z, w
                                for r in rotations])
        self.add(node, frames, "position", "vector3", positions)
        self.add(node, frames, "quaternion", "quaternion", quaternions)

    def command(self, repetitions: int = 1_000_000) -> bytes:
        import msgpack

        animations = [{"path": node, "clip": {"fps": self.fps, "name": "default", "tracks": [
            {"name": "." + name, "type": kind, "keys": keys} for name, (kind, keys) in tracks.items()]}}
            for node, tracks in self.tracks.items()]
        return msgpack.packb({"type": "set_animation", "animations": animations, "path": "",
                              "options": {"play": True, "repetitions": repetitions}}, use_single_float=True)


def _import_meshcat():
    """meshcat (its import pulls a zmq server module that warns about its own deprecated event loop)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
        import meshcat.animation
        import meshcat.geometry
    return meshcat


def viewer_class():
    """pinocchio's MeshcatVisualizer with flat-shaded materials (the decimated meshes need no normals)."""
    _import_meshcat()
    import meshcat.geometry as mg
    from pinocchio.visualize import MeshcatVisualizer

    class FlatPhongMaterial(mg.MeshPhongMaterial):
        """Phong with flat shading: the decimated meshes need no normals."""

        def lower(self, object_data):
            data = super().lower(object_data)
            data["flatShading"] = True
            return data

    class ReplayVisualizer(MeshcatVisualizer):
        """pinocchio's MeshcatVisualizer with our decimated, cached meshes in place of the raw files."""

        triangles = 0

        def loadMeshFromFile(self, geometry_object):
            arrays = mesh_arrays(geometry_object)
            return None if arrays is None else mg.TriangularMeshGeometry(*arrays)

        def loadViewerGeometryObject(self, geometry_object, geometry_type, color=None):
            arrays = mesh_arrays(geometry_object) if geometry_object.meshPath else None
            if arrays is None:
                return super().loadViewerGeometryObject(geometry_object, geometry_type, color)
            rgba = np.asarray(geometry_object.meshColor if color is None else color, dtype=float)
            material = FlatPhongMaterial(color=int(rgba[0] * 255) << 16 | int(rgba[1] * 255) << 8 | int(rgba[2] * 255))
            if rgba[3] < 1:
                material.transparent, material.opacity = True, float(rgba[3])
            self.triangles += len(arrays[1])
            self.viewer[self.getViewerNodeName(geometry_object, geometry_type)].set_object(
                mg.TriangularMeshGeometry(*arrays), material)

    return ReplayVisualizer


def _frame_samples(time_s: np.ndarray, fps: float) -> tuple[np.ndarray, float]:
    """Indices of the samples shown at t0 + k / fps (nearest in time) and the run duration."""
    if time_s.size > 1:
        step = float(np.median(np.diff(time_s)))
        duration = float(time_s[-1] - time_s[0]) + step
    else:
        duration = 1.0 / fps
    n_frames = max(1, int(round(duration * fps)))
    wanted = time_s[0] + np.arange(n_frames) / fps
    return _nearest(time_s, wanted), duration


def _nearest(times: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    right = np.clip(np.searchsorted(times, wanted), 0, times.size - 1)
    left = np.clip(right - 1, 0, times.size - 1)
    return np.where(np.abs(times[left] - wanted) <= np.abs(times[right] - wanted), left, right)


def _color(text: str | None, default: str) -> int:
    text = (text or default).lstrip("#")
    try:
        return int(text[:6], 16)
    except ValueError:
        return int(default.lstrip("#"), 16)


def _matrix(position, rotation=None, scale=None) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float).reshape(3, 3)
    if scale is not None:
        T[:3, :3] = T[:3, :3] @ np.diag(scale)
    T[:3, 3] = position
    return T


def _segment(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, rotation and scale of a unit cylinder (meshcat: along y) spanning p0 -> p1."""
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    rotation = np.eye(3)
    if length > 1e-9:
        rotation = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), axis / length).toRotationMatrix()
    return 0.5 * (p0 + p1), rotation, np.array([1.0, max(length, 1e-6), 1.0])


def _add_objects(viewer, animation, objects: Sequence[dict] | None, frame_times: np.ndarray) -> list[str]:
    """The scene's boxes and lines, static or animated at the replay's frame times."""
    import meshcat.geometry as mg

    names = []
    for k, obj in enumerate(objects or []):
        name, kind = str(obj.get("name", f"object {k}")), obj.get("kind")
        node = viewer[f"{_ROOT}/objects/{k}"]
        times = obj.get("t")
        index = None if times is None else _nearest(np.asarray(times, dtype=float), frame_times)
        if kind == "box":
            half = np.asarray(obj["half_size_m"], dtype=float).reshape(3)
            position = np.asarray(obj["position_m"], dtype=float).reshape(-1, 3)
            rotation = np.asarray(obj.get("rotation", np.eye(3)), dtype=float).reshape(-1, 9)
            node.set_object(mg.Box(2 * half), mg.MeshLambertMaterial(color=_color(obj.get("color"), "#999999")))
            poses = [(p, r, None) for p, r in zip(position, rotation)]
        elif kind == "line":
            points = np.asarray(obj["points_m"], dtype=float).reshape(-1, 6)
            node.set_object(mg.Cylinder(1.0, 0.006), mg.MeshLambertMaterial(color=_color(obj.get("color"), "#222222")))
            poses = [_segment(p[:3], p[3:]) for p in points]
        else:
            raise ConfigError(f"scene object '{name}' has kind {kind!r}; the replay draws 'box' and 'line'")
        node.set_transform(_matrix(*poses[0 if index is None else min(index[0], len(poses) - 1)]))
        if index is not None and len(poses) > 1:
            frames = range(len(index))
            animation.add_pose(node.path.lower(), frames, np.array([poses[i][0] for i in index]),
                               np.array([poses[i][1] for i in index]))
            if kind == "line":
                animation.add(node.path.lower(), frames, "scale", "vector3", np.array([poses[i][2] for i in index]))
        names.append(name)
    return names


def _normalise_extras(extras, time_s: np.ndarray) -> list[tuple[str, Any, str | None]]:
    out = []
    for k, item in enumerate(extras or []):
        if isinstance(item, dict):
            name, positions, color = item.get("name", f"extra {k}"), item.get("positions", item.get("points")), item.get("color")
        else:
            name, positions, color = item[0], item[1], (item[2] if len(item) > 2 else None)
        if positions is None:
            raise ConfigError(f"extra trajectory '{name}' has no positions")
        if not callable(positions):
            positions = np.asarray(positions, dtype=float)
            if positions.shape != (time_s.size, 3):
                raise ConfigError(f"extra trajectory '{name}' has shape {positions.shape}; expected ({time_s.size}, 3), "
                                  "one world point per time sample (or a callable t -> (3,))")
        out.append((str(name), positions, color))
    return out


def _add_extras(viewer, animation, extras, time_s: np.ndarray, samples: np.ndarray) -> None:
    import meshcat.geometry as mg

    for k, (name, positions, color) in enumerate(_normalise_extras(extras, time_s)):
        node = viewer[f"{_ROOT}/extras/{k}"]
        node.set_object(mg.Sphere(0.02), mg.MeshLambertMaterial(color=_color(color, EXTRA_COLORS[k % len(EXTRA_COLORS)])))
        last, track = np.zeros(3), []
        for idx in samples:
            p = np.asarray(positions(float(time_s[idx])) if callable(positions) else positions[idx], dtype=float).ravel()
            if p.size >= 3 and np.all(np.isfinite(p[:3])):
                last = p[:3]
            track.append(last)
        node.set_transform(_matrix(track[0]))
        animation.add(node.path.lower(), range(len(samples)), "position", "vector3", np.array(track))


def _check(robot, time_s, q, fps) -> tuple[np.ndarray, np.ndarray]:
    time_s = np.asarray(time_s, dtype=float).ravel()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if not fps > 0:
        raise ConfigError(f"fps must be positive, got {fps}")
    if time_s.size == 0:
        raise ConfigError("the replay needs at least one sample")
    if q.shape != (time_s.size, robot.nq):
        raise ConfigError(f"q has shape {q.shape}; expected ({time_s.size}, {robot.nq}) for robot '{robot.name}'")
    if np.any(np.diff(time_s) < 0):
        raise ConfigError("time_s must be non-decreasing")
    return time_s, q


def _record(robot, time_s, q, fps: float, extras, objects) -> tuple[_Recorder, dict[str, Any]]:
    """Drive pinocchio's MeshcatVisualizer into a recorder: the scene, then one animation frame per sample."""
    meshcat = _import_meshcat()
    geometry, source = robot_geometry(robot)
    recorder = _Recorder()
    viewer = meshcat.Visualizer(window=recorder)
    viz = viewer_class()(robot.model, None, geometry)
    viz.initViewer(viewer=viewer)
    viz.loadViewerModel(rootNodeName=f"{_ROOT}/robot")
    span = float(time_s[-1] - time_s[0]) if time_s.size > 1 else 0.0
    fps = min(float(fps), MAX_NODE_FRAMES / max(geometry.ngeoms + len(objects or []), 1) / max(span, 1e-9))
    samples, duration = _frame_samples(time_s, fps)
    viz.display(q[samples[0]])  # the first frame as the static scene (before play, after reset)
    # then every geometry's placement per frame (pinocchio's geometry placements, as display() sets them)
    gdata = geometry.createData()
    data = robot.model.createData()
    placements = np.empty((len(samples), geometry.ngeoms, 4, 4))
    for frame, idx in enumerate(samples):
        pin.updateGeometryPlacements(robot.model, data, geometry, gdata, q[idx])
        placements[frame] = [gdata.oMg[g].homogeneous for g in range(geometry.ngeoms)]
    animation = _Animation(fps)
    frames = range(len(samples))
    for g, obj in enumerate(geometry.geometryObjects):
        node = viewer[viz.getViewerNodeName(obj, pin.GeometryType.VISUAL)].path.lower()
        animation.add_pose(node, frames, placements[:, g, :3, 3], placements[:, g, :3, :3])
    object_names = _add_objects(viewer, animation, objects, time_s[samples])
    _add_extras(viewer, animation, extras, time_s, samples)
    floor = viewer[f"{_ROOT}/floor"]  # a light floor just under meshcat's grid, so that the feet have ground
    floor.set_object(meshcat.geometry.Box([30.0, 30.0, 0.01]), meshcat.geometry.MeshLambertMaterial(color=0xd9dce1))
    floor.set_transform(_matrix([0.0, 0.0, -0.0055]))
    height = max(float(robot.q_nominal[2]), 0.2)  # camera distance in proportion to the robot's size
    viewer["/Cameras/default/rotated/<object>"].set_property("position", (height * np.array([5.0, 3.0, 5.0])).tolist())
    recorder.commands[("set_animation", "")] = animation.command()
    meta = {"version": 2, "robot": robot.name, "fps": float(fps), "n_frames": int(len(samples)),
            "duration_s": round(duration, 6), "t": [round(float(time_s[i]), 4) for i in samples],
            "geometry": source, "triangles": viz.triangles, "objects": object_names,
            "nodes": [viz.getViewerNodeName(o, pin.GeometryType.VISUAL) for o in geometry.geometryObjects]}
    return recorder, meta


def replay_data(robot, time_s, q, fps: float = 30, extras: Sequence | None = None,
                objects: Sequence[dict] | None = None, scenario: str | None = None) -> dict[str, Any]:
    """The replay's metadata and its meshcat commands (base64 msgpack, in order): see the module docstring."""
    time_s, q = _check(robot, time_s, q, fps)
    recorder, meta = _record(robot, time_s, q, fps, extras, objects)
    return {**meta, "scenario": scenario, "commands": recorder.blobs()}


def save_replay(robot, time_s, q, out_path, fps: float = 30, extras: Sequence | None = None,
                objects: Sequence[dict] | None = None, scenario: str | None = None) -> Path:
    """Write the HTML replay of configurations `q` (n, nq) at times `time_s` (n,) and return its path.

    `extras`: optional named world-point trajectories drawn as small spheres, each `{"name": str,
    "positions": (n, 3) array or callable t -> (3,), "color": "#rrggbb"}` or a `(name, positions[,
    color])` tuple (a non-finite point keeps the last one). `objects`: the scene's boxes and lines
    (`Scene.replay_objects()`); `scenario`: the run's name, shown in the title.
    """
    meshcat = _import_meshcat()
    data = replay_data(robot, time_s, q, fps, extras, objects, scenario)
    commands = data.pop("commands")
    viewer_js = (Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js").read_text(encoding="utf-8")
    title = f"wbmpc replay: {scenario} ({robot.name})" if scenario else f"wbmpc replay: {robot.name}"
    note = "" if data["geometry"] == GEOMETRY_SOURCES[0] else f" &middot; drawn with {data['geometry']}: meshes missing"
    html = (_TEMPLATE.replace("__TITLE__", html_escape(title))
            .replace("__NOTE__", note)
            .replace("__META__", json.dumps(data, separators=(",", ":")).replace("</", "<\\/"))
            .replace("__COMMANDS__", json.dumps(commands, separators=(",", ":")))
            .replace("__VIEWER__", viewer_js.replace("</script", "<\\/script")))
    path = Path(out_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html, encoding="utf-8")
    return path


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__TITLE__</title>
<style>
  body { margin: 0; font: 13px system-ui, sans-serif; }
  #meshcat-pane { width: 100vw; height: 100vh; overflow: hidden; }
  #info { position: absolute; left: 12px; top: 8px; pointer-events: none; color: #222; }
  #info b { font-size: 15px; }
  #clock { font-variant-numeric: tabular-nums; }
</style>
</head>
<body>
<div id="meshcat-pane"></div>
<div id="info"><b>__TITLE__</b><br><span id="clock">t = 0.00 s</span>
  <span>&middot; Animations panel (top right): play, pause, time &middot; drag: rotate, wheel: zoom__NOTE__</span></div>
<script id="replay-data" type="application/json">__META__</script>
<script>__VIEWER__</script>
<script>
  // meshcat's viewer replays the recorded commands (scene, then the animation) in order
  const meta = JSON.parse(document.getElementById("replay-data").textContent);
  const viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
  for (const blob of __COMMANDS__) {
    viewer.handle_command_bytearray(Uint8Array.from(atob(blob), c => c.charCodeAt(0)));
  }
  if (viewer.gui) { viewer.gui.open(); }  // the controls with the Animations panel shown from the start
  const clock = document.getElementById("clock");
  function tick() {
    const t = viewer.animator && viewer.animator.mixer ? viewer.animator.mixer.time : 0;
    const k = Math.min(meta.n_frames - 1, Math.max(0, Math.floor(t * meta.fps) % meta.n_frames));
    clock.textContent = "t = " + meta.t[k].toFixed(2) + " s";
    clock.dataset.frame = k;
    requestAnimationFrame(tick);
  }
  tick();
  window.wbmpcReplay = { viewer, meta };
</script>
</body>
</html>
"""
