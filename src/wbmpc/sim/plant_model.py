"""A plant that is not the controller's model: MuJoCo simulates another file of the same robot (`--plant-model`).

The controller plans with its `RobotModel` (say example-robot-data's Go2 URDF); the plant is the robot as another
file describes it (say unitree_mujoco's `go2.xml`: other masses, inertias, foot spheres, joint damping, armature,
friction losses and contact settings). Nothing of the controller's model goes into the plant.

An MJCF file is loaded by MuJoCo as it is (includes, `<default>` classes, meshes, options) and then edited:

- its actuators (Menagerie's position servos, Unitree's torque motors) are replaced by one torque motor per
  controller joint, limited to the file's force limits (an actuator's `forcerange`, else a motor's gear *
  gain * `ctrlrange`; the joint's `actuatorfrcrange` stays, MuJoCo applies it), so that the motor law of eq. 10
  drives the plant as it drives a robot;
- its sensors and keyframes go: the plant reads qpos/qvel (as for wbmpc's own scene) and wbmpc sets the state;
- the static geoms of its world body (a floor, a terrain plane) go; wbmpc's floor (friction `friction_mu`,
  priority 0, so that foot geoms with a priority keep their own friction as in Unitree's and Menagerie's
  scenes) and the scene's objects are added;
- joints the controller locks are welded at the controller's angles;
- the time step is the plant's `dt_s`; the file's other options (integrator, cone, impratio, ...) stay.

A URDF is simulated as wbmpc's own scene of that file: its inertias, its primitive collision geometry, foot
spheres of its own radius and its `<dynamics damping friction>` (viscous and dry joint friction).

Joints are matched by name (an error lists both sides where they differ); a joint whose axis the file points
the other way gets the opposite sign, a joint `ref` an offset. The controller's base frame is the frame of the
body with the file's free joint; the joint anchors of both models at their zero pose are compared and the largest
distance reported (`joint_anchor_mismatch_m`). The drive-train fields of `PlantConfig` (armature, damping,
frictionloss) are added to the file's own.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError
from wbmpc.robots import RobotModel
from wbmpc.robots.mjcf import MESH_HINT, force_limits, joint_name
from wbmpc.sim.mujoco_scene import (
    ENV_CONAFFINITY,
    ENV_CONTYPE,
    MujocoPlantConfig,
    SceneBodies,
    SceneRobot,
    register_scene_bodies,
)

OBJECT_PREFIX = "wbmpc_object_"  # the scene's objects while they are attached (then renamed back)
FOOT_GEOM_RADIUS_M = 0.05  # a foot's contact geoms: those of its rigid body within this of the contact point
AXIS_TOLERANCE = 1e-3  # |cos| of the angle between the two models' joint axes must be within this of 1


def build_plant_scene(robot: RobotModel, config: MujocoPlantConfig) -> tuple[mujoco.MjModel, SceneRobot]:
    """The compiled scene of `config.plant_model` with the floor and the scene's objects, and where the
    controller's robot is in it (see the module docstring)."""
    path = Path(config.plant_model)
    if not path.is_file():
        raise ModelError(f"plant model file not found: {path} (--plant-model takes an MJCF .xml or a URDF)")
    kind = "urdf" if path.suffix.lower() == ".urdf" else "mjcf"
    spec = _urdf_spec(robot, path, config) if kind == "urdf" else _load_spec(path)
    _name_unnamed(spec)
    original = _compile(spec.copy(), path)
    match = _match(robot, original, path)
    limits = force_limits(original, match["sign"])
    report = _report(robot, original, match, limits, path, kind)
    _replace_actuators(spec, robot, limits)
    for element in (*spec.sensors, *spec.keys):
        spec.delete(element)
    dropped = _drop_world_geoms(spec)  # a URDF's: wbmpc's own floor of that scene, added again below as for any file
    report["dropped_world_geoms"] = dropped if kind == "mjcf" else []
    _weld_locked_joints(spec, original, robot, match)
    _add_drive_train(spec, robot, config)
    spec.option.timestep = config.dt_s
    _add_environment(spec, config, match["bodies"].names[0])
    register_scene_bodies(spec, match["bodies"])
    if config.spec_callback is not None:
        config.spec_callback(spec)
    model = _compile(spec, path)
    layout = _layout(robot, model, match, report, path)
    report["timestep_s"] = float(model.opt.timestep)
    # the robot as simulated: with the model errors of a campaign and anything mounted on it
    report["mass_kg"] = float(sum(model.body_mass[b] for b in _subtree(model, int(model.body(match["bodies"].names[0]).id))))
    return model, layout


