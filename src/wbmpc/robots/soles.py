"""Flat feet: the sole rectangle of a surface contact (6D wrench) and where it is read from.

A surface contact carries a 6D wrench in its sole frame: a frame at the centre of the sole
rectangle, on its bottom face, with the foot link's axes (x forward along the length, z up out of
the sole). The rectangle comes from the URDF collision geometry of the foot link, read through
pinocchio's `GeometryModel` (the bounding box of its primitives: boxes, spheres, cylinders,
capsules), or is given as LENGTH,WIDTH (`--sole`), centred on the foot frame's origin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError

FOOT_CONTACTS = ("point", "surface")


@dataclass(frozen=True)
class Sole:
    """Sole rectangle of a flat foot: its size and the sole frame's origin in the foot frame."""

    foot: str
    length_m: float  # along the foot frame's x
    width_m: float  # along the foot frame's y
    centre_m: np.ndarray  # sole frame origin (centre of the bottom face) in the foot frame

    @property
    def frame(self) -> str:
        """Name of the sole frame added to the pinocchio model (the contact frame of the wrench)."""
        return f"{self.foot}_sole"

    @property
    def half_length_m(self) -> float:
        return 0.5 * self.length_m

    @property
    def half_width_m(self) -> float:
        return 0.5 * self.width_m

    def corners_m(self) -> np.ndarray:
        """(4, 3) sole corners in the sole frame."""
        x, y = self.half_length_m, self.half_width_m
        return np.array([[x, y, 0.0], [x, -y, 0.0], [-x, -y, 0.0], [-x, y, 0.0]])


def check_sole_size(size: tuple[float, float], label: str = "--sole") -> tuple[float, float]:
    if len(size) != 2 or not all(np.isfinite(s) and 0.01 <= s <= 1.0 for s in size):
        raise ModelError(f"{label} needs LENGTH,WIDTH in metres, each in [0.01, 1], got {size}")
    return float(size[0]), float(size[1])


def sole_from_size(foot: str, size: tuple[float, float]) -> Sole:
    length, width = check_sole_size(size)
    return Sole(foot, length, width, np.zeros(3))


def soles_from_collisions(model: pin.Model, urdf: Path, feet: tuple[str, ...], frame_id) -> dict[str, Sole]:
    """The sole of each foot: bounding box (in the foot frame) of the collision primitives attached to
    the foot link in pinocchio's collision `GeometryModel`; its bottom face is the sole.

    A foot whose link has no primitive collision geometry raises a `ModelError` naming the link and
    `--sole` (meshes are not used: their bounding box is rarely the sole)."""
    geometry = _collision_model(model, urdf)
    soles = {}
    for foot in feet:
        fid = frame_id(foot)
        frame = model.frames[fid]
        lows, highs = [], []
        for obj in geometry.geometryObjects:
            if obj.parentFrame != fid and not (obj.parentJoint == frame.parentJoint and _link_of(model, obj) == foot):
                continue
            extent = _primitive_extent(obj.geometry)
            if extent is None:
                continue
            placement = frame.placement.actInv(obj.placement)  # geometry placement is in the joint frame
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * extent
            points = corners @ placement.rotation.T + placement.translation
            lows.append(points.min(axis=0))
            highs.append(points.max(axis=0))
        if not lows:
            raise ModelError(
                f"foot link '{foot}' has no primitive collision geometry (box, sphere, cylinder) in {urdf} to read its "
                "sole from; give the sole size with --sole LENGTH,WIDTH (metres) or use point feet"
            )
        low, high = np.min(lows, axis=0), np.max(highs, axis=0)
        centre = np.array([0.5 * (low[0] + high[0]), 0.5 * (low[1] + high[1]), low[2]])
        soles[foot] = Sole(foot, float(high[0] - low[0]), float(high[1] - low[1]), centre)
    return soles


def soles_from_primitives(model: pin.Model, primitives, feet: tuple[str, ...], frame_id, path: Path) -> dict[str, Sole]:
    """The sole of each foot from a file's primitive collision geometry (`urdf_geometry.Primitive`, e.g. an MJCF's
    colliding geoms: g1's four 5 mm corner spheres): the bounding box, in the foot frame, of the primitives of the
    body carrying the foot (the foot's own body, or the body a foot site sits on); its bottom face is the sole."""
    soles = {}
    for foot in feet:
        frame = model.frames[frame_id(foot)]
        body = frame.name if frame.type == pin.FrameType.BODY else model.frames[frame.parentFrame].name
        lows, highs = [], []
        for shape in primitives:
            if shape.link != body:
                continue
            extent = _shape_extent(shape.kind, shape.size)
            placement = frame.placement.actInv(shape.placement)
            corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * extent
            points = corners @ placement.rotation.T + placement.translation
            lows.append(points.min(axis=0))
            highs.append(points.max(axis=0))
        if not lows:
            raise ModelError(f"foot '{foot}' (body '{body}') has no primitive collision geom (box, sphere, capsule, "
                             f"cylinder) in {path} to read its sole from; give the sole size with --sole LENGTH,WIDTH "
                             "(metres) or use point feet (--foot-contact point)")
        soles[foot] = _sole(foot, np.min(lows, axis=0), np.max(highs, axis=0))
    return soles


def _sole(foot: str, low: np.ndarray, high: np.ndarray) -> Sole:
    centre = np.array([0.5 * (low[0] + high[0]), 0.5 * (low[1] + high[1]), low[2]])
    return Sole(foot, float(high[0] - low[0]), float(high[1] - low[1]), centre)


def _shape_extent(kind: str, size: tuple[float, ...]) -> np.ndarray:
    """Half extents of a primitive's bounding box in its own frame (MuJoCo's size convention)."""
    if kind == "box":
        return np.asarray(size, dtype=float)
    if kind == "sphere":
        return np.full(3, float(size[0]))
    r, h = float(size[0]), float(size[1])
    return np.array([r, r, h + (r if kind == "capsule" else 0.0)])


def _collision_model(model: pin.Model, urdf: Path) -> pin.GeometryModel:
    from wbmpc.robots.presets import example_robot_data_dir

    package_dirs = [str(Path(urdf).parent)]
    try:
        package_dirs.append(str(example_robot_data_dir().parents[1]))
    except ModelError:
        pass
    try:
        return pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION, package_dirs=package_dirs)
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"pinocchio cannot read the collision geometry of {urdf} ({exc}); give the sole size "
                         "with --sole LENGTH,WIDTH") from exc


def _link_of(model: pin.Model, obj) -> str:
    return model.frames[obj.parentFrame].name if obj.parentFrame < len(model.frames) else ""


def _primitive_extent(geometry) -> np.ndarray | None:
    """Half extents of a primitive's bounding box in its own frame (None for meshes)."""
    kind = type(geometry).__name__
    if kind == "Box":
        return np.asarray(geometry.halfSide, dtype=float)
    if kind == "Sphere":
        return np.full(3, float(geometry.radius))
    if kind in ("Cylinder", "Capsule"):
        r, h = float(geometry.radius), float(geometry.halfLength)
        return np.array([r, r, h + (r if kind == "Capsule" else 0.0)])
    return None
