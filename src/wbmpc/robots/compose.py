"""An arm on any legged base: two URDFs composed into one robot (`--arm URDF --mount FRAME ...`).

The arm's tree is attached below a frame of the base by a fixed joint (`mount_xyz_m`, `mount_rpy_rad`
in that frame), like a URDF author would write it: the result is one URDF, content-addressed in the
cache directory, so that every consumer of a `RobotModel` (the pinocchio model and the MPC, the
MuJoCo scene and its collision primitives, the replay, deploy) reads the composed robot as it reads
any other. A massless root link of the arm (z1.urdf's `world`) with one fixed child joint is folded
into the mount. Link and joint names of the arm that the base already uses get the prefix `arm_`
(reported in `Composition.renamed`). The result equals pinocchio's `appendModel` of the two models
(tests/robots/test_compose.py), and b1.urdf + z1.urdf at the mount of b1-z1.urdf equals b1-z1.urdf.

ElementTree, not pinocchio, handles the URDFs here: composing edits and writes URDF text (pinocchio
reads URDFs into models, it does not write them), and that file is what MuJoCo, the replay and deploy read.
"""

from __future__ import annotations

import copy
import hashlib
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError
from wbmpc.robots.model import RobotSpec

ARM_PREFIX = "arm_"


@dataclass(frozen=True)
class ArmMount:
    """An arm URDF and where it sits on the base (a link or joint frame of the base URDF)."""

    urdf: Path
    mount_frame: str
    mount_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    arm_ee: str | None = None  # None: the arm's only leaf link
    locked_joints: tuple[str, ...] = ()  # arm joints locked at the reference pose (names in the arm URDF)
    joint_positions_rad: dict[str, float] = field(default_factory=dict)  # arm reference pose (others 0)

    def __post_init__(self):
        for label, values in (("--mount-xyz", self.mount_xyz_m), ("--mount-rpy", self.mount_rpy_rad)):
            if len(values) != 3 or not all(np.isfinite(float(v)) for v in values):
                raise ModelError(f"{label} needs three finite numbers X,Y,Z, got {values!r}")


@dataclass(frozen=True)
class Composition:
    """The composed URDF and what the composition did to the arm's names."""

    urdf: Path
    renamed: dict[str, str]  # arm name -> name in the composed robot (collisions with the base)
    arm_ee: str
    arm_joints: tuple[str, ...]  # the arm's moving joints, composed names

    def note(self) -> str:
        if not self.renamed:
            return ""
        names = ", ".join(f"{a} -> {b}" for a, b in sorted(self.renamed.items()))
        return f"arm links/joints that the base also names were prefixed with '{ARM_PREFIX}': {names}"


def _parse(path: Path, label: str) -> ET.Element:
    if not Path(path).is_file():
        raise ModelError(f"{label} URDF file not found: {path}")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ModelError(f"{label} URDF {path} is not well-formed XML ({exc})") from None


def _origin(element: ET.Element | None) -> pin.SE3:
    if element is None:
        return pin.SE3.Identity()
    xyz = np.array([float(x) for x in element.get("xyz", "0 0 0").split()])
    rpy = np.array([float(x) for x in element.get("rpy", "0 0 0").split()])
    return pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz)


def _set_origin(joint: ET.Element, placement: pin.SE3) -> None:
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    origin.set("xyz", " ".join(repr(float(x)) for x in placement.translation))
    origin.set("rpy", " ".join(repr(float(x)) for x in pin.rpy.matrixToRpy(placement.rotation)))


def _absolute_meshes(root: ET.Element, urdf: Path) -> None:
    """Relative mesh paths made absolute: the composed file lives elsewhere."""
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if name and "://" not in name and not os.path.isabs(name):
            mesh.set("filename", str((Path(urdf).parent / name).resolve()))


