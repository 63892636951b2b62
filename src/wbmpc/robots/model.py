"""`RobotModel`: a floating-base pinocchio model with limits, feet and arm end-effector.

Loaded from a URDF with a free-flyer root joint, or from an MJCF with a free joint (MuJoCo Menagerie,
unitree_mujoco; `robots/mjcf.py`: limits, torque limits, keyframes, drive train and feet given as sites or
geoms from MuJoCo's compiler). An optional SRDF group state (or an MJCF keyframe) gives the reference
(nominal) pose. Joints can be locked at that pose (the paper locks the last two Z1 joints and the gripper,
section V-B).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError, unknown_name
from wbmpc.robots.soles import FOOT_CONTACTS, Sole, sole_from_size, soles_from_collisions, soles_from_primitives

GRAVITY_M_S2 = 9.81
MIN_SOLE_M = (0.08, 0.04)  # (length, width): a derived flat foot's sole is at least this (a ball foot is not)
SUPPORTED_JOINTS = frozenset(
    f"JointModel{kind}"
    for kind in ("RX", "RY", "RZ", "RevoluteUnaligned", "RUBX", "RUBY", "RUBZ", "RevoluteUnboundedUnaligned",
                 "PX", "PY", "PZ", "PrismaticUnaligned")
)


JointValues = float | Mapping[str, float]  # one value for every joint, or {joint name: value} (others 0)


def joint_values(value: JointValues, joint_names: tuple[str, ...], label: str) -> np.ndarray:
    """A per-joint parameter as an array in `joint_names` order; finite and >= 0 or a clear error."""
    if isinstance(value, Mapping):
        out = np.zeros(len(joint_names))
        for joint, entry in value.items():
            if joint not in joint_names:
                raise ModelError(f"{label}: {unknown_name('joint', joint, joint_names)}")
            out[joint_names.index(joint)] = _non_negative(entry, f"{label}[{joint!r}]")
        return out
    return np.full(len(joint_names), _non_negative(value, label))


def _non_negative(value, label: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"{label} must be a number, got {value!r}") from exc
    if not (np.isfinite(number) and number >= 0):
        raise ModelError(f"{label} must be a finite number >= 0, got {value!r}")
    return number


@dataclass(frozen=True)
class RobotSpec:
    """Everything needed to load a robot; presets are instances of this.

    Drive-train terms of the controller's model (paper section VI-D), one value for all joints or
    {joint: value}: `armature_kg_m2` (rotor inertia reflected through the gearbox, added to the
    diagonal of the mass matrix), `viscous_friction_nm_s` (tau += b v) and `coulomb_friction_nm`
    (tau += c tanh(v / coulomb_velocity_rad_s), a smooth sign(v) the NLP can differentiate).
    """

    name: str
    urdf: Path | None  # the robot's URDF, or None with `mjcf`
    feet: tuple[str, ...]
    arm_ee: str | None = None
    srdf: Path | None = None
    pose: str | None = None
    locked_joints: tuple[str, ...] = ()
    effort_limit_nm: dict[str, float] = field(default_factory=dict)
    velocity_limit_rad_s: dict[str, float] = field(default_factory=dict)
    position_limit_rad: dict[str, tuple[float, float]] = field(default_factory=dict)
    foot_radius_m: float | None = None
    joint_positions_rad: dict[str, float] = field(default_factory=dict)  # overrides of the reference pose
    # None: the file's own values where it has them (an MJCF's armature, damping, frictionloss), else 0
    armature_kg_m2: JointValues | None = None
    viscous_friction_nm_s: JointValues | None = None
    coulomb_friction_nm: JointValues | None = None
    coulomb_velocity_rad_s: float = 0.05
    # "point": 3D force at each foot frame; "surface": flat feet with a 6D wrench at the sole (soles.py),
    # the sole rectangle from `sole_m` (length, width) or else the foot link's collision geometry; None: derived,
    # surface for two feet whose links carry a sole (`MIN_SOLE_M`), else point
    foot_contact: str | None = None
    sole_m: tuple[float, float] | None = None
    mjcf: Path | None = None  # the robot's MJCF instead of a URDF (free joint at its root)
    keyframe: str | None = None  # MJCF keyframe of the nominal pose (None: the file's first, else its zero pose)
    like_preset: str | None = None  # the preset this file is another description of: its settings apply (presets.py)
    # an arm on an MJCF base (robots/compose.py): (its URDF, the base frame it is mounted on, x y z roll pitch yaw)
    mjcf_arm: tuple[Path, str, tuple[float, ...]] | None = None

    def __post_init__(self):
        if (self.urdf is None) == (self.mjcf is None):
            raise ModelError("a robot is described by a URDF (--urdf) or an MJCF (--mjcf): give exactly one")
        if self.mjcf_arm is not None and self.mjcf is None:
            raise ModelError("mjcf_arm mounts an arm URDF on an MJCF base: it needs mjcf (a URDF base is composed "
                             "into one URDF, robots/compose.py)")
        if self.keyframe is not None and self.mjcf is None:
            raise ModelError(f"a keyframe ('{self.keyframe}', --keyframe) names a pose of an MJCF file (--mjcf FILE)")
        if self.keyframe is not None and self.srdf is not None:
            raise ModelError("the nominal pose comes from an SRDF (--srdf/--pose) or an MJCF keyframe (--keyframe): not both")
        if self.foot_contact not in (*FOOT_CONTACTS, None):
            raise ModelError(f"foot contact must be one of {', '.join(FOOT_CONTACTS)}, got {self.foot_contact!r}")
        if self.sole_m is not None and self.foot_contact == "point":
            raise ModelError("a sole size (--sole) describes flat feet: it needs foot_contact='surface'")
        duplicates = sorted({f for f in self.feet if self.feet.count(f) > 1})
        if duplicates:
            raise ModelError(f"foot frames must be distinct; {', '.join(duplicates)} given more than once (--feet)")
        if self.arm_ee is not None and self.arm_ee in self.feet:
            raise ModelError(f"'{self.arm_ee}' is given both as a foot and as the arm end-effector (--feet, --arm-ee)")
        if self.pose is not None and self.srdf is None:
            raise ModelError(f"a pose name ('{self.pose}', --pose) needs the SRDF that defines it (--srdf FILE)")
        duplicates = sorted({j for j in self.locked_joints if self.locked_joints.count(j) > 1})
        if duplicates:
            raise ModelError(f"joints to lock must be distinct; {', '.join(duplicates)} given more than once (--lock)")


class RobotModel:
    """A legged robot (optionally with an arm) on a free-flyer root.

    Attributes: `model` (pinocchio, reduced), `nq`, `nv`, `n_joints` (= nv - 6), `joint_names`
    (actuated joints in velocity order), `feet`, `arm_ee`, `q_nominal`, `mass_kg`, and per-joint
    limits `q_min`, `q_max`, `v_max`, `tau_max` (length `n_joints`).

    Joints: one-DoF revolute or prismatic (aligned or not with an axis of their frame) and
    continuous joints (pinocchio's RUBX/RUBY/RUBZ, stored as (cos, sin) in q: nq = 2, nv = 1);
    fixed joints are merged into their parent body by pinocchio. `joint_positions(q)` gives one
    angle / displacement per joint whatever the q layout. A URDF limit with lower >= upper (the
    usual `<limit effort=.. velocity=..>` without lower/upper) and continuous joints mean no
    position limit. A reference pose outside the limits is clipped into them.
    """

    def __init__(self, spec: RobotSpec):
        self.spec = spec
        self.name = spec.name
        if spec.srdf is not None and not Path(spec.srdf).is_file():
            raise ModelError(f"SRDF file not found: {spec.srdf}")
        self.mjcf = None  # MuJoCo's compiled model of an MJCF robot's file
        if spec.mjcf is not None:
            full = self._load_mjcf(spec)
        else:
            urdf = Path(spec.urdf)
            if not urdf.is_file():
                raise ModelError(f"URDF file not found: {urdf}")
            try:
                full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
            except (RuntimeError, ValueError) as exc:
                raise ModelError(f"pinocchio cannot parse URDF {urdf}: {exc}") from exc

        for i in range(2, full.njoints):
            if full.joints[i].shortname() not in SUPPORTED_JOINTS and full.names[i] not in spec.locked_joints:
                raise ModelError(
                    f"joint '{full.names[i]}' has type {full.joints[i].shortname()} ({full.joints[i].nv} DoF), which "
                    "wbmpc does not support; it supports revolute, continuous and prismatic joints (aligned or not) "
                    "below the free-flyer root: lock the joint (--lock) or change its type in the robot's file"
                )
        q_ref = self.reference_configuration(full, spec)
        self.keyframe: str | None = None  # the MJCF keyframe of the nominal pose
        if self.mjcf is not None and spec.srdf is None:
            q_ref = self._keyframe_configuration(full, spec)
        # where the nominal pose comes from: "srdf", "keyframe" or "zero" (the file's zero pose), before overrides
        self.pose_source = "srdf" if spec.srdf is not None else "keyframe" if self.keyframe is not None else "zero"
        for joint in spec.locked_joints:
            if not full.existJointName(joint) or full.getJointId(joint) == 1:
                raise ModelError(unknown_name("joint to lock", joint, list(full.names)[2:]))
        lock_ids = [full.getJointId(j) for j in spec.locked_joints]
        model = pin.buildReducedModel(full, lock_ids, q_ref) if lock_ids else full
        self.full_model: pin.Model = full  # before locking: a plant model holding the locked joints reads it
        self.locked_positions: dict[str, float] = {
            full.names[j]: _joint_angle(full, j, q_ref) for j in lock_ids}  # where each locked joint is held
        keep = [i for i in range(full.nq) if not self._q_index_locked(full, lock_ids, i)]
        self.model: pin.Model = model
        self.data = model.createData()
        self.nq, self.nv = model.nq, model.nv
        self.n_joints = model.nv - 6
        self.joint_names: tuple[str, ...] = tuple(model.names[2:])
        joint_ids = [model.getJointId(n) for n in self.joint_names]
        self._joint_iq = np.array([model.idx_qs[j] for j in joint_ids], dtype=int)
        self.continuous = np.array([model.nqs[j] == 2 for j in joint_ids], dtype=bool)

        self.feet = tuple(spec.feet)
        self.arm_ee = spec.arm_ee
        frames = [f.name for f in model.frames]
        for frame in (*self.feet, *([self.arm_ee] if self.arm_ee else [])):
            if not model.existFrame(frame) and self.mjcf is not None:
                bodies = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
                sites = [self.mjcf.site(k).name for k in range(self.mjcf.nsite) if self.mjcf.site(k).name]
                raise ModelError(f"MJCF {spec.mjcf} has no body, site or geom named '{frame}' (--feet/--arm-ee); "
                                 f"its bodies: {', '.join(bodies)}; its sites: {', '.join(sites) or 'none'}")
            if not model.existFrame(frame):
                raise ModelError(unknown_name("frame", frame, frames))
        if len(self.feet) == 0:
            raise ModelError("a legged robot needs at least one foot frame (--feet F1,F2,...)")

        self.mass_kg = float(sum(inertia.mass for inertia in model.inertias))
        self.soles: dict[str, Sole] = self._add_sole_frames(model, spec)
        self.data = model.createData()
        self._set_limits(model, spec)
        self._set_drive_train(model, spec)
        self.foot_radius_m = spec.foot_radius_m if spec.foot_radius_m is not None else self._foot_radius()
        q_ref = np.asarray(q_ref)[keep]
        for joint, value in spec.joint_positions_rad.items():
            if joint not in self.joint_names:
                raise ModelError(unknown_name("joint in joint_positions_rad", joint, self.joint_names))
            positions = self.joint_positions(q_ref)
            positions[self.joint_names.index(joint)] = float(value)
            q_ref = self.with_joint_positions(q_ref, positions)
        q_ref = self.with_joint_positions(q_ref, np.clip(self.joint_positions(q_ref), self.q_min, self.q_max))
        self.q_nominal = self._standing_configuration(q_ref)

    # ------------------------------------------------------------------ loading helpers
    @property
    def model_file(self) -> Path:
        """The file the robot was loaded from (its URDF or MJCF)."""
        return Path(self.spec.mjcf if self.spec.mjcf is not None else self.spec.urdf)

    def _load_mjcf(self, spec: RobotSpec) -> pin.Model:
        """pinocchio's model of an MJCF with a free joint at its root, frames for feet given as sites or geoms;
        MuJoCo's compiled model of the same file in `self.mjcf` (robots/mjcf.py)."""
        from wbmpc.robots import mjcf

        path = Path(spec.mjcf)
        self.mjcf = mjcf.compile_mjcf(path)
        try:
            full = pin.buildModelFromMJCF(str(path))
        except (RuntimeError, ValueError) as exc:
            raise ModelError(f"pinocchio cannot parse MJCF {path}: {exc}") from exc
        if full.njoints < 2 or full.joints[1].shortname() != "JointModelFreeFlyer":
            raise ModelError(f"MJCF {path} has no free joint at its root: wbmpc's robots move freely (add "
                             "<freejoint/> to the root body of the legs)")
        mjcf.add_point_frames(full, self.mjcf, (*spec.feet, spec.arm_ee))
        if spec.mjcf_arm is not None:  # the arm's URDF model appended at its mount, as a composed URDF would read
            urdf, frame, (x, y, z, roll, pitch, yaw) = spec.mjcf_arm
            try:
                arm = pin.buildModelFromUrdf(str(urdf))
            except (RuntimeError, ValueError) as exc:
                raise ModelError(f"pinocchio cannot parse the arm URDF {urdf}: {exc}") from exc
            mount = pin.SE3(pin.rpy.rpyToMatrix(np.array([roll, pitch, yaw])), np.array([x, y, z]))
            from wbmpc.robots.compose import append_model

            full = append_model(full, arm, full.getFrameId(frame), mount)
        return full

    def geometry(self, kind: pin.GeometryType) -> pin.GeometryModel:
        """An MJCF robot's geoms as pinocchio reads them (VISUAL or COLLISION), with its mounted arm's URDF geometry
        (the replay, collision avoidance; a URDF robot's is read by pinocchio's URDF parser where it is needed)."""
        from wbmpc.robots.urdf_geometry import _package_dirs

        geometry = pin.buildGeomFromMJCF(self.model, str(self.spec.mjcf), kind)
        if self.spec.mjcf_arm is not None:
            urdf = Path(self.spec.mjcf_arm[0])
            for obj in pin.buildGeomFromUrdf(self.model, str(urdf), kind, package_dirs=_package_dirs(urdf)).geometryObjects:
                geometry.addGeometryObject(obj)
        return geometry

    def collision_primitives(self):
        """The file's primitive collision geometry (`urdf_geometry.Primitive` list, in the pinocchio joint
        frames of this model): a URDF's `<collision>` boxes, spheres, cylinders, an MJCF's colliding geoms."""
        if "_primitives" not in self.__dict__:
            if self.mjcf is not None:
                from wbmpc.robots import mjcf, urdf_geometry

                self._primitives = mjcf.collision_primitives(self.model, self.mjcf)
                if self.spec.mjcf_arm is not None:
                    self._primitives += urdf_geometry.collision_primitives(self.model, self.spec.mjcf_arm[0])
            else:
                from wbmpc.robots.urdf_geometry import collision_primitives

                self._primitives = collision_primitives(self.model, self.spec.urdf)
        return self._primitives

    def _add_sole_frames(self, model: pin.Model, spec: RobotSpec) -> dict[str, Sole]:
        """Flat feet: the sole of each foot and a frame `<foot>_sole` at its centre (the contact frame). Where the
        spec leaves the kind of contact open, two feet whose links carry a sole of at least MIN_SOLE_M stand on
        it (g1's feet), any others are points (`foot_contact_source`: "spec" or "derived")."""
        self.foot_contact_source = "spec" if spec.foot_contact is not None else "derived"
        if spec.foot_contact == "point" or (spec.foot_contact is None and len(self.feet) != 2 and spec.sole_m is None):
            return {}
        if spec.sole_m is not None:
            soles = {foot: sole_from_size(foot, spec.sole_m) for foot in self.feet}
        else:
            try:
                soles = self._soles_from_geometry(model, spec)
            except ModelError:
                if spec.foot_contact == "surface":
                    raise
                return {}
            if spec.foot_contact is None and not all(s.length_m >= MIN_SOLE_M[0] and s.width_m >= MIN_SOLE_M[1]
                                                     for s in soles.values()):
                return {}  # ball feet, not soles
        for foot, sole in soles.items():
            fid = self.frame_id(foot)
            frame = model.frames[fid]
            placement = frame.placement * pin.SE3(np.eye(3), sole.centre_m)
            model.addFrame(pin.Frame(sole.frame, frame.parentJoint, fid, placement, pin.FrameType.OP_FRAME))
        return soles

    def _soles_from_geometry(self, model: pin.Model, spec: RobotSpec) -> dict[str, Sole]:
        if self.mjcf is not None:
            from wbmpc.robots.mjcf import collision_primitives

            return soles_from_primitives(model, collision_primitives(model, self.mjcf), self.feet, self.frame_id,
                                         self.model_file)
        return soles_from_collisions(model, Path(spec.urdf), self.feet, self.frame_id)

    @staticmethod
    def _q_index_locked(full: pin.Model, lock_ids: list[int], i: int) -> bool:
        for jid in lock_ids:
            start = full.idx_qs[jid]
            if start <= i < start + full.nqs[jid]:
                return True
        return False

    @staticmethod
    def reference_configuration(full: pin.Model, spec: RobotSpec) -> np.ndarray:
        """The SRDF pose `spec.pose` as read by pinocchio (`loadReferenceConfigurations`), after
        `_check_srdf_pose` refused what pinocchio would silently read as the neutral value."""
        q = pin.neutral(full)
        if spec.srdf is None:
            return q
        if spec.pose is None:
            raise ModelError(f"an SRDF was given ({spec.srdf}) but no pose name (--pose NAME)")
        _check_srdf_pose(full, spec)
        pin.loadReferenceConfigurations(full, str(spec.srdf), False)
        q = np.array(full.referenceConfigurations[spec.pose], dtype=float)
        if q.size >= 7:
            q[3:7] /= np.linalg.norm(q[3:7])
        return q

    def _keyframe_configuration(self, full: pin.Model, spec: RobotSpec) -> np.ndarray:
        """An MJCF's keyframe `spec.keyframe` (default: its first; none: its zero pose) as a configuration."""
        from wbmpc.robots.mjcf import keyframe_positions

        self.keyframe, positions = keyframe_positions(self.mjcf, spec.keyframe, Path(spec.mjcf))
        q = pin.neutral(full)
        for joint, value in positions.items():
            if not full.existJointName(joint):
                continue
            jid = full.getJointId(joint)
            start = full.idx_qs[jid]
            if full.nqs[jid] == 2 and full.nvs[jid] == 1:
                q[start:start + 2] = np.cos(value), np.sin(value)
            elif full.nqs[jid] == 1:
                q[start] = value
        return q

    def _set_limits(self, model: pin.Model, spec: RobotSpec) -> None:
        names = list(self.joint_names)
        iq = [model.idx_qs[model.getJointId(n)] for n in names]
        iv = [model.idx_vs[model.getJointId(n)] for n in names]
        self.q_min = np.array(model.lowerPositionLimit)[iq]
        self.q_max = np.array(model.upperPositionLimit)[iq]
        unlimited = self.continuous | ~(self.q_min < self.q_max)  # URDF <limit> without lower/upper: 0, 0
        self.q_min[unlimited], self.q_max[unlimited] = -np.inf, np.inf
        self.v_max = np.array(model.velocityLimit)[iv]
        self.tau_max = np.array(model.effortLimit)[iv]
        if self.mjcf is not None:
            self._set_mjcf_limits(names)
        for table, target in (
            (spec.effort_limit_nm, "tau_max"),
            (spec.velocity_limit_rad_s, "v_max"),
        ):
            for joint, value in table.items():
                if joint not in names:
                    raise ModelError(unknown_name("joint", joint, names))
                getattr(self, target)[names.index(joint)] = float(value)
        for joint, (lo, hi) in spec.position_limit_rad.items():
            if joint not in names:
                raise ModelError(unknown_name("joint", joint, names))
            self.q_min[names.index(joint)], self.q_max[names.index(joint)] = lo, hi
        big = 1e10
        self.q_min = np.maximum(self.q_min, -big)
        self.q_max = np.minimum(self.q_max, big)
        for label, arr in (("effort", self.tau_max), ("velocity", self.v_max)):
            bad = [names[i] for i in np.flatnonzero(~(arr > 0) | (arr > big))]
            if bad and self.mjcf is not None:
                raise ModelError(f"joints {bad} have no torque limit in MJCF {spec.mjcf}: give their actuators a "
                                 "ctrlrange (motor) or forcerange, or the joints an actuatorfrcrange")
            if bad:
                raise ModelError(f"joints {bad} have no positive {label} limit in the URDF; give one in the RobotSpec")

    def _set_mjcf_limits(self, names: list[str]) -> None:
        """An MJCF's joint ranges and torque limits as MuJoCo compiles them (`robots/mjcf.py`); MJCF has no
        velocity limits (the OCP's bound is then 1e10 rad/s, as for joints without position limits)."""
        from wbmpc.robots.mjcf import force_limits, mjcf_joints

        m = self.mjcf
        own = mjcf_joints(m)  # a mounted arm's joints keep its URDF's limits
        for k, name in enumerate(names):
            if name not in own:
                continue
            j = int(m.joint(name).id)
            if m.jnt_limited[j] and not self.continuous[k]:
                offset = m.qpos0[m.jnt_qposadr[j]]
                self.q_min[k], self.q_max[k] = m.jnt_range[j] - offset
            else:
                self.q_min[k], self.q_max[k] = -np.inf, np.inf
        limits = force_limits(m, [n for n in names if n in own])
        for k, name in enumerate(names):
            if name in own:
                self.tau_max[k] = min(-limits[name][0], limits[name][1]) if name in limits else np.inf
                self.v_max[k] = 1e10

    def _set_drive_train(self, model: pin.Model, spec: RobotSpec) -> None:
        """Armature and joint friction of the controller's model; pinocchio's algorithms (rnea, crba,
        aba) include `model.armature`, its `damping`/`friction` fields are set for reference only."""
        names = self.joint_names
        own = {"armature_kg_m2": 0.0, "viscous_friction_nm_s": 0.0, "coulomb_friction_nm": 0.0}
        if self.mjcf is not None:  # the file's armature, damping and frictionloss (a mounted arm's: none)
            from wbmpc.robots.mjcf import drive_train, mjcf_joints

            own = drive_train(self.mjcf, [n for n in names if n in mjcf_joints(self.mjcf)])
        for label in own:
            value = getattr(spec, label)
            setattr(self, label, joint_values(own[label] if value is None else value, names, label))
        self.coulomb_velocity_rad_s = _non_negative(spec.coulomb_velocity_rad_s, "coulomb_velocity_rad_s")
        if not self.coulomb_velocity_rad_s > 0:
            raise ModelError("coulomb_velocity_rad_s must be > 0 (the smoothing of sign(v))")
        iv = [model.idx_vs[model.getJointId(n)] for n in names]
        for field_name, values in (("armature", self.armature_kg_m2), ("damping", self.viscous_friction_nm_s),
                                   ("friction", self.coulomb_friction_nm)):
            vector = np.array(getattr(model, field_name), dtype=float)
            vector[iv] = values
            setattr(model, field_name, vector)

    def joint_friction_torque(self, v_joints: np.ndarray) -> np.ndarray:
        """Friction torques b v + c tanh(v / v_c) the joints need on top of the rigid-body dynamics."""
        v_joints = np.asarray(v_joints, dtype=float)
        return self.viscous_friction_nm_s * v_joints + self.coulomb_friction_nm * np.tanh(
            v_joints / self.coulomb_velocity_rad_s
        )

    def _standing_configuration(self, q: np.ndarray) -> np.ndarray:
        """Reference pose with the base lifted so that the lowest foot touches the ground."""
        q = q.copy()
        pin.framesForwardKinematics(self.model, self.data, q)
        z_feet = [self.data.oMf[self.frame_id(self.contact_frame(f))].translation[2] - self.contact_height_m(f)
                  for f in self.feet]
        q[2] -= min(z_feet)
        return q

    def _foot_radius(self) -> float:
        """Radius of the first foot's collision sphere (a URDF: the foot link's; an MJCF: the sphere on the foot's
        body nearest the foot frame, within its radius + 1 cm: Menagerie's and Unitree's feet are spheres on the
        calf at a foot body or site); else 2 cm."""
        spheres = [s for s in self.collision_primitives() if s.kind == "sphere"]
        for foot in self.feet:
            if self.mjcf is None:
                own = [s for s in spheres if s.link == foot]
                if own:
                    return min(own, key=lambda shape: shape.index).size[0]
                continue
            frame = self.model.frames[self.frame_id(foot)]
            near = [(np.linalg.norm(s.placement.translation - frame.placement.translation), s) for s in spheres
                    if s.joint_id == frame.parentJoint]
            near = [(d, s) for d, s in near if d <= s.size[0] + 0.01]
            if near:
                return min(near, key=lambda item: item[0])[1].size[0]
        return 0.02

    # ------------------------------------------------------------------ queries
    def frame_id(self, name: str) -> int:
        """Frame index by name; a BODY frame wins when a link and its fixed joint share the name.

        Remembered per name: the MPC asks for the feet and the end-effector at every step, and the
        scan over all frames cost ~0.5 ms of CPU per step on b1_z1."""
        cache = self.__dict__.setdefault("_frame_ids", {})
        if name not in cache:
            cache[name] = self._find_frame(name)
        return cache[name]

    def _find_frame(self, name: str) -> int:
        matches = [i for i, f in enumerate(self.model.frames) if f.name == name]
        if not matches:
            raise ModelError(unknown_name("frame", name, {f.name for f in self.model.frames}))
        bodies = [i for i in matches if self.model.frames[i].type == pin.FrameType.BODY]
        return (bodies or matches)[0]

    def joint_index(self, name: str) -> int:
        """Index of an actuated joint in the joint vectors (q_j, v_j, tau_j)."""
        if name not in self.joint_names:
            raise ModelError(unknown_name("joint", name, self.joint_names))
        return self.joint_names.index(name)

    @property
    def leg_joint_mask(self) -> np.ndarray:
        """True for joints on a chain from the root to a foot; the others belong to the arm."""
        legs = set()
        for foot in self.feet:
            joint = self.model.frames[self.frame_id(foot)].parentJoint
            while joint > 1:
                legs.add(self.model.names[joint])
                joint = self.model.parents[joint]
        return np.array([name in legs for name in self.joint_names])

    @property
    def surface_feet(self) -> tuple[str, ...]:
        """Feet with a 6D wrench at their sole (flat feet), in `feet` order; the others are points."""
        return tuple(f for f in self.feet if f in self.soles)

    def contact_frame(self, foot: str) -> str:
        """Frame at which a foot's contact acts: its sole frame (flat feet) or the foot frame itself."""
        return self.soles[foot].frame if foot in self.soles else foot

    def contact_height_m(self, foot: str) -> float:
        """Height of the contact frame above the ground in stance: 0 on a sole, the radius on a point foot."""
        return 0.0 if foot in self.soles else self.foot_radius_m

    @property
    def contact_kinds(self) -> dict[str, str]:
        """{contact frame given by the user: "surface" (6D wrench) or "point" (3D force)}."""
        return {name: "surface" if name in self.soles else "point" for name in self.contact_frames}

    @property
    def contact_frames(self) -> tuple[str, ...]:
        """Feet, then the arm end-effector if any: the order of the stacked contact forces F_c."""
        return self.feet + ((self.arm_ee,) if self.arm_ee else ())

    def frame_trajectories(self, q: np.ndarray, frames) -> dict[str, np.ndarray]:
        """World positions (n, 3) of the named frames for every configuration row of `q` (FK)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        data = self.model.createData()
        ids = {name: self.frame_id(name) for name in frames}
        out = {name: np.empty((q.shape[0], 3)) for name in frames}
        for k, qk in enumerate(q):
            pin.forwardKinematics(self.model, data, qk)
            for name, fid in ids.items():
                out[name][k] = pin.updateFramePlacement(self.model, data, fid).translation
        return out

    def joint_positions(self, q: np.ndarray, near: np.ndarray | None = None) -> np.ndarray:
        """Joint angles / displacements (..., n_joints) of configurations q (..., nq).

        Continuous joints give atan2(sin, cos) in (-pi, pi], or with `near` (..., n_joints) the angle
        that differs from `near` by at most pi (for position errors across the +-pi seam).
        """
        q = np.asarray(q, dtype=float)
        out = q[..., self._joint_iq].copy()
        if self.continuous.any():
            iq = self._joint_iq[self.continuous]
            angle = np.arctan2(q[..., iq + 1], q[..., iq])
            if near is not None:
                ref = np.asarray(near, dtype=float)[..., self.continuous]
                angle = ref + np.angle(np.exp(1j * (angle - ref)))
            out[..., self.continuous] = angle
        return out

    def with_joint_positions(self, q: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """A copy of configuration q (nq,) with its joint coordinates set from `positions` (n_joints,)."""
        q = np.array(q, dtype=float)
        positions = np.asarray(positions, dtype=float)
        plain = ~self.continuous
        q[self._joint_iq[plain]] = positions[plain]
        if self.continuous.any():
            iq = self._joint_iq[self.continuous]
            q[iq], q[iq + 1] = np.cos(positions[self.continuous]), np.sin(positions[self.continuous])
        return q

    def random_configuration(self, rng: np.random.Generator) -> np.ndarray:
        """A random configuration on the manifold within joint limits (unit quaternion)."""
        q = self.q_nominal.copy()
        q[:3] += rng.uniform(-1, 1, 3)
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
        lo = np.maximum(self.q_min, -np.pi)
        hi = np.minimum(self.q_max, np.pi)
        return self.with_joint_positions(q, rng.uniform(lo, hi))

    def summary(self) -> dict:
        return {
            "robot": self.name,
            "file": str(self.model_file),
            "like_preset": self.spec.like_preset,
            "nq": self.nq,
            "nv": self.nv,
            "n_joints": self.n_joints,
            "mass_kg": self.mass_kg,
            "feet": list(self.feet),
            "arm_ee": self.arm_ee,
            "contacts": self.contact_kinds,
            "contacts_source": self.foot_contact_source,
            "pose_source": "preset" if self.pose_source == "zero" and self.spec.joint_positions_rad else self.pose_source,
            "keyframe": self.keyframe,
            "soles_m": {f: {"length": s.length_m, "width": s.width_m, "centre": [float(c) for c in s.centre_m]}
                        for f, s in self.soles.items()},
            "joints": list(self.joint_names),
            "continuous_joints": [n for n, c in zip(self.joint_names, self.continuous) if c],
            "armature_kg_m2": _compact(self.armature_kg_m2, self.joint_names),
            "viscous_friction_nm_s": _compact(self.viscous_friction_nm_s, self.joint_names),
            "coulomb_friction_nm": _compact(self.coulomb_friction_nm, self.joint_names),
        }


def _joint_angle(model: pin.Model, jid: int, q: np.ndarray) -> float:
    """The angle (displacement) of 1-DoF joint `jid` in configuration q: continuous joints from (cos, sin)."""
    start = model.idx_qs[jid]
    if model.nqs[jid] == 2 and model.nvs[jid] == 1:
        return float(np.arctan2(q[start + 1], q[start]))
    return float(q[start])


def _compact(values: np.ndarray, names: tuple[str, ...]):
    """One number when every joint has the same value, else {joint: value}."""
    if np.all(values == values[0]) if values.size else True:
        return float(values[0]) if values.size else 0.0
    return {n: float(v) for n, v in zip(names, values)}


def _check_srdf_pose(full: pin.Model, spec: RobotSpec) -> None:
    """Refuse an SRDF pose pinocchio would misread. ElementTree stays here because pinocchio's reader
    cannot say what is wrong: it skips a joint value it cannot read (not a number, not finite, the wrong
    count) with a line on stdout (which would break `--json`) and leaves the neutral value, and a
    malformed file gives a bare parser message."""
    try:
        root = ET.parse(spec.srdf).getroot()
    except ET.ParseError as exc:
        raise ModelError(f"SRDF {spec.srdf} is not well-formed XML ({exc}); fix the file or drop --srdf") from None
    states = {s.get("name"): s for s in root.iter("group_state")}
    if spec.pose not in states:
        raise ModelError(
            f"SRDF {spec.srdf} has no group_state '{spec.pose}'; available poses: {', '.join(sorted(states)) or 'none'}"
        )
    for joint in states[spec.pose].iter("joint"):
        name = joint.get("name")
        try:
            values = np.array([float(x) for x in joint.get("value", "").split()])
        except ValueError:
            raise ModelError(f"SRDF {spec.srdf}, pose '{spec.pose}': joint '{name}' has a non-numeric value "
                             f"{joint.get('value')!r}; give numbers in radians (or metres)") from None
        if not np.all(np.isfinite(values)):
            raise ModelError(f"SRDF {spec.srdf}, pose '{spec.pose}': joint '{name}' has a non-finite value "
                             f"{joint.get('value')!r}")
        if not full.existJointName(name):
            continue  # SRDFs often name joints of other variants; pinocchio ignores them too
        jid = full.getJointId(name)
        continuous = values.size == 1 and full.nqs[jid] == 2 and full.nvs[jid] == 1  # given by its angle
        if values.size != full.nqs[jid] and not continuous:
            raise ModelError(f"SRDF pose '{spec.pose}': joint '{name}' needs {full.nqs[jid]} values, got {values.size}")
