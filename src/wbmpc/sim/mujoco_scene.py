"""A MuJoCo scene (MJCF) built from a `RobotModel`: same kinematics and inertias as pinocchio.

One MuJoCo body per pinocchio joint, named after the link that joint carries (e.g. `base`,
`FL_calf`); joints keep pinocchio's names (`root_joint` is the free joint); one `motor` actuator
per joint in `robot.joint_names` order. Inertias are written with `fullinertia` at full precision.

Collision filtering: robot geoms have contype=2, everything else (floor, objects) contype=1/conaffinity=3,
so the robot touches the environment. Robot-robot contacts (`self_collision`, on by default) give robot
geoms conaffinity=3 (else 1: the robot never touches itself); MuJoCo leaves out a body and its parent,
and `<exclude>` leaves out the body pairs whose shapes touch at the nominal pose (the arm's base on the
trunk) and those of a body and its grandparent that touch somewhere within the joint limits (a hip
rotor on the trunk and the thigh: the URDF's primitives overlap where the real parts do not). Extra scene
objects are MJCF `<body>` snippets added to the worldbody (their geoms inherit the environment
defaults), or arbitrary edits through `spec_callback(spec: mujoco.MjSpec)` before compilation; such an
edit finds the robot's bodies with `scene_bodies(spec, robot)`, in this scene and in a plant model's.

With `MujocoPlantConfig.plant_model` the robot is another file of the same robot instead
(`wbmpc.sim.plant_model`); `build_scene` gives either scene and `SceneRobot`, where the controller's
joints, actuators, bodies and feet are in it.
"""

from __future__ import annotations

import weakref
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from wbmpc.robots import RobotModel
from wbmpc.sim.base import PlantConfig, PlantInputError
from wbmpc.sim.shapes import CollisionShape, robot_collision_shapes
from wbmpc.sim.terrain_geoms import add_terrain
from wbmpc.terrain import Terrain

ROBOT_CONTYPE, ROBOT_CONAFFINITY = 2, 1
ROBOT_SELF_CONAFFINITY = ROBOT_CONAFFINITY | ROBOT_CONTYPE  # robot geoms that touch the robot too
ENV_CONTYPE, ENV_CONAFFINITY = 1, 3
SELF_CONTACT_TOUCH_M = 0.005  # robot shapes this close at the nominal pose touch by design (excluded)
SELF_CONTACT_SAMPLES = 200  # random joint configurations for the grandparent exclusions
DEFAULT_CONTACT_TIMECONST_S = 0.005  # the floor contact's solref time constant on steps up to 2.5 ms
MIN_MASS_KG = 1e-9
MIN_INERTIA_KG_M2 = 1e-9
_JOINT_AXES = {
    "RX": "1 0 0", "RY": "0 1 0", "RZ": "0 0 1", "RUBX": "1 0 0", "RUBY": "0 1 0", "RUBZ": "0 0 1",
    "PX": "1 0 0", "PY": "0 1 0", "PZ": "0 0 1",
}  # fmt: skip