def _mount_link(base: ET.Element, frame: str, base_urdf: Path) -> tuple[str, pin.SE3]:
    """The base link the arm hangs from, and the frame's placement in it (a joint frame is its child link's)."""
    links = [link.get("name") for link in base.iter("link")]
    if frame in links:
        return frame, pin.SE3.Identity()
    for joint in base.iter("joint"):
        if joint.get("name") == frame:
            return joint.find("child").get("link"), pin.SE3.Identity()
    joints = [joint.get("name") for joint in base.iter("joint")]
    raise ModelError(f"--mount '{frame}' is not a link or joint of {base_urdf}; its frames are: "
                     f"links {', '.join(links)}; joints {', '.join(joints)}")


def compose(base_urdf: Path, arm: ArmMount, cache_dir: Path | None = None) -> Composition:
    """Write the composed URDF (once per content) and return it with the names it changed."""
    base = _parse(base_urdf, "base")
    arm_root = _parse(arm.urdf, "arm")
    base = copy.deepcopy(base)
    _absolute_meshes(base, base_urdf)
    _absolute_meshes(arm_root, arm.urdf)
    mount_link, mount_frame = _mount_link(base, arm.mount_frame, base_urdf)
    mount = mount_frame * pin.SE3(pin.rpy.rpyToMatrix(np.asarray(arm.mount_rpy_rad, float)),
                                  np.asarray(arm.mount_xyz_m, float))

    taken = {e.get("name") for e in base.iter("link")} | {e.get("name") for e in base.iter("joint")}
    arm_links = [e for e in arm_root.findall("link")]
    arm_joints = [e for e in arm_root.findall("joint")]
    renamed: dict[str, str] = {}
    for element in arm_links + arm_joints:
        name = element.get("name")
        if name in taken:
            new = ARM_PREFIX + name
            while new in taken:
                new = ARM_PREFIX + new
            renamed[name] = new
    link_names = {e.get("name") for e in arm_links}
    for link in arm_links:
        link.set("name", renamed.get(link.get("name"), link.get("name")))
    for joint in arm_joints:
        joint.set("name", renamed.get(joint.get("name"), joint.get("name")))
        for tag in ("parent", "child"):
            element = joint.find(tag)
            if element is not None and element.get("link") in link_names:
                element.set("link", renamed.get(element.get("link"), element.get("link")))

    children = {j.find("child").get("link") for j in arm_joints}
    roots = [link for link in arm_links if link.get("name") not in children]
    if len(roots) != 1:
        raise ModelError(f"arm URDF {arm.urdf} has {len(roots)} root links ({', '.join(r.get('name') for r in roots)}); "
                         "it needs exactly one, the link to mount")
    root = roots[0]
    below = [j for j in arm_joints if j.find("parent").get("link") == root.get("name")]
    if not list(root) and len(below) == 1 and below[0].get("type") == "fixed":  # a massless 'world' root: fold it
        fold = below[0]
        _set_origin(fold, mount * _origin(fold.find("origin")))
        fold.find("parent").set("link", mount_link)
        arm_links.remove(root)
        mount_joint = None
    else:
        mount_joint = ET.Element("joint", {"name": _free_name("arm_mount_joint", taken | set(renamed.values())),
                                           "type": "fixed"})
        ET.SubElement(mount_joint, "parent", {"link": mount_link})
        ET.SubElement(mount_joint, "child", {"link": root.get("name")})
        _set_origin(mount_joint, mount)

    materials = {m.get("name") for m in base.findall("material")}
    for material in arm_root.findall("material"):
        if material.get("name") not in materials:
            base.append(material)
    for element in arm_links + ([mount_joint] if mount_joint is not None else []) + arm_joints:
        base.append(element)

    moving = tuple(j.get("name") for j in arm_joints if j.get("type") not in ("fixed", "floating", "planar"))
    ee = _arm_ee(arm, arm_links, arm_joints, renamed)
    path = _cached_urdf(base, f"{Path(base_urdf).stem}+{Path(arm.urdf).stem}", cache_dir)
    return Composition(urdf=path, renamed=renamed, arm_ee=ee, arm_joints=moving)


def _free_name(name: str, taken: set[str]) -> str:
    while name in taken:
        name = ARM_PREFIX + name
    taken.add(name)
    return name


