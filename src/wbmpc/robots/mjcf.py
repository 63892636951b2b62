"""Robots described in MJCF (MuJoCo Menagerie, unitree_mujoco): what pinocchio's parser leaves out, read from
MuJoCo's compiler.

`pinocchio.buildModelFromMJCF` gives the kinematic tree, the inertias, the joint ranges and the drive train
(armature, damping, frictionloss) of the controller's model. MuJoCo, the format's reference, compiles the same
file (its `<default>` classes, `<include>`s, meshes) for the rest: the torque limits (`force_limits`: an
actuator's `forcerange`, a motor's gear x gain x `ctrlrange`, a joint's `actuatorfrcrange`), the keyframes
(`keyframe_positions`: the nominal pose), the sites and geoms (a foot given as a site or a geom gets a frame:
`add_point_frames`) and the primitive collision geoms (`collision_primitives`: soles, the MuJoCo scene).
MJCF files carry no joint velocity limits.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError
from wbmpc.robots.urdf_geometry import Primitive

MESH_HINT = ("a mesh or texture file it names is missing: restore it, or drop the geoms that use it from your copy "
             "of the file")
_KINDS = {int(mujoco.mjtGeom.mjGEOM_BOX): "box", int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
          int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule", int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder"}
_ONE_DOF = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def compile_mjcf(path: str | Path, role: str = "MJCF") -> mujoco.MjModel:
    """MuJoCo's compiled model of the file (cached per file version); a clear error naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{role} file not found: {path}")
    stat = path.stat()
    return _compiled(str(path.resolve()), stat.st_mtime_ns, stat.st_size, role)


@lru_cache(maxsize=16)
def _compiled(path: str, _mtime_ns: int, _size: int, role: str) -> mujoco.MjModel:
    try:
        return mujoco.MjModel.from_xml_path(path)
    except ValueError as exc:
        text = str(exc).strip()
        hint = f"; {MESH_HINT}" if "opening file" in text.lower() or "resource not found" in text.lower() else ""
        raise ModelError(f"MuJoCo cannot load {role} {path}: {text}{hint}") from None


def joint_name(m: mujoco.MjModel, j: int) -> str:
    return m.joint(j).name or f"joint{j}"


def mjcf_joints(m: mujoco.MjModel) -> set[str]:
    """The names of the file's joints."""
    return {m.joint(j).name for j in range(m.njnt)}


def force_limits(m: mujoco.MjModel, joints) -> dict[str, tuple[float, float, str]]:
    """{joint: (low, high, source)} of the file's force limits on the named joints (N m or N); joints without
    any are left out. An actuator's `forcerange` if limited, else a motor's (fixed gain, no bias) gear x gain x
    `ctrlrange` (a servo's ctrlrange is a position: no force limit), within the joint's `actuatorfrcrange`."""
    joints = set(joints)
    limits: dict[str, tuple[float, float, str]] = {}
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        joint = joint_name(m, int(m.actuator_trnid[a, 0]))
        if joint not in joints or joint in limits:
            continue
        gear = float(m.actuator_gear[a, 0])
        motor = m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED and m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
        if m.actuator_forcelimited[a]:
            low, high = gear * m.actuator_forcerange[a]
            source = f"actuator '{m.actuator(a).name}' forcerange"
        elif motor and m.actuator_ctrllimited[a]:
            low, high = gear * m.actuator_gainprm[a, 0] * m.actuator_ctrlrange[a]
            source = f"motor '{m.actuator(a).name}' ctrlrange"
        else:
            continue
        limits[joint] = (float(min(low, high)), float(max(low, high)), source)
    for joint in joints:
        j = int(m.joint(joint).id)
        if m.jnt_actfrclimited[j]:
            low, high = (float(x) for x in m.jnt_actfrcrange[j])
            old = limits.get(joint, (-np.inf, np.inf, ""))
            limits[joint] = (max(low, old[0]), min(high, old[1]),
                             "joint actuatorfrcrange" + (f" and {old[2]}" if old[2] else ""))
    return limits