# ------------------------------------------------------------------------------------------- loading
def _load_spec(path: Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise ModelError(f"MuJoCo cannot read plant model {path}: {exc}") from None


def _compile(spec: mujoco.MjSpec, path: Path) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        text = str(exc).strip()
        hint = f"; {MESH_HINT}" if "opening file" in text.lower() or "resource not found" in text.lower() else ""
        raise ModelError(f"MuJoCo cannot load plant model {path}: {text}{hint}") from None


def _name_unnamed(spec: mujoco.MjSpec) -> None:
    """Names for the file's unnamed bodies and free joints: the plant finds them by name after each compile."""
    taken = {b.name for b in spec.bodies} | {j.name for j in spec.joints}
    for k, body in enumerate(spec.bodies):
        if not body.name and body is not spec.worldbody and body.parent is not None:
            body.name = _free_name(f"wbmpc_body{k}", taken)
    for joint in spec.joints:
        if not joint.name and joint.type == mujoco.mjtJoint.mjJNT_FREE:
            joint.name = _free_name("root_joint", taken)


def _free_name(name: str, taken: set[str]) -> str:
    candidate, k = name, 1
    while candidate in taken:
        candidate, k = f"{name}_{k}", k + 1
    taken.add(candidate)
    return candidate


def _urdf_spec(robot: RobotModel, path: Path, config: MujocoPlantConfig) -> mujoco.MjSpec:
    """wbmpc's own scene of another URDF of the robot (the same foot and end-effector frames and kind of feet),
    with the file's `<dynamics damping friction>` as the joints' damping and frictionloss and its effort limits."""
    import dataclasses

    from wbmpc.robots import RobotSpec
    from wbmpc.sim.mujoco_scene import build_mjcf, self_contact_exclusions

    spec = RobotSpec(name=path.stem, urdf=path, feet=robot.feet, arm_ee=robot.arm_ee,
                     foot_contact="surface" if robot.soles else "point", sole_m=robot.spec.sole_m)
    try:
        plant_robot = RobotModel(spec)
    except ModelError as exc:
        raise ModelError(f"plant model {path}: {exc}") from None
    raw = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    column = {name: raw.idx_vs[raw.getJointId(name)] for name in plant_robot.joint_names}
    drive = {"joint_damping_nm_s_per_rad": {n: float(raw.damping[i]) for n, i in column.items()},
             "joint_frictionloss_nm": {n: float(raw.friction[i]) for n, i in column.items()},
             "joint_armature_kg_m2": 0.0}
    own = dataclasses.replace(config, plant_model=None, spec_callback=None, extra_bodies_mjcf=(), **drive)
    scene = mujoco.MjSpec.from_string(build_mjcf(plant_robot, own))
    if config.self_collision:
        for first, second in self_contact_exclusions(plant_robot, _compile(scene.copy(), path)):
            scene.add_exclude(bodyname1=first, bodyname2=second)
    return scene


# ------------------------------------------------------------------------------------------- matching
def _match(robot: RobotModel, m: mujoco.MjModel, path: Path) -> dict:
    """The plant's root, its joints matched to the controller's by name, their signs and offsets, its bodies."""
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    if not free:
        raise ModelError(f"plant model {path} has no free joint: a legged robot's root body needs one "
                         "(<freejoint/> in its MJCF root body)")
    subtree = {j: _subtree(m, int(m.jnt_bodyid[j])) for j in free}
    names = {joint_name(m, j): j for j in range(m.njnt)}
    controller = set(robot.joint_names) | set(robot.locked_positions)
    root = max(free, key=lambda j: sum(n in names and int(m.jnt_bodyid[names[n]]) in subtree[j] for n in controller))
    bodies = subtree[root]
    plant_joints = [joint_name(m, j) for j in range(m.njnt) if j != root and int(m.jnt_bodyid[j]) in bodies]
    missing = [n for n in robot.joint_names if n not in plant_joints]  # a locked joint may be rigid in the file
    extra = [n for n in plant_joints if n not in controller]
    if missing or extra:
        raise ModelError(
            f"the joints of plant model {path} do not match the controller's ({robot.name}); joints are matched by name."
            + (f" Not in the plant model: {', '.join(missing)}." if missing else "")
            + (f" In the plant model only: {', '.join(extra)} (lock them in the controller, --lock, or remove them)."
               if extra else "")
            + f" Controller joints: {', '.join(robot.joint_names)}"
            + (f" (locked: {', '.join(robot.locked_positions)})" if robot.locked_positions else "")
            + f". Plant model joints: {', '.join(plant_joints)}")
    full, full_data = robot.full_model, robot.full_model.createData()
    pin.forwardKinematics(full, full_data, pin.neutral(full))
    data = mujoco.MjData(m)
    data.qpos[:] = m.qpos0
    _set_root(m, data, root, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))
    mujoco.mj_kinematics(m, data)
    sign, offset, anchor_error = {}, {}, {}
    for name in (n for n in controller if n in plant_joints):
        jid, pj = full.getJointId(name), names[name]
        kind = {int(mujoco.mjtJoint.mjJNT_SLIDE): "slide", int(mujoco.mjtJoint.mjJNT_HINGE): "hinge"}.get(int(m.jnt_type[pj]))
        motion = np.array(full_data.joints[jid].S).ravel()  # (linear, angular) in the joint frame
        prismatic = full.joints[jid].shortname().startswith(("JointModelP", "JointModelPrismatic"))
        if kind is None or prismatic != (kind == "slide") or full.joints[jid].nv != 1:
            raise ModelError(f"joint '{name}' is a {full.joints[jid].shortname()} in the controller's model and a "
                             f"{mujoco.mjtJoint(m.jnt_type[pj]).name} in plant model {path}; they must be the same kind")
        axis_c = full_data.oMi[jid].rotation @ (motion[:3] if prismatic else motion[3:])
        axis_p = data.xaxis[pj]
        cos = float(axis_c @ axis_p / (np.linalg.norm(axis_c) * np.linalg.norm(axis_p)))
        if abs(abs(cos) - 1.0) > AXIS_TOLERANCE:
            raise ModelError(f"joint '{name}' turns about {np.round(axis_c, 4).tolist()} in the controller's model and "
                             f"about {np.round(axis_p, 4).tolist()} in plant model {path} (both at their zero pose): "
                             "not the same robot, or a different zero pose")
        sign[name] = 1.0 if cos > 0 else -1.0
        offset[name] = float(m.qpos0[m.jnt_qposadr[pj]])
        anchor_error[name] = float(np.linalg.norm(full_data.oMi[jid].translation - data.xanchor[pj]))
    match = dict(root_name=joint_name(m, root), sign=sign, offset=offset, anchor_error=anchor_error,
                 robot_bodies=bodies, locked={n: a for n, a in robot.locked_positions.items() if n in plant_joints})
    match["bodies"] = _bodies_at_nominal(robot, m, match)
    return match