def _arm_ee(arm: ArmMount, links: list[ET.Element], joints: list[ET.Element], renamed: dict[str, str]) -> str:
    """The end-effector frame: `arm.arm_ee` (arm name or composed name), else the arm's only leaf link."""
    names = [link.get("name") for link in links] + [joint.get("name") for joint in joints]
    if arm.arm_ee is not None:
        ee = renamed.get(arm.arm_ee, arm.arm_ee)
        if ee not in names:
            raise ModelError(f"--arm-ee '{arm.arm_ee}' is not a link or joint of the arm {arm.urdf}; "
                             f"its frames: {', '.join(names)}")
        return ee
    parents = {joint.find("parent").get("link") for joint in joints}
    leaves = [link.get("name") for link in links if link.get("name") not in parents]
    if len(leaves) != 1:
        raise ModelError(f"the arm {arm.urdf} ends in {len(leaves)} links ({', '.join(leaves)}): "
                         "name its end-effector with --arm-ee FRAME")
    return leaves[0]


def compose_spec(base: RobotSpec, arm: ArmMount, name: str | None = None) -> tuple[RobotSpec, Composition]:
    """The spec of the base with the arm mounted: the composed URDF (an MJCF base: the base's file and the arm's URDF,
    renamed, with its mount, `mjcf_arm`), the arm's end-effector, its locked joints and reference pose added to the
    base's (arm names mapped through the renaming)."""
    if base.arm_ee is not None:
        raise ModelError(f"{base.name} already has an arm (end-effector {base.arm_ee}); mount an arm on a legged base")
    if base.mjcf is not None:
        composition, mount = compose_on_mjcf(Path(base.mjcf), arm)
        files = dict(mjcf_arm=(composition.urdf, arm.mount_frame, mount))
    else:
        composition = compose(base.urdf, arm)
        files = dict(urdf=composition.urdf)
    mapped = composition.renamed
    locked = tuple(mapped.get(j, j) for j in arm.locked_joints)
    pose = {mapped.get(j, j): v for j, v in arm.joint_positions_rad.items()}
    spec = replace(base, name=name or f"{base.name}+{Path(arm.urdf).stem}", **files,
                   arm_ee=composition.arm_ee, locked_joints=tuple(base.locked_joints) + locked,
                   joint_positions_rad={**base.joint_positions_rad, **pose})
    return spec, composition


def compose_on_mjcf(base_mjcf: Path, arm: ArmMount, cache_dir: Path | None = None) -> tuple[Composition, tuple]:
    """An arm on an MJCF base: the arm's URDF with the names the base also uses prefixed and a massless root
    folded into the mount, written content-addressed to the cache; `RobotModel` appends its pinocchio model to the
    base's at the mount (`pin.appendModel`, as the URDF composition equals). Returns the composition and the
    mount placement in the mount frame (x, y, z, roll, pitch, yaw)."""
    import pinocchio as pin

    base = pin.buildModelFromMJCF(str(base_mjcf))
    frames = [f.name for f in base.frames]
    if arm.mount_frame not in frames:
        bodies = [f.name for f in base.frames if f.type == pin.FrameType.BODY]
        raise ModelError(f"--mount '{arm.mount_frame}' is not a body or joint of {base_mjcf}; its bodies: "
                         f"{', '.join(bodies)}; joints: {', '.join(base.names[1:])}")
    taken = set(frames) | set(base.names)
    root = copy.deepcopy(_parse(arm.urdf, "arm"))
    _absolute_meshes(root, arm.urdf)
    links, joints = root.findall("link"), root.findall("joint")
    renamed: dict[str, str] = {}
    for element in links + joints:
        if element.get("name") in taken:
            renamed[element.get("name")] = _free_name(ARM_PREFIX + element.get("name"), taken)
    link_names = {e.get("name") for e in links}
    for element in links + joints:
        element.set("name", renamed.get(element.get("name"), element.get("name")))
    for joint in joints:
        for tag in ("parent", "child"):
            element = joint.find(tag)
            if element is not None and element.get("link") in link_names:
                element.set("link", renamed.get(element.get("link"), element.get("link")))
    mount = pin.SE3(pin.rpy.rpyToMatrix(np.asarray(arm.mount_rpy_rad, float)), np.asarray(arm.mount_xyz_m, float))
    children = {j.find("child").get("link") for j in joints}
    roots = [link for link in links if link.get("name") not in children]
    if len(roots) != 1:
        raise ModelError(f"arm URDF {arm.urdf} has {len(roots)} root links ({', '.join(r.get('name') for r in roots)}); "
                         "it needs exactly one, the link to mount")
    below = [j for j in joints if j.find("parent").get("link") == roots[0].get("name")]
    if not list(roots[0]) and len(below) == 1 and below[0].get("type") == "fixed":  # a massless 'world' root: fold it
        mount = mount * _origin(below[0].find("origin"))
        new_root = below[0].find("child").get("link")
        root.remove(roots[0])
        root.remove(below[0])
        links = [link for link in links if link is not roots[0]]
        joints = [j for j in joints if j is not below[0]]
        roots = [link for link in links if link.get("name") == new_root]
    moving = tuple(j.get("name") for j in joints if j.get("type") not in ("fixed", "floating", "planar"))
    ee = _arm_ee(arm, links, joints, renamed)
    path = _cached_urdf(root, f"{Path(base_mjcf).stem}+{Path(arm.urdf).stem}", cache_dir)
    placement = (*map(float, mount.translation), *map(float, pin.rpy.matrixToRpy(mount.rotation)))
    return Composition(urdf=path, renamed=renamed, arm_ee=ee, arm_joints=moving), placement