@dataclass(frozen=True)
class MujocoPlantConfig(PlantConfig):
    """MuJoCo scene settings on top of `PlantConfig` (units in the names).

    Contacts use MuJoCo's soft-constraint model: `contact_timeconst_s` (>= 2 dt for stability; None: 5 ms,
    or 2 dt on a physics step longer than 2.5 ms) and `contact_dampratio` form `solref`; `contact_solimp` is
    MuJoCo's impedance tuple.
    """

    contact_timeconst_s: float | None = None
    contact_dampratio: float = 1.0
    contact_solimp: tuple[float, float, float, float, float] = (0.95, 0.99, 0.001, 0.5, 2.0)
    torsional_friction_m: float = 0.0
    # joint dry friction (joint_frictionloss_nm) is a soft constraint in MuJoCo; with its default
    # impedance a joint held at half its friction torque still creeps at ~0.3 rad/s, so it gets a
    # stiff one: time constant (None: 2 dt_s) and impedance
    joint_friction_timeconst_s: float | None = None
    joint_friction_solimp: tuple[float, float, float, float, float] = (0.99, 0.999, 0.001, 0.5, 2.0)
    integrator: str = "implicitfast"  # Euler | RK4 | implicit | implicitfast
    cone: str = "elliptic"  # elliptic | pyramidal
    use_urdf_collision_primitives: bool = True
    ee_sphere_radius_m: float | None = 0.03
    extra_bodies_mjcf: tuple[str, ...] = ()
    spec_callback: Callable[[mujoco.MjSpec], None] | None = None
    terrain: Terrain | None = None  # boxes, ramps, heightmaps and the floor's height (sim/terrain_geoms.py)
    self_collision: bool = True  # robot-robot contacts (see the module docstring); counted by the plant
    # another file of the same robot (MJCF or URDF) that MuJoCo simulates instead of the controller's model
    # (`wbmpc.sim.plant_model`); None: the scene is built from the controller's `RobotModel`
    plant_model: str | Path | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.integrator not in ("Euler", "RK4", "implicit", "implicitfast"):
            raise PlantInputError(f"integrator must be Euler, RK4, implicit or implicitfast, got {self.integrator!r}")
        if self.cone not in ("elliptic", "pyramidal"):
            raise PlantInputError(f"cone must be 'elliptic' or 'pyramidal', got {self.cone!r}")
        timeconst = self.joint_friction_timeconst_s
        if timeconst is not None and not (np.isfinite(timeconst) and timeconst >= 2 * self.dt_s):
            raise PlantInputError(f"joint_friction_timeconst_s ({timeconst}) must be >= 2 * dt_s ({2 * self.dt_s})")
        if self.contact_timeconst_s is not None and not self.contact_timeconst_s >= 2 * self.dt_s:
            raise PlantInputError(
                f"contact_timeconst_s ({self.contact_timeconst_s}) must be >= 2 * dt_s ({2 * self.dt_s}) for a stable contact"
            )

    @property
    def contact_timeconst(self) -> float:
        """The floor contact's time constant in use (s): `contact_timeconst_s`, or its default for `dt_s`."""
        if self.contact_timeconst_s is not None:
            return self.contact_timeconst_s
        return max(DEFAULT_CONTACT_TIMECONST_S, 2 * self.dt_s)


@dataclass(frozen=True)
class SceneBodies:
    """The MuJoCo body carrying each pinocchio joint 1..njoints-1 of the controller's model (`names`) and that
    joint's frame in the body's frame (`joint_frames`): identities in wbmpc's own scene, a plant model's own
    body frames otherwise."""

    names: tuple[str, ...]
    joint_frames: tuple[pin.SE3, ...]

    def body(self, joint_id: int) -> str:
        return self.names[joint_id - 1]

    def frame(self, robot: RobotModel, frame: str) -> tuple[str, pin.SE3]:
        """(MuJoCo body, placement in that body's frame) of a frame of the controller's model."""
        f = robot.model.frames[robot.frame_id(frame)]
        return self.names[f.parentJoint - 1], self.joint_frames[f.parentJoint - 1] * f.placement


@dataclass(frozen=True)
class SceneRobot:
    """Where the controller's robot is in a compiled scene. Joint k of `robot.joint_names` is MuJoCo joint
    `joints[k]` with qpos = `joint_offset[k]` + `joint_sign[k]` * q_k (an axis the file points the other way,
    a `ref`), driven by actuator `actuators[k]` (ids) with ctrl = sign * tau; `foot_geoms[i]`: the geom ids that
    make foot i's contacts; `robot_geoms`: (ngeom,) True for the robot's geoms; `plant_model`: the plant model's
    report (None in wbmpc's own scene)."""

    root_joint: str
    joints: tuple[str, ...]
    joint_sign: np.ndarray
    joint_offset: np.ndarray
    actuators: tuple[int, ...]
    bodies: SceneBodies
    foot_geoms: tuple[tuple[int, ...], ...]
    robot_geoms: np.ndarray
    plant_model: dict | None = None


_SCENE_BODIES: "weakref.WeakKeyDictionary[mujoco.MjSpec, SceneBodies]" = weakref.WeakKeyDictionary()


def scene_bodies(spec: mujoco.MjSpec, robot: RobotModel) -> SceneBodies:
    """The robot's bodies in the scene `spec` is building (for `spec_callback` edits: sites at a frame, payloads)."""
    return _SCENE_BODIES.get(spec) or own_scene_bodies(robot)


def register_scene_bodies(spec: mujoco.MjSpec, bodies: SceneBodies) -> None:
    _SCENE_BODIES[spec] = bodies


def own_scene_bodies(robot: RobotModel) -> SceneBodies:
    names = tuple(body_names(robot))
    return SceneBodies(names, tuple(pin.SE3.Identity() for _ in names))