def _bodies_at_nominal(robot: RobotModel, m: mujoco.MjModel, match: dict) -> SceneBodies:
    """The plant body of each controller joint and the controller's joint frame in it, both models at the nominal pose."""
    data = mujoco.MjData(m)
    data.qpos[:] = m.qpos0
    _set_plant_pose(robot, m, data, match, robot.q_nominal)
    mujoco.mj_kinematics(m, data)
    model, pdata = robot.model, robot.model.createData()
    pin.forwardKinematics(model, pdata, robot.q_nominal)
    names, frames = [], []
    for jid in range(1, model.njoints):
        body = int(m.joint(match["root_name"] if jid == 1 else model.names[jid]).bodyid[0])
        placement = pin.SE3(data.xmat[body].reshape(3, 3).copy(), data.xpos[body].copy())
        names.append(m.body(body).name or f"body{body}")
        frames.append(placement.actInv(pdata.oMi[jid]))
    return SceneBodies(tuple(names), tuple(frames))


def _foot_geoms(robot: RobotModel, m: mujoco.MjModel, match: dict, path: Path) -> tuple[tuple[int, ...], ...]:
    """Each foot's contact geoms: collision geoms of the rigid body carrying the foot within FOOT_GEOM_RADIUS_M of
    its contact point (at the plant's nominal pose), else all of that rigid body's collision geoms."""
    data = mujoco.MjData(m)
    data.qpos[:] = m.qpos0
    _set_plant_pose(robot, m, data, match, robot.q_nominal)
    mujoco.mj_kinematics(m, data)
    bodies: SceneBodies = match["bodies"]
    out = []
    collides = (np.asarray(m.geom_contype) | np.asarray(m.geom_conaffinity)) > 0
    for foot in robot.feet:
        body_name, placement = bodies.frame(robot, robot.contact_frame(foot))
        body = int(m.body(body_name).id)
        point = data.xpos[body] + data.xmat[body].reshape(3, 3) @ placement.translation
        weld = int(m.body_weldid[body])
        candidates = [g for g in range(m.ngeom) if collides[g] and int(m.body_weldid[m.geom_bodyid[g]]) == weld]
        if not candidates:
            raise ModelError(f"foot '{foot}' is on body '{body_name}' of plant model {path}, which has no collision "
                             "geom (contype/conaffinity 0 on all): the plant's foot cannot touch the floor")
        near = [g for g in candidates if np.linalg.norm(data.geom_xpos[g] - point) <= FOOT_GEOM_RADIUS_M]
        out.append(tuple(near or candidates))
    return tuple(out)