def keyframe_positions(m: mujoco.MjModel, name: str | None, path: Path) -> tuple[str | None, dict[str, float]]:
    """(keyframe, {hinge/slide joint: position relative to its zero}) of keyframe `name`, or of the file's first
    keyframe when `name` is None; (None, {}) for a file without keyframes (its zero pose)."""
    names = [m.key(k).name for k in range(m.nkey)]
    if name is None:
        if not names:
            return None, {}
        key = 0
    elif name in names:
        key = names.index(name)
    else:
        raise ModelError(f"MJCF {path} has no keyframe '{name}'; its keyframes: {', '.join(n or '(unnamed)' for n in names) or 'none'} "
                         "(--keyframe NAME; without it the file's first keyframe, or its zero pose)")
    qpos = m.key_qpos[key]
    out = {}
    for j in range(m.njnt):
        if int(m.jnt_type[j]) in _ONE_DOF:
            adr = int(m.jnt_qposadr[j])
            out[joint_name(m, j)] = float(qpos[adr] - m.qpos0[adr])
    return names[key] or f"key{key}", out


def drive_train(m: mujoco.MjModel, joints) -> dict[str, dict[str, float]]:
    """{"armature_kg_m2" | "viscous_friction_nm_s" | "coulomb_friction_nm": {joint: value}} from the file."""
    out = {"armature_kg_m2": {}, "viscous_friction_nm_s": {}, "coulomb_friction_nm": {}}
    for joint in joints:
        dof = int(m.joint(joint).dofadr[0])
        out["armature_kg_m2"][joint] = float(m.dof_armature[dof])
        out["viscous_friction_nm_s"][joint] = float(m.dof_damping[dof])
        out["coulomb_friction_nm"][joint] = float(m.dof_frictionloss[dof])
    return out


def _body_frame(model: pin.Model, m: mujoco.MjModel, body: int) -> pin.Frame:
    name = m.body(body).name
    if not model.existFrame(name, pin.FrameType.BODY):
        raise ModelError(f"body '{name}' of the MJCF has no frame in pinocchio's model")
    return model.frames[model.getFrameId(name, pin.FrameType.BODY)]


def _local(pos: np.ndarray, quat_wxyz: np.ndarray) -> pin.SE3:
    return pin.SE3(pin.Quaternion(float(quat_wxyz[0]), *map(float, quat_wxyz[1:])).toRotationMatrix(), np.array(pos))


def add_point_frames(model: pin.Model, m: mujoco.MjModel, names) -> None:
    """A frame for each named site or geom of the file that is not a frame of `model` yet (feet, hands)."""
    for name in names:
        if not name or model.existFrame(name):
            continue
        for kind, count, get in (("site", m.nsite, m.site), ("geom", m.ngeom, m.geom)):
            ids = [k for k in range(count) if get(k).name == name]
            if ids:
                element = get(ids[0])
                parent = _body_frame(model, m, int(element.bodyid[0]))
                placement = parent.placement * _local(element.pos, element.quat)
                model.addFrame(pin.Frame(name, parent.parentJoint, model.getFrameId(parent.name, pin.FrameType.BODY),
                                         placement, pin.FrameType.OP_FRAME))
                break


def collision_primitives(model: pin.Model, m: mujoco.MjModel) -> list[Primitive]:
    """The file's primitive collision geoms (box, sphere, capsule, cylinder; contype or conaffinity set) of the
    bodies that are frames of `model`, in the frame of the pinocchio joint that carries the body (meshes and
    planes are left out, as for URDFs)."""
    out, counts = [], {}
    for g in range(m.ngeom):
        kind = _KINDS.get(int(m.geom_type[g]))
        if kind is None or not (m.geom_contype[g] or m.geom_conaffinity[g]):
            continue
        body = int(m.geom_bodyid[g])
        if body == 0 or not model.existFrame(m.body(body).name, pin.FrameType.BODY):
            continue
        frame = _body_frame(model, m, body)
        size = m.geom_size[g]
        size = {"box": tuple(map(float, size)), "sphere": (float(size[0]),)}.get(kind, (float(size[0]), float(size[1])))
        index = counts[frame.name] = counts.get(frame.name, -1) + 1
        out.append(Primitive(frame.name, index, int(frame.parentJoint), kind, size,
                             frame.placement * _local(m.geom_pos[g], m.geom_quat[g])))
    return out