def build_scene(robot: RobotModel, config: MujocoPlantConfig | None = None) -> tuple[mujoco.MjModel, SceneRobot]:
    """The compiled scene and where the robot is in it: wbmpc's own scene of `robot`, or with
    `config.plant_model` that file's robot (`wbmpc.sim.plant_model`)."""
    config = config or MujocoPlantConfig()
    if config.plant_model is not None:
        from wbmpc.sim.plant_model import build_plant_scene

        return build_plant_scene(robot, config)
    model = build_model(robot, config)
    n = robot.n_joints
    layout = SceneRobot(
        root_joint=robot.model.names[1], joints=tuple(robot.joint_names), joint_sign=np.ones(n), joint_offset=np.zeros(n),
        actuators=tuple(int(model.actuator(name).id) for name in robot.joint_names),
        bodies=own_scene_bodies(robot), foot_geoms=tuple((int(model.geom(f).id),) for f in robot.feet),
        robot_geoms=is_robot_geom(model))
    return model, layout


def body_names(robot: RobotModel) -> list[str]:
    """MuJoCo body name of each pinocchio joint 1..njoints-1: its link (identity-placed BODY frame)."""
    model, names = robot.model, []
    for jid in range(1, model.njoints):
        links = [
            f.name
            for f in model.frames
            if f.parentJoint == jid and f.type == pin.FrameType.BODY and f.placement.isIdentity(1e-12)
        ]
        name = next((n for n in links if n not in names), model.names[jid])
        names.append(name)
    return names


def mujoco_inertia(mass_kg: float, inertia_kg_m2: np.ndarray) -> tuple[float, np.ndarray]:
    """Mass and rotational inertia (about the centre of mass) as MuJoCo accepts them.

    MuJoCo rejects moving bodies without mass (the massless links between the axes of a URDF
    ball joint), inertias that are not positive definite (point masses) and principal moments
    violating the triangle inequality A + B >= C (not a physical body). Such inputs get
    MIN_MASS_KG, principal moments of at least MIN_INERTIA_KG_M2 and the two smaller moments
    raised until A + B = C; physical inertias pass unchanged (see `regularised_bodies`).
    """
    mass = max(float(mass_kg), MIN_MASS_KG)
    inertia = 0.5 * (np.asarray(inertia_kg_m2, dtype=float) + np.asarray(inertia_kg_m2, dtype=float).T)
    moments, axes = np.linalg.eigh(inertia)
    fixed = np.maximum(moments, MIN_INERTIA_KG_M2)
    deficit = fixed[2] - fixed[0] - fixed[1]
    if deficit > 0:
        fixed[:2] += 0.5 * deficit * (1 + 1e-9)
    if np.array_equal(fixed, moments) and mass == mass_kg:
        return mass, np.asarray(inertia_kg_m2, dtype=float)
    return mass, axes @ np.diag(fixed) @ axes.T


def regularised_bodies(robot: RobotModel) -> list[str]:
    """MuJoCo bodies whose mass or inertia `mujoco_inertia` had to change (the plant then differs
    slightly from the pinocchio model there)."""
    out = []
    for jid, name in enumerate(body_names(robot), start=1):
        inertia = robot.model.inertias[jid]
        mass, rotational = mujoco_inertia(inertia.mass, inertia.inertia)
        if mass != inertia.mass or not np.array_equal(rotational, inertia.inertia):
            out.append(name)
    return out


def build_mjcf(robot: RobotModel, config: MujocoPlantConfig | None = None) -> str:
    """The MJCF text of the robot on a floor (plus `config.extra_bodies_mjcf`)."""
    config = config or MujocoPlantConfig()
    model = robot.model
    root = ET.Element("mujoco", model=robot.name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="auto", balanceinertia="false")
    ET.SubElement(
        root,
        "option",
        timestep=_f(config.dt_s),
        integrator=config.integrator,
        cone=config.cone,
        gravity=_v(model.gravity.linear),
    )
    visual = ET.SubElement(root, "visual")
    ET.SubElement(visual, "global", offwidth="1280", offheight="720")
    _defaults(root, config)
    asset = ET.SubElement(root, "asset")
    ET.SubElement(
        asset, "texture", name="grid", type="2d", builtin="checker", rgb1=".2 .3 .4", rgb2=".3 .4 .5", width="512", height="512"
    )
    ET.SubElement(asset, "material", name="grid", texture="grid", texrepeat="1 1", texuniform="true", reflectance=".1")

    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", name="sun", pos="0 0 5", dir="0 0 -1", directional="true")
    ET.SubElement(world, "geom", name="floor", type="plane", size="0 0 0.05", material="grid", priority="1")
    shapes = robot_collision_shapes(robot, config.use_urdf_collision_primitives, config.ee_sphere_radius_m)
    if config.terrain is not None:
        add_terrain(root, asset, world, config.terrain)
    _add_bodies(world, robot, shapes, body_names(robot), _drive_train(robot, config))
    for k, snippet in enumerate(config.extra_bodies_mjcf):
        try:
            world.append(ET.fromstring(snippet))
        except ET.ParseError as exc:
            raise PlantInputError(f"extra_bodies_mjcf[{k}] is not valid XML: {exc}") from exc

    actuator = ET.SubElement(root, "actuator")
    for name, tau in zip(robot.joint_names, robot.tau_max):
        ET.SubElement(actuator, "motor", name=name, joint=name, gear="1", ctrlrange=_v([-tau, tau]), forcerange=_v([-tau, tau]))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def build_model(robot: RobotModel, config: MujocoPlantConfig | None = None) -> mujoco.MjModel:
    """Compile the scene; `config.spec_callback` may edit the `mujoco.MjSpec` first."""
    config = config or MujocoPlantConfig()
    spec = mujoco.MjSpec.from_string(build_mjcf(robot, config))
    if config.spec_callback is not None:
        config.spec_callback(spec)
    model = spec.compile()
    if not config.self_collision:
        return model
    for first, second in self_contact_exclusions(robot, model):
        spec.add_exclude(bodyname1=first, bodyname2=second)
    return spec.compile()