def _set_plant_pose(robot: RobotModel, m: mujoco.MjModel, data: mujoco.MjData, match: dict, q: np.ndarray) -> None:
    """The plant at the controller's configuration q (joints the plant welded are left out)."""
    _set_root(m, data, m.joint(match["root_name"]).id, q[:3], q[[6, 3, 4, 5]])
    angles = dict(zip(robot.joint_names, robot.joint_positions(q)))
    angles.update(match["locked"])
    joints = {joint_name(m, j): j for j in range(m.njnt)}
    for name, angle in angles.items():
        if name in joints:
            data.qpos[m.jnt_qposadr[joints[name]]] = match["offset"][name] + match["sign"][name] * angle


def _set_root(m: mujoco.MjModel, data: mujoco.MjData, joint: int, position: np.ndarray, quat_wxyz: np.ndarray) -> None:
    adr = int(m.jnt_qposadr[joint])
    data.qpos[adr:adr + 3] = position
    data.qpos[adr + 3:adr + 7] = quat_wxyz


def _subtree(m: mujoco.MjModel, root: int) -> set[int]:
    out = {root}
    for b in range(root + 1, m.nbody):  # bodies are numbered depth first: a subtree follows its root
        if int(m.body_parentid[b]) in out:
            out.add(b)
    return out


# ------------------------------------------------------------------------------------------- actuators
def _replace_actuators(spec: mujoco.MjSpec, robot: RobotModel, limits: dict) -> None:
    """The file's actuators out, one torque motor (gear 1) per controller joint in (named after the joint)."""
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for name in robot.joint_names:
        motor = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        motor.set_to_motor()
        motor.gear = [1.0, 0, 0, 0, 0, 0]
        low, high, _ = limits.get(name, (-np.inf, np.inf, ""))
        if np.isfinite(low) and np.isfinite(high):
            motor.ctrlrange = [low, high]
            motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        else:
            motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        motor.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE


def _drop_world_geoms(spec: mujoco.MjSpec) -> list[str]:
    """Remove the geoms of the world body (the file's floor or terrain): wbmpc adds its own floor."""
    dropped = []
    for geom in list(spec.worldbody.geoms):
        dropped.append(geom.name or mujoco.mjtGeom(geom.type).name.removeprefix("mjGEOM_").lower())
        spec.delete(geom)
    return dropped


def _weld_locked_joints(spec: mujoco.MjSpec, m: mujoco.MjModel, robot: RobotModel, match: dict) -> None:
    """Joints the controller locks become rigid at the controller's angle: the joint goes, its body turns
    (or slides) about the joint's anchor by that angle in its parent's frame."""
    for name, angle in match["locked"].items():
        pj = int(m.joint(name).id)
        body_id = int(m.jnt_bodyid[pj])
        value = match["sign"][name] * angle  # qpos - qpos0
        anchor, axis = np.array(m.jnt_pos[pj]), np.array(m.jnt_axis[pj])
        rotation, shift = np.eye(3), np.zeros(3)
        if m.jnt_type[pj] == mujoco.mjtJoint.mjJNT_HINGE:
            rotation = pin.AngleAxis(value, axis / np.linalg.norm(axis)).toRotationMatrix()
            shift = anchor - rotation @ anchor
        else:
            shift = value * axis / np.linalg.norm(axis)
        body_rotation = _quat_matrix(m.body_quat[body_id])
        body = spec.body(m.body(body_id).name)
        body.pos = m.body_pos[body_id] + body_rotation @ shift
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, (body_rotation @ rotation).ravel())
        body.quat = quat
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
        spec.delete(spec.joint(name))


def _quat_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat_wxyz, dtype=float))
    return out.reshape(3, 3)


def _add_drive_train(spec: mujoco.MjSpec, robot: RobotModel, config: MujocoPlantConfig) -> None:
    """`PlantConfig`'s armature, damping and frictionloss on top of the file's own values."""
    columns = {field: config.joint_array(robot, field) for field in
               ("joint_armature_kg_m2", "joint_damping_nm_s_per_rad", "joint_frictionloss_nm")}
    for k, name in enumerate(robot.joint_names):
        joint = spec.joint(name)
        joint.armature = joint.armature + columns["joint_armature_kg_m2"][k]
        damping = np.array(joint.damping, dtype=float)
        damping[0] += columns["joint_damping_nm_s_per_rad"][k]
        joint.damping = damping
        joint.frictionloss = joint.frictionloss + columns["joint_frictionloss_nm"][k]