def append_model(base: pin.Model, arm: pin.Model, frame_id: int, placement: pin.SE3) -> pin.Model:
    """`arm` (a fixed-base model) attached to frame `frame_id` of `base` at `placement` in that frame: its joints,
    limits, inertias (the root link's on the mount's joint) and frames. `pin.appendModel` does the same but looks
    frames up by name alone and stops at a link and a joint of the same name (Z1's gripperStator)."""
    model = pin.Model(base)
    mount = base.frames[frame_id]
    offset = mount.placement * placement  # the arm's universe in the mount's joint frame
    joints = {0: mount.parentJoint}
    for j in range(1, arm.njoints):
        iq, nq, iv, nv = arm.idx_qs[j], arm.nqs[j], arm.idx_vs[j], arm.nvs[j]
        joint_placement = offset * arm.jointPlacements[j] if arm.parents[j] == 0 else arm.jointPlacements[j]
        joints[j] = model.addJoint(joints[arm.parents[j]], arm.joints[j], joint_placement, arm.names[j],
                                   arm.effortLimit[iv:iv + nv], arm.velocityLimit[iv:iv + nv],
                                   arm.lowerPositionLimit[iq:iq + nq], arm.upperPositionLimit[iq:iq + nq])
        model.appendBodyToJoint(joints[j], arm.inertias[j], pin.SE3.Identity())
    model.appendBodyToJoint(mount.parentJoint, offset.act(arm.inertias[0]), pin.SE3.Identity())
    frames = {0: frame_id}
    for k in range(1, len(arm.frames)):
        f = arm.frames[k]
        frame_placement = offset * f.placement if f.parentJoint == 0 else f.placement
        frames[k] = model.addFrame(pin.Frame(f.name, joints[f.parentJoint], frames.get(f.parentFrame, frame_id),
                                             frame_placement, f.type, f.inertia), False)  # inertias are in the joints
    return model


def _cached_urdf(root: ET.Element, stem: str, cache_dir) -> Path:
    """The composed URDF in the cache (`<cache>/composed/<stem>-<content hash>.urdf`), written once, atomically."""
    text = ET.tostring(root, encoding="unicode")
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    if cache_dir is None:
        from wbmpc.cache import default_cache_dir

        cache_dir = default_cache_dir()
    folder = Path(cache_dir) / "composed"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stem}-{digest}.urdf"
    if not path.is_file():
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text('<?xml version="1.0" ?>\n' + text)
        tmp.replace(path)
    return path