def is_robot_geom(model: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) True for the robot's geoms (contype ROBOT_CONTYPE)."""
    return (np.asarray(model.geom_contype) & ROBOT_CONTYPE) > 0


def self_contact_exclusions(robot: RobotModel, model: mujoco.MjModel, seed: int = 0) -> list[tuple[str, str]]:
    """Body pairs left out of robot-robot contacts (see the module docstring): touching at the nominal pose,
    or a body and its grandparent touching in one of SELF_CONTACT_SAMPLES random configurations."""
    data = mujoco.MjData(model)
    robot_geoms = np.flatnonzero(is_robot_geom(model))
    parent = np.asarray(model.body_parentid)
    body = np.asarray(model.geom_bodyid)
    pairs = [(g1, g2) for i, g1 in enumerate(robot_geoms) for g2 in robot_geoms[i + 1:]
             if body[g1] != body[g2] and parent[body[g1]] != body[g2] and parent[body[g2]] != body[g1]]
    root = model.joint(robot.model.names[1])
    qadr = np.array([model.joint(n).qposadr[0] for n in robot.joint_names])

    def pose(q):
        data.qpos[root.qposadr[0]: root.qposadr[0] + 3] = q[:3]
        data.qpos[root.qposadr[0] + 3: root.qposadr[0] + 7] = q[[6, 3, 4, 5]]
        data.qpos[qadr] = robot.joint_positions(q)
        mujoco.mj_forward(model, data)

    def touching(g1, g2) -> bool:
        return mujoco.mj_geomDistance(model, data, int(g1), int(g2), SELF_CONTACT_TOUCH_M, None) < SELF_CONTACT_TOUCH_M

    excluded = set()
    pose(robot.q_nominal)
    for g1, g2 in pairs:
        if touching(g1, g2):
            excluded.add(tuple(sorted((int(body[g1]), int(body[g2])))))
    grand = [(g1, g2) for g1, g2 in pairs if parent[parent[body[g1]]] == body[g2] or parent[parent[body[g2]]] == body[g1]]
    rng = np.random.default_rng(seed)
    low = np.where(np.isfinite(robot.q_min), robot.q_min, -np.pi)
    high = np.where(np.isfinite(robot.q_max), robot.q_max, np.pi)
    for _ in range(SELF_CONTACT_SAMPLES if grand else 0):
        pose(robot.with_joint_positions(robot.q_nominal, rng.uniform(low, high)))
        for g1, g2 in grand:
            if touching(g1, g2):
                excluded.add(tuple(sorted((int(body[g1]), int(body[g2])))))
    return [(model.body(a).name, model.body(b).name) for a, b in sorted(excluded)]


# --------------------------------------------------------------------------------- helpers
def _defaults(root: ET.Element, config: MujocoPlantConfig) -> None:
    default = ET.SubElement(root, "default")
    friction = _v([config.friction_mu, config.torsional_friction_m, 0.0001])
    ET.SubElement(
        default,
        "geom",
        contype=str(ENV_CONTYPE),
        conaffinity=str(ENV_CONAFFINITY),
        condim="3",
        friction=friction,
        solref=_v([config.contact_timeconst, config.contact_dampratio]),
        solimp=_v(config.contact_solimp),
    )
    robot_class = ET.SubElement(default, "default", attrib={"class": "robot"})
    affinity = ROBOT_SELF_CONAFFINITY if config.self_collision else ROBOT_CONAFFINITY
    ET.SubElement(robot_class, "geom", contype=str(ROBOT_CONTYPE), conaffinity=str(affinity), rgba=".7 .7 .75 1")