def _add_environment(spec: mujoco.MjSpec, config: MujocoPlantConfig, root_body: str) -> None:
    """wbmpc's floor (see the module docstring), a light, the tracking camera and the scene's objects."""
    world = spec.worldbody
    world.add_light(name="wbmpc_sun", pos=[0, 0, 5], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], rgba=[0.25, 0.35, 0.45, 1],
                   contype=ENV_CONTYPE, conaffinity=ENV_CONAFFINITY, condim=3, priority=0,
                   friction=[config.friction_mu, config.torsional_friction_m, 0.0001],
                   solref=[config.contact_timeconst, config.contact_dampratio], solimp=list(config.contact_solimp))
    if not any(c.name == "track" for c in spec.cameras):
        spec.body(root_body).add_camera(name="track", mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, pos=[0, -2.5, 1.0],
                             quat=_camera_quat())
    if not config.extra_bodies_mjcf:
        return
    import xml.etree.ElementTree as ET

    from wbmpc.sim.base import PlantInputError
    from wbmpc.sim.mujoco_scene import _f, _v

    default = (f'<default><geom contype="{ENV_CONTYPE}" conaffinity="{ENV_CONAFFINITY}" condim="3" '
               f'friction="{_v([config.friction_mu, config.torsional_friction_m, 0.0001])}" '
               f'solref="{_f(config.contact_timeconst)} {_f(config.contact_dampratio)}" '
               f'solimp="{_v(config.contact_solimp)}"/></default>')
    for k, snippet in enumerate(config.extra_bodies_mjcf):
        try:
            name = ET.fromstring(snippet).get("name")
        except ET.ParseError as exc:
            raise PlantInputError(f"extra_bodies_mjcf[{k}] is not valid XML: {exc}") from exc
        child = mujoco.MjSpec.from_string(f"<mujoco>{default}<worldbody>{snippet}</worldbody></mujoco>")
        world.add_frame().attach_body(child.body(name) if name else child.worldbody.first_body(), OBJECT_PREFIX, "")
    for element in (*spec.bodies, *spec.joints, *spec.geoms, *spec.sites):  # the names the objects' code looks up
        if element.name.startswith(OBJECT_PREFIX):
            element.name = element.name.removeprefix(OBJECT_PREFIX)


def _camera_quat() -> list[float]:
    """wbmpc's tracking camera: behind and above, looking forward and down (xyaxes 1 0 0, 0 0.37 0.93)."""
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.37, 0.93])
    y /= np.linalg.norm(y)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([x, y, np.cross(x, y)]).ravel())
    return quat.tolist()


# ------------------------------------------------------------------------------------------- layout, report
def _layout(robot: RobotModel, model: mujoco.MjModel, match: dict, report: dict, path: Path) -> SceneRobot:
    root_body = int(model.body(match["bodies"].names[0]).id)
    robot_bodies = _subtree(model, root_body)
    robot_geoms = np.array([int(model.geom_bodyid[g]) in robot_bodies for g in range(model.ngeom)], dtype=bool)
    return SceneRobot(
        root_joint=match["root_name"], joints=tuple(robot.joint_names),
        joint_sign=np.array([match["sign"][n] for n in robot.joint_names]),
        joint_offset=np.array([match["offset"][n] for n in robot.joint_names]),
        actuators=tuple(int(model.actuator(n).id) for n in robot.joint_names),
        bodies=match["bodies"], foot_geoms=_foot_geoms(robot, model, match, path), robot_geoms=robot_geoms,
        plant_model=report)


def _report(robot: RobotModel, m: mujoco.MjModel, match: dict, limits: dict, path: Path, kind: str) -> dict:
    """What the plant ran: the file, its mass against the controller's, limits, flips, offsets."""
    bodies = sorted(match["robot_bodies"])
    worst = max(match["anchor_error"], key=match["anchor_error"].get) if match["anchor_error"] else None
    return {
        "file": str(path), "format": kind,
        "mass_kg": float(sum(m.body_mass[b] for b in bodies)), "controller_mass_kg": float(robot.mass_kg),
        "torque_limit_nm": {n: [limits[n][0], limits[n][1]] if n in limits else None for n in robot.joint_names},
        "controller_torque_limit_nm": {n: float(t) for n, t in zip(robot.joint_names, robot.tau_max)},
        "joints_reversed": sorted(n for n, s in match["sign"].items() if s < 0),
        "joint_offsets_rad": {n: o for n, o in sorted(match["offset"].items()) if o != 0.0},
        "welded_joints": sorted(match["locked"]),
        "joint_anchor_mismatch_m": match["anchor_error"][worst] if worst else 0.0,
        "joint_anchor_mismatch_joint": worst,
        "options": {"integrator": mujoco.mjtIntegrator(m.opt.integrator).name.removeprefix("mjINT_"),
                    "cone": mujoco.mjtCone(m.opt.cone).name.removeprefix("mjCONE_").lower(),
                    "impratio": float(m.opt.impratio)},
    }
