"""The URDF's primitive collision geometry (box, cylinder, sphere, capsule), read by pinocchio.

`collision_primitives(model, urdf)` gives every primitive `<collision>` of the links of `model` in
the frame of the pinocchio joint that carries the link (`pin.buildGeomFromUrdf`: the same placements
pinocchio's collision checking uses, and its `<collision_checking><capsule/>` replacement of a
cylinder by a capsule). Meshes are left out: wbmpc does not collide with them. The MuJoCo plant's
shapes (`wbmpc.sim.shapes`) and the foot radius of `RobotModel` come from here.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

_mesh_loader = None  # one coal.CachedMeshLoader per process: each mesh file is read once


@dataclass(frozen=True)
class Primitive:
    """One primitive collision of link `link` (its `index`-th `<collision>`), in joint `joint_id`'s frame.

    size follows MuJoCo's convention: box (half_x, half_y, half_z), sphere (radius,), cylinder and
    capsule (radius, half_length) along the local z axis.
    """

    link: str
    index: int
    joint_id: int
    kind: str
    size: tuple[float, ...]
    placement: pin.SE3

    @property
    def name(self) -> str:
        return f"{self.link}_collision{self.index}"


def collision_primitives(model: pin.Model, urdf: str | Path) -> list[Primitive]:
    """The primitives of `urdf`'s links that are frames of `model` (see the module docstring)."""
    import coal

    global _mesh_loader
    if _mesh_loader is None:
        _mesh_loader = coal.CachedMeshLoader()
    try:
        geometry = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION,
                                         package_dirs=_package_dirs(Path(urdf)), mesh_loader=_mesh_loader)
    except (RuntimeError, ValueError):  # a mesh file missing or unreadable, or not a URDF
        return _primitives_without_meshes(model, Path(urdf))
    out = []
    for obj in geometry.geometryObjects:
        shape = obj.geometry
        if isinstance(shape, coal.Box):
            kind, size = "box", tuple(float(h) for h in shape.halfSide)
        elif isinstance(shape, coal.Sphere):
            kind, size = "sphere", (float(shape.radius),)
        elif isinstance(shape, (coal.Cylinder, coal.Capsule)):
            kind, size = type(shape).__name__.lower(), (float(shape.radius), float(shape.halfLength))
        else:
            continue  # a mesh
        link = model.frames[obj.parentFrame].name
        suffix = obj.name[len(link) + 1:]  # pinocchio names them LINK_K, K counting the link's <collision>s
        out.append(Primitive(link, int(suffix) if suffix.isdigit() else 0, int(obj.parentJoint), kind, size,
                             pin.SE3(obj.placement)))
    return out


def _package_dirs(urdf: Path) -> list[str]:
    """`package://name/...` is looked up above the URDF (example-robot-data's layout) and in
    example-robot-data (URDFs composed in the cache dir keep the base's package:// meshes)."""
    dirs = [str(p) for p in urdf.resolve().parents]
    try:
        from wbmpc.robots.presets import example_robot_data_dir

        dirs += [str(p) for p in example_robot_data_dir().parents]
    except Exception:  # example-robot-data not installed: the URDF's own folders only
        pass
    return dirs


def _primitives_without_meshes(model: pin.Model, urdf: Path) -> list[Primitive]:
    """The primitives when pinocchio cannot build the geometry because a mesh file is missing: a URDF
    without its meshes (wbmpc never collides with them) keeps its primitives. ElementTree stays for
    this case only: pinocchio's parser loads every mesh and fails on the first one it cannot find."""
    try:
        root = ET.parse(urdf).getroot()
    except (ET.ParseError, OSError):
        return []
    out = []
    for link in root.iter("link"):
        name = link.get("name")
        if not model.existFrame(name):
            continue
        frame = model.frames[_body_frame(model, name)]
        for k, collision in enumerate(link.iter("collision")):
            shape = _parse_primitive(collision)
            if shape is not None:
                kind, size, placement = shape
                out.append(Primitive(name, k, int(frame.parentJoint), kind, size, frame.placement * placement))
    return out


def _body_frame(model: pin.Model, name: str) -> int:
    """The link's BODY frame (a fixed joint may share its name)."""
    if model.existFrame(name, pin.FrameType.BODY):
        return model.getFrameId(name, pin.FrameType.BODY)
    return model.getFrameId(name)


def _parse_primitive(collision: ET.Element) -> tuple[str, tuple[float, ...], pin.SE3] | None:
    geometry = collision.find("geometry")
    if geometry is None:
        return None
    origin = collision.find("origin")
    xyz = np.array([float(x) for x in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
    rpy = np.array([float(x) for x in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
    placement = pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz)
    if (box := geometry.find("box")) is not None:
        return "box", tuple(0.5 * float(x) for x in box.get("size").split()), placement
    if (cylinder := geometry.find("cylinder")) is not None:
        return "cylinder", (float(cylinder.get("radius")), 0.5 * float(cylinder.get("length"))), placement
    if (sphere := geometry.find("sphere")) is not None:
        return "sphere", (float(sphere.get("radius")),), placement
    return None