def _drive_train(robot: RobotModel, config: MujocoPlantConfig) -> dict[str, dict[str, str]]:
    """Per joint MJCF attributes of the plant's drive train: armature, damping, frictionloss."""
    columns = {
        "armature": config.joint_array(robot, "joint_armature_kg_m2"),
        "damping": config.joint_array(robot, "joint_damping_nm_s_per_rad"),
        "frictionloss": config.joint_array(robot, "joint_frictionloss_nm"),
    }
    timeconst = config.joint_friction_timeconst_s or 2 * config.dt_s
    friction = {"solreffriction": _v([timeconst, 1.0]), "solimpfriction": _v(config.joint_friction_solimp)}
    return {
        name: {**{key: _f(values[k]) for key, values in columns.items()},
               **(friction if columns["frictionloss"][k] > 0 else {})}
        for k, name in enumerate(robot.joint_names)
    }


def _add_bodies(
    world: ET.Element, robot: RobotModel, shapes: list[CollisionShape], names: list[str], drive: dict[str, dict[str, str]]
) -> None:
    model = robot.model
    elements: dict[int, ET.Element] = {0: world}
    limits = {n: (lo, hi) for n, lo, hi in zip(robot.joint_names, robot.q_min, robot.q_max)}
    for jid in range(1, model.njoints):
        placement = model.jointPlacements[jid]
        body = ET.SubElement(
            elements[model.parents[jid]],
            "body",
            name=names[jid - 1],
            pos=_v(placement.translation),
            quat=_v(pin.Quaternion(placement.rotation).coeffs()[[3, 0, 1, 2]]),
        )
        elements[jid] = body
        inertia = model.inertias[jid]
        mass, I = mujoco_inertia(inertia.mass, inertia.inertia)
        ET.SubElement(
            body,
            "inertial",
            pos=_v(inertia.lever),
            mass=_f(mass),
            fullinertia=_v([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]),
        )
        _add_joint(body, robot, jid, limits, drive)
        if jid == 1:
            ET.SubElement(body, "camera", name="track", mode="trackcom", pos="0 -2.5 1.0", xyaxes="1 0 0 0 0.37 0.93")
        for shape in (s for s in shapes if s.joint_id == jid):
            _add_geom(body, shape)
    for name in robot.contact_frames:
        frame = model.frames[robot.frame_id(name)]
        ET.SubElement(elements[frame.parentJoint], "site", name=name, pos=_v(frame.placement.translation), size="0.01")


def _add_joint(body: ET.Element, robot: RobotModel, jid: int, limits: dict, drive: dict[str, dict[str, str]]) -> None:
    model, name = robot.model, robot.model.names[jid]
    joint = model.joints[jid]
    short = joint.shortname()
    if jid == 1:
        if short != "JointModelFreeFlyer":
            raise PlantInputError(f"the root joint must be a free flyer, got {short}")
        ET.SubElement(body, "freejoint", name=name)
        return
    kind = "hinge" if "Revolute" in short or short.startswith("JointModelR") else "slide"
    suffix = short.removeprefix("JointModel")
    if suffix in _JOINT_AXES:
        axis = _JOINT_AXES[suffix]
    elif suffix in ("RevoluteUnaligned", "RevoluteUnboundedUnaligned", "PrismaticUnaligned"):
        data = robot.model.createData()
        pin.forwardKinematics(robot.model, data, pin.neutral(robot.model))
        subspace = np.array(data.joints[jid].S).ravel()  # (linear, angular); constant for these joints
        axis = _v(subspace[:3] if kind == "slide" else subspace[3:])
    else:
        raise PlantInputError(f"joint '{name}' of type {short} has no MuJoCo equivalent in wbmpc.sim")
    lo, hi = limits[name]
    attrs = dict(name=name, type=kind, axis=axis, **drive[name])
    if np.isfinite(lo) and np.isfinite(hi) and hi - lo < 1e9:
        attrs.update(range=_v([lo, hi]), limited="true")
    ET.SubElement(body, "joint", **attrs)


def _add_geom(body: ET.Element, shape: CollisionShape) -> None:
    quat = pin.Quaternion(shape.rotation).coeffs()[[3, 0, 1, 2]]
    attrs = {"class": "robot", "name": shape.name, "type": shape.kind, "size": _v(shape.size)}
    attrs.update(pos=_v(shape.pos), quat=_v(quat))
    if shape.is_foot:
        attrs["rgba"] = ".2 .2 .2 1"
    ET.SubElement(body, "geom", attrs)


def _f(x: float) -> str:
    return repr(float(x))


def _v(values) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(values).ravel())
