"""Rigid-body algorithms in CasADi SX, built from a numeric pinocchio `Model`.

Conventions follow pinocchio: q = [p_base, quat_xyzw, q_joints], v = [v_base (local), w_base
(local), v_joints]; joint quantities live in joint (body) frames. The stacked contact forces F act
*on the robot*: first a linear force in world coordinates at every contact frame (feet, then arm
end-effector), then a moment for every surface contact (flat foot, `robot.soles`) in its sole frame's
axes. A point contact carries a 3D force, a surface contact a 6D wrench (force at the sole centre plus
moment): the moments in the sole frame make the wrench cone rows linear (ocp/problem.py).

The graphs are kept small on purpose: joint rotations about aligned axes are sparse, constant
zero/one entries of placements vanish through SX simplification, per-body dynamics use the
Newton-Euler equations about the centre of mass, and contact forces are rotated down the
chain one joint at a time instead of through world Jacobians.

Mass distribution: a `Configuration` may carry `InertialParameters` (symbols of the NLP or
numbers): the base body's centre of mass moved by `base_com_offset` (base frame, its mass and rotational
inertia about the CoM kept), a point mass `payload_kg` at `SymbolicDynamics.payload_frame` (the arm's
end-effector, else the base origin) and, on a robot with an arm, optionally a second one `base_payload_kg` at
the base origin (a load on the back: its position shows in the CoM offset). RNEA and CRBA then equal pinocchio's on the model edited alike
(`InertialParameters.apply_to`); zero values give today's model exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.errors import ModelError
from wbmpc.robots.model import RobotModel
from wbmpc.symbolic import spatial as sp

_REVOLUTE = {"JointModelRX": (1, 0, 0), "JointModelRY": (0, 1, 0), "JointModelRZ": (0, 0, 1)}
_PRISMATIC = {"JointModelPX": (1, 0, 0), "JointModelPY": (0, 1, 0), "JointModelPZ": (0, 0, 1)}
_UNBOUNDED = {"JointModelRUBX": (1, 0, 0), "JointModelRUBY": (0, 1, 0), "JointModelRUBZ": (0, 0, 1)}


@dataclass(frozen=True)
class _Joint:
    """Numeric description of one joint below the root, read from the pinocchio model."""

    parent: int
    kind: str  # "revolute" | "prismatic"
    unbounded: bool  # revolute stored as (cos, sin) in q
    axis: np.ndarray
    placement_rotation: np.ndarray
    placement_translation: np.ndarray
    idx_q: int
    idx_v: int


@dataclass(frozen=True)
class _Body:
    mass: float
    com: np.ndarray
    inertia_com: np.ndarray


@dataclass(frozen=True)
class InertialParameters:
    """Base CoM offset (3, base frame, m) and a payload point mass (kg) at the payload frame: SX or numbers."""

    base_com_offset: ca.SX
    payload_kg: ca.SX
    base_payload_kg: ca.SX | None = None  # a point mass at the base origin (robots with an arm)

    @staticmethod
    def apply_to(robot: RobotModel, base_com_offset_m, payload_kg: float, base_payload_kg: float = 0.0) -> pin.Model:
        """A copy of `robot.model` with these numeric values (the independent reference of the symbolic ones)."""
        model = robot.model.copy()
        base = model.inertias[1]
        model.inertias[1] = pin.Inertia(base.mass, np.array(base.lever) + np.asarray(base_com_offset_m, float),
                                        np.array(base.inertia))
        joint, offset = payload_placement(robot)
        model.inertias[joint] = model.inertias[joint] + pin.Inertia(float(payload_kg), offset, np.zeros((3, 3)))
        model.inertias[1] = model.inertias[1] + pin.Inertia(float(base_payload_kg), np.zeros(3), np.zeros((3, 3)))
        return model

    def point_masses(self, dyn: "SymbolicDynamics") -> list[tuple[int, np.ndarray, ca.SX]]:
        """(joint, offset in its frame, mass) of each payload."""
        masses = [(dyn.payload_joint, dyn.payload_offset, self.payload_kg)]
        if self.base_payload_kg is not None:
            masses.append((1, np.zeros(3), self.base_payload_kg))
        return masses


def payload_placement(robot: RobotModel) -> tuple[int, np.ndarray]:
    """(joint index, offset in its frame) where a payload sits: the arm's end-effector, else the base origin."""
    if robot.arm_ee is None:
        return 1, np.zeros(3)
    frame = robot.model.frames[robot.frame_id(robot.arm_ee)]
    return frame.parentJoint, np.array(frame.placement.translation)


@dataclass(frozen=True)
class _Contact:
    joint: int
    offset: np.ndarray  # frame origin in the joint frame
    rotation: np.ndarray  # contact frame axes in the joint frame
    surface: bool  # a 6D wrench (flat foot) instead of a 3D force


class Configuration:
    """Symbolic configuration: base rotation/position and per-joint (cos, sin) or displacement.

    Caches local joint transforms and (lazily) world rotations/positions so that every
    algorithm evaluated on the same configuration shares one expression graph.
    """

    def __init__(self, dyn: "SymbolicDynamics", base_rotation: ca.SX, base_position: ca.SX, joint_values: list):
        self.dyn = dyn
        self.base_rotation = base_rotation
        self.base_position = base_position
        self.local_rotation: list = [None] * dyn.njoints
        self.local_translation: list = [None] * dyn.njoints
        for i, joint in dyn.joints.items():
            value = joint_values[i]
            if joint.kind == "revolute":
                cos_q, sin_q = value
                rot = sp.axis_rotation(joint.axis, cos_q, sin_q)
                if not sp.is_identity(joint.placement_rotation):
                    rot = ca.mtimes(sp.const(joint.placement_rotation), rot)
                self.local_rotation[i] = rot
                self.local_translation[i] = sp.const(joint.placement_translation)
            else:
                self.local_rotation[i] = sp.const(joint.placement_rotation)
                self.local_translation[i] = sp.const(joint.placement_translation) + ca.mtimes(
                    sp.const(joint.placement_rotation), sp.const(joint.axis)
                ) * value
        self.inertial: InertialParameters | None = None  # the model's own mass distribution when None
        self._world_rotation: dict[int, ca.SX] = {1: base_rotation}
        self._world_position: dict[int, ca.SX] = {1: base_position}

    def world_rotation(self, i: int) -> ca.SX:
        if i not in self._world_rotation:
            parent = self.dyn.joints[i].parent
            self._world_rotation[i] = ca.mtimes(self.world_rotation(parent), self.local_rotation[i])
        return self._world_rotation[i]

    def world_position(self, i: int) -> ca.SX:
        if i not in self._world_position:
            parent = self.dyn.joints[i].parent
            self._world_position[i] = self.world_position(parent) + ca.mtimes(
                self.world_rotation(parent), self.local_translation[i]
            )
        return self._world_position[i]

    def to_local(self, i: int, world_vector: ca.SX) -> ca.SX:
        """R_i^T x, rotated down the chain one joint at a time (cheaper than forming R_i)."""
        chain = self.dyn.chain(i)
        x = ca.mtimes(self.base_rotation.T, world_vector)
        for j in chain[1:]:
            x = ca.mtimes(self.local_rotation[j].T, x)
        return x


class Motion:
    """Per-joint spatial velocities (linear, angular) of a configuration and a velocity vector."""

    def __init__(self, cfg: Configuration, v: ca.SX):
        dyn = cfg.dyn
        self.v = v
        self.lin: list = [None] * dyn.njoints
        self.ang: list = [None] * dyn.njoints
        self.lin[1], self.ang[1] = v[0:3], v[3:6]
        for i, joint in dyn.joints.items():
            rot, t = cfg.local_rotation[i], cfg.local_translation[i]
            p = joint.parent
            lin = ca.mtimes(rot.T, self.lin[p] + sp.cross(self.ang[p], t))
            ang = ca.mtimes(rot.T, self.ang[p])
            qd = v[joint.idx_v]
            if joint.kind == "revolute":
                ang = ang + sp.const(joint.axis) * qd
            else:
                lin = lin + sp.const(joint.axis) * qd
            self.lin[i], self.ang[i] = lin, ang


class SymbolicDynamics:
    """CasADi expressions and functions of a `RobotModel`'s rigid-body dynamics.

    The expression-level methods (taking a `Configuration`) are what the OCP uses; the
    `*_function` methods wrap them as `casadi.Function` of pinocchio-layout q for validation.
    """

    def __init__(self, robot: RobotModel):
        self.robot = robot
        model: pin.Model = robot.model
        self.model = model
        self.nq, self.nv, self.njoints = model.nq, model.nv, model.njoints
        if model.joints[1].shortname() != "JointModelFreeFlyer":
            raise ModelError("the first joint must be a free-flyer root (load the URDF with JointModelFreeFlyer)")
        self.joints: dict[int, _Joint] = {}
        # motion subspaces S (linear, angular) of every joint: the axis of unaligned joints (the Python
        # bindings expose no `axis` on some of them, e.g. RevoluteUnboundedUnaligned)
        data = model.createData()
        pin.forwardKinematics(model, data, pin.neutral(model))
        for i in range(2, model.njoints):
            jm = model.joints[i]
            name = jm.shortname()
            if name in _REVOLUTE or name in _UNBOUNDED:
                kind, axis = "revolute", np.array(_REVOLUTE.get(name) or _UNBOUNDED[name], float)
            elif name in ("JointModelRevoluteUnaligned", "JointModelRevoluteUnboundedUnaligned"):
                kind, axis = "revolute", np.array(data.joints[i].S, float).ravel()[3:]
            elif name in _PRISMATIC:
                kind, axis = "prismatic", np.array(_PRISMATIC[name], float)
            elif name == "JointModelPrismaticUnaligned":
                kind, axis = "prismatic", np.array(data.joints[i].S, float).ravel()[:3]
            else:
                raise ModelError(
                    f"joint '{model.names[i]}' has unsupported type {name}; supported: revolute, continuous and "
                    "prismatic joints (aligned or unaligned axes); lock it or change its type in the URDF"
                )
            placement = model.jointPlacements[i]
            self.joints[i] = _Joint(
                parent=model.parents[i],
                kind=kind,
                unbounded=name in _UNBOUNDED or name == "JointModelRevoluteUnboundedUnaligned",
                axis=axis,
                placement_rotation=np.array(placement.rotation),
                placement_translation=np.array(placement.translation),
                idx_q=model.idx_qs[i],
                idx_v=model.idx_vs[i],
            )
        self.bodies = {
            i: _Body(float(model.inertias[i].mass), np.array(model.inertias[i].lever), np.array(model.inertias[i].inertia))
            for i in range(1, model.njoints)
        }
        self.gravity = np.array(model.gravity.linear)
        # drive train (section VI-D): armature on the mass-matrix diagonal, smoothed joint friction
        self.armature = np.asarray(robot.armature_kg_m2, dtype=float)
        self.viscous_friction = np.asarray(robot.viscous_friction_nm_s, dtype=float)
        self.coulomb_friction = np.asarray(robot.coulomb_friction_nm, dtype=float)
        self.coulomb_velocity = float(robot.coulomb_velocity_rad_s)
        self.total_mass = sum(b.mass for b in self.bodies.values())
        # frames where the contact forces act: the sole frame of a flat foot, else the named frame
        self.contact_frames = tuple(robot.contact_frame(f) for f in robot.feet) + ((robot.arm_ee,) if robot.arm_ee else ())
        self.contacts = [self._contact(name, surface=name not in robot.contact_frames)
                         for name in self.contact_frames]
        self.surface_contacts = [i for i, c in enumerate(self.contacts) if c.surface]
        self.payload_joint, self.payload_offset = payload_placement(robot)
        self.n_linear_forces = 3 * len(self.contacts)
        self.n_forces = self.n_linear_forces + 3 * len(self.surface_contacts)

    def _contact(self, frame: str, surface: bool) -> _Contact:
        f = self.model.frames[self.robot.frame_id(frame)]
        return _Contact(joint=f.parentJoint, offset=np.array(f.placement.translation),
                        rotation=np.array(f.placement.rotation), surface=surface)

    def moment_slice(self, i: int) -> slice:
        """Where the moment of surface contact i (index into `contacts`) sits in the stacked F."""
        start = self.n_linear_forces + 3 * self.surface_contacts.index(i)
        return slice(start, start + 3)

    def chain(self, i: int) -> list[int]:
        """Joint indices from the root (1) down to joint i."""
        out = []
        while i > 0:
            out.append(i)
            i = self.model.parents[i]
        return out[::-1]

    @cached_property
    def subtree_mass(self) -> dict[int, float]:
        mass = {i: b.mass for i, b in self.bodies.items()}
        for i in sorted(self.joints, reverse=True):
            mass[self.joints[i].parent] += mass[i]
        return mass

    # ------------------------------------------------------------------ configurations
    def configuration(self, q: ca.SX) -> Configuration:
        """Configuration from a pinocchio-layout q (unit quaternion base)."""
        values = {}
        for i, joint in self.joints.items():
            if joint.kind == "revolute" and joint.unbounded:
                values[i] = (q[joint.idx_q], q[joint.idx_q + 1])
            elif joint.kind == "revolute":
                values[i] = (ca.cos(q[joint.idx_q]), ca.sin(q[joint.idx_q]))
            else:
                values[i] = q[joint.idx_q]
        return Configuration(self, sp.quat_to_rotation(q[3:7]), q[0:3], values)

    def configuration_from_increment(
        self, base_rotation_ref: ca.SX, q_ref: ca.SX, dq: ca.SX
    ) -> Configuration:
        """q = q_ref (+) dq on the free-flyer manifold (eq. 4's delta-q), reference as parameters.

        `base_rotation_ref` is the 3x3 rotation of q_ref's quaternion (passed precomputed);
        revolute joints are q_ref_j + dq_j.
        """
        rot_inc, pos_inc = sp.exp_se3(dq[0:3], dq[3:6])
        rotation = ca.mtimes(base_rotation_ref, rot_inc)
        position = q_ref[0:3] + ca.mtimes(base_rotation_ref, pos_inc)
        values = {}
        for i, joint in self.joints.items():
            iv = joint.idx_v
            if joint.kind == "revolute" and joint.unbounded:
                c0, s0 = q_ref[joint.idx_q], q_ref[joint.idx_q + 1]
                c1, s1 = ca.cos(dq[iv]), ca.sin(dq[iv])
                values[i] = (c0 * c1 - s0 * s1, s0 * c1 + c0 * s1)
            elif joint.kind == "revolute":
                angle = q_ref[joint.idx_q] + dq[iv]
                values[i] = (ca.cos(angle), ca.sin(angle))
            else:
                values[i] = q_ref[joint.idx_q] + dq[iv]
        return Configuration(self, rotation, position, values)

    # ------------------------------------------------------------------ Lie group
    def integrate(self, q: ca.SX, dq: ca.SX) -> ca.SX:
        """pinocchio.integrate: q (+) dq (base: SE(3) exponential in the local frame)."""
        rot0 = sp.quat_to_rotation(q[3:7])
        _, pos_inc = sp.exp_se3(dq[0:3], dq[3:6])
        out = [q[0:3] + ca.mtimes(rot0, pos_inc), sp.quat_multiply(q[3:7], sp.quat_exp(dq[3:6]))]
        for joint in self.joints.values():
            if joint.kind == "revolute" and joint.unbounded:
                c0, s0 = q[joint.idx_q], q[joint.idx_q + 1]
                c1, s1 = ca.cos(dq[joint.idx_v]), ca.sin(dq[joint.idx_v])
                out.append(ca.vertcat(c0 * c1 - s0 * s1, s0 * c1 + c0 * s1))
            else:
                out.append(q[joint.idx_q] + dq[joint.idx_v])
        return ca.vertcat(*out)

    def difference(self, q0: ca.SX, q1: ca.SX) -> ca.SX:
        """pinocchio.difference: dq with q0 (+) dq = q1 (base: SE(3) logarithm)."""
        quat0_inv = ca.vertcat(-q0[3:6], q0[6])
        rel = sp.quat_multiply(quat0_inv, q1[3:7])
        w = sp.quat_log(rel)
        p_rel = ca.mtimes(sp.quat_to_rotation(q0[3:7]).T, q1[0:3] - q0[0:3])
        out = [sp.log_se3_translation(w, p_rel), w]
        for joint in self.joints.values():
            if joint.kind == "revolute" and joint.unbounded:
                c0, s0 = q0[joint.idx_q], q0[joint.idx_q + 1]
                c1, s1 = q1[joint.idx_q], q1[joint.idx_q + 1]
                out.append(ca.atan2(c0 * s1 - s0 * c1, c0 * c1 + s0 * s1))
            else:
                out.append(q1[joint.idx_q] - q0[joint.idx_q])
        return ca.vertcat(*out)

    # ------------------------------------------------------------------ kinematics
    def frame_placement(self, cfg: Configuration, frame: str) -> tuple[ca.SX, ca.SX]:
        """World position and rotation of a frame (forward kinematics)."""
        f = self.model.frames[self.robot.frame_id(frame)]
        rot = cfg.world_rotation(f.parentJoint)
        position = cfg.world_position(f.parentJoint) + ca.mtimes(rot, sp.const(f.placement.translation))
        return position, ca.mtimes(rot, sp.const(f.placement.rotation))

    def frame_velocity(self, cfg: Configuration, motion: Motion, frame: str) -> tuple[ca.SX, ca.SX]:
        """Linear and angular velocity of a frame, world-aligned axes (LOCAL_WORLD_ALIGNED)."""
        f = self.model.frames[self.robot.frame_id(frame)]
        j = f.parentJoint
        rot = cfg.world_rotation(j)
        lin_local = motion.lin[j] + sp.cross(motion.ang[j], sp.const(f.placement.translation))
        return ca.mtimes(rot, lin_local), ca.mtimes(rot, motion.ang[j])

    def frame_linear_velocity(self, cfg: Configuration, motion: Motion, frame: str) -> ca.SX:
        """World linear velocity of a frame origin, without forming the joint's world rotation:
        the base rotation is applied once to the local velocity lifted up the chain."""
        f = self.model.frames[self.robot.frame_id(frame)]
        j = f.parentJoint
        x = motion.lin[j] + sp.cross(motion.ang[j], sp.const(f.placement.translation))
        for k in reversed(self.chain(j)[1:]):
            x = ca.mtimes(cfg.local_rotation[k], x)
        return ca.mtimes(cfg.base_rotation, x)

    # ------------------------------------------------------------------ dynamics
    def joint_accelerations(self, cfg: Configuration, motion: Motion, a: ca.SX, gravity: bool) -> tuple[list, list]:
        """Each joint's spatial acceleration (linear at its origin, angular) in its own frame, pinocchio's `data.a`
        (with `gravity`: the base accelerated by -g, RNEA's trick): the forward pass of RNEA."""
        accel_lin: list = [None] * self.njoints
        accel_ang: list = [None] * self.njoints
        accel_lin[1] = a[0:3]
        if gravity:
            # a_0 = -g expressed in the base frame: R^T (-g)
            accel_lin[1] = accel_lin[1] - ca.mtimes(cfg.base_rotation.T, sp.const(self.gravity))
        accel_ang[1] = a[3:6]
        for i, joint in self.joints.items():
            rot, t, p = cfg.local_rotation[i], cfg.local_translation[i], joint.parent
            lin = ca.mtimes(rot.T, accel_lin[p] + sp.cross(accel_ang[p], t))
            ang = ca.mtimes(rot.T, accel_ang[p])
            axis = sp.const(joint.axis)
            qd, qdd = motion.v[joint.idx_v], a[joint.idx_v]
            if joint.kind == "revolute":
                s_qd = axis * qd
                lin = lin + sp.cross(motion.lin[i], s_qd)
                ang = ang + axis * qdd + sp.cross(motion.ang[i], s_qd)
            else:
                lin = lin + axis * qdd + sp.cross(motion.ang[i], axis * qd)
            accel_lin[i], accel_ang[i] = lin, ang
        return accel_lin, accel_ang

    def _body_wrenches(self, cfg: Configuration, motion: Motion, a: ca.SX, gravity: bool):
        """Forward pass of RNEA: net spatial force (force, moment about joint origin) per body."""
        accel_lin, accel_ang = self.joint_accelerations(cfg, motion, a, gravity)
        force, moment = {}, {}
        inertial = cfg.inertial
        for i, body in self.bodies.items():
            w, v = motion.ang[i], motion.lin[i]
            c = sp.const(body.com)
            if i == 1 and inertial is not None:
                c = c + inertial.base_com_offset
            inertia = sp.const(body.inertia_com)
            v_com = v + sp.cross(w, c)
            a_com = accel_lin[i] + sp.cross(accel_ang[i], c) + sp.cross(w, v_com)
            f = body.mass * a_com
            n_com = ca.mtimes(inertia, accel_ang[i]) + sp.cross(w, ca.mtimes(inertia, w))
            force[i], moment[i] = f, n_com + sp.cross(c, f)
        for j, offset, mass in inertial.point_masses(self) if inertial is not None else ():  # the payloads
            r = sp.const(offset)
            w = motion.ang[j]
            a_point = accel_lin[j] + sp.cross(accel_ang[j], r) + sp.cross(w, motion.lin[j] + sp.cross(w, r))
            f = mass * a_point
            force[j], moment[j] = force[j] + f, moment[j] + sp.cross(r, f)
        return force, moment

    def _apply_contacts(self, cfg: Configuration, force: dict, moment: dict, forces: ca.SX | None) -> None:
        if forces is None:
            return
        offset = 0
        for contact in self.contacts:
            f_local = cfg.to_local(contact.joint, forces[offset : offset + 3])
            offset += 3
            j = contact.joint
            force[j] = force[j] - f_local
            moment[j] = moment[j] - sp.cross(sp.const(contact.offset), f_local)
        for i in self.surface_contacts:  # sole-frame moments: a constant rotation into the joint frame
            contact = self.contacts[i]
            tau = forces[self.moment_slice(i)]
            if not sp.is_identity(contact.rotation):
                tau = ca.mtimes(sp.const(contact.rotation), tau)
            moment[contact.joint] = moment[contact.joint] - tau

    def _backward(self, cfg: Configuration, force: dict, moment: dict) -> ca.SX:
        """Backward pass: accumulate wrenches to the root, project on joint axes."""
        tau: list = [None] * self.nv
        for i in sorted(self.joints, reverse=True):
            joint = self.joints[i]
            axis = joint.axis
            tau[joint.idx_v] = _dot_const(axis, moment[i] if joint.kind == "revolute" else force[i])
            rot, t, p = cfg.local_rotation[i], cfg.local_translation[i], joint.parent
            f_parent = ca.mtimes(rot, force[i])
            force[p] = force[p] + f_parent
            moment[p] = moment[p] + ca.mtimes(rot, moment[i]) + sp.cross(t, f_parent)
        base = ca.vertcat(force[1], moment[1])
        for k in range(6):
            tau[k] = base[k]
        return ca.vertcat(*tau)

    def rnea(self, cfg: Configuration, motion: Motion, a: ca.SX, forces: ca.SX | None = None) -> ca.SX:
        """Inverse dynamics tau = M a + b - J_c^T F_c (eqs. 2 and 5); base rows are local wrenches.

        With a drive train on the robot, joint rows add I_a a_j + b v_j + c tanh(v_j / v_c).
        """
        force, moment = self._body_wrenches(cfg, motion, a, gravity=True)
        self._apply_contacts(cfg, force, moment, forces)
        return self._backward(cfg, force, moment) + self.drive_train_torque(motion.v, a)

    def drive_train_torque(self, v: ca.SX, a: ca.SX) -> ca.SX:
        """Generalized forces of the joints' armature and friction (zero rows vanish from the graph)."""
        rows = [ca.SX(0)] * self.nv
        for i in range(self.nv - 6):
            k = 6 + i
            term = ca.SX(0)
            if self.armature[i]:
                term += self.armature[i] * a[k]
            if self.viscous_friction[i]:
                term += self.viscous_friction[i] * v[k]
            if self.coulomb_friction[i]:
                term += self.coulomb_friction[i] * ca.tanh(v[k] / self.coulomb_velocity)
            rows[k] = term
        return ca.vertcat(*rows)

    def _composite_inertias(self, cfg: Configuration) -> dict[int, ca.SX]:
        """6x6 composite spatial inertias (lin, ang ordering) in joint frames (CRBA's first pass)."""
        comp = {}
        for i, body in self.bodies.items():
            c = body.com
            cx = _skew_np(c)
            top = np.hstack([body.mass * np.eye(3), -body.mass * cx])
            bottom = np.hstack([body.mass * cx, body.inertia_com - body.mass * cx @ cx])
            comp[i] = sp.const(np.vstack([top, bottom]))
        if cfg.inertial is not None:
            dc = cfg.inertial.base_com_offset
            base = self.bodies[1]
            comp[1] = comp[1] + _first_moment_inertia(base.mass, sp.const(base.com) + dc) - sp.const(
                _first_moment_inertia(base.mass, base.com))
            for j, offset, mass in cfg.inertial.point_masses(self):
                comp[j] = comp[j] + _first_moment_inertia(mass, sp.const(offset))
        for i in sorted(self.joints, reverse=True):
            p = self.joints[i].parent
            xm = _motion_transform(cfg.local_rotation[i], cfg.local_translation[i])
            comp[p] = comp[p] + ca.mtimes([xm.T, comp[i], xm])
        return comp

    def mass_matrix(self, cfg: Configuration) -> ca.SX:
        """Joint-space inertia matrix M(q) by the composite rigid-body algorithm."""
        comp = self._composite_inertias(cfg)
        mass = ca.SX.zeros(self.nv, self.nv)
        for i in sorted(self.joints, reverse=True):
            joint = self.joints[i]
            s = _motion_subspace(joint)
            f = ca.mtimes(comp[i], s)  # 6x1
            mass[joint.idx_v, joint.idx_v] = ca.mtimes(s.T, f)
            j = i
            while self.joints.get(j) is not None:
                jj = self.joints[j]
                xm = _motion_transform(cfg.local_rotation[j], cfg.local_translation[j])
                f = ca.mtimes(xm.T, f)
                parent = jj.parent
                if parent == 1:
                    mass[0:6, joint.idx_v] = f
                    mass[joint.idx_v, 0:6] = f.T
                    break
                k = self.joints[parent].idx_v
                val = ca.mtimes(_motion_subspace(self.joints[parent]).T, f)
                mass[k, joint.idx_v] = val
                mass[joint.idx_v, k] = val
                j = parent
        mass[0:6, 0:6] = comp[1]
        for i in np.flatnonzero(self.armature):
            mass[6 + i, 6 + i] += self.armature[i]
        return mass

    def forward_dynamics(self, cfg: Configuration, motion: Motion, tau_joints: ca.SX, forces: ca.SX | None = None) -> ca.SX:
        """a = M^-1 ([0; tau_j] + J_c^T F_c - b), with M factorised by the sparse L^T D L of the tree."""
        bias = self.rnea(cfg, motion, ca.SX.zeros(self.nv), forces)  # b - J^T F
        rhs = ca.vertcat(ca.SX.zeros(6), tau_joints) - bias
        return _ltdl_solve(self.mass_matrix(cfg), self.dof_parents, rhs)

    @cached_property
    def dof_parents(self) -> list[int]:
        """Parent DoF of each DoF (the free-flyer block is a chain), -1 for the first."""
        parents = [-1, 0, 1, 2, 3, 4]
        for i in range(2, self.njoints):
            p = self.joints[i].parent
            parents.append(5 if p == 1 else self.joints[p].idx_v)
        return parents

    # ------------------------------------------------------------------ centroidal
    def com_local(self, cfg: Configuration) -> ca.SX:
        """Centre of mass in the base frame (relative to the base origin)."""
        moment = {i: sp.const(b.mass * b.com) for i, b in self.bodies.items()}
        for i in sorted(self.joints, reverse=True):
            j = self.joints[i]
            moment[j.parent] = moment[j.parent] + ca.mtimes(cfg.local_rotation[i], moment[i]) + self.subtree_mass[i] * cfg.local_translation[i]
        return moment[1] / self.total_mass

    def com(self, cfg: Configuration) -> ca.SX:
        return cfg.base_position + ca.mtimes(cfg.base_rotation, self.com_local(cfg))

    def _to_centroidal_frame(self, cfg: Configuration, lin: ca.SX, ang: ca.SX) -> ca.SX:
        """Base-frame wrench-like quantity about the base origin -> world axes about the CoM."""
        ang_com = ang - sp.cross(self.com_local(cfg), lin)
        return ca.vertcat(ca.mtimes(cfg.base_rotation, lin), ca.mtimes(cfg.base_rotation, ang_com))

    def centroidal_momentum(self, cfg: Configuration, motion: Motion) -> ca.SX:
        """h_com = A(q) v: linear momentum and angular momentum about the CoM, world axes."""
        lin, ang = {}, {}
        for i, body in self.bodies.items():
            w = motion.ang[i]
            c = sp.const(body.com)
            l = body.mass * (motion.lin[i] + sp.cross(w, c))
            lin[i] = l
            ang[i] = ca.mtimes(sp.const(body.inertia_com), w) + sp.cross(c, l)
        for i in sorted(self.joints, reverse=True):
            rot, t, p = cfg.local_rotation[i], cfg.local_translation[i], self.joints[i].parent
            l_parent = ca.mtimes(rot, lin[i])
            lin[p] = lin[p] + l_parent
            ang[p] = ang[p] + ca.mtimes(rot, ang[i]) + sp.cross(t, l_parent)
        return self._to_centroidal_frame(cfg, lin[1], ang[1])

    def centroidal_momentum_rate(self, cfg: Configuration, motion: Motion, a: ca.SX) -> ca.SX:
        """dh_com/dt = A(q) a + Adot(q, v) v, from the RNEA body wrenches without gravity."""
        force, moment = self._body_wrenches(cfg, motion, a, gravity=False)
        for i in sorted(self.joints, reverse=True):
            rot, t, p = cfg.local_rotation[i], cfg.local_translation[i], self.joints[i].parent
            f_parent = ca.mtimes(rot, force[i])
            force[p] = force[p] + f_parent
            moment[p] = moment[p] + ca.mtimes(rot, moment[i]) + sp.cross(t, f_parent)
        return self._to_centroidal_frame(cfg, force[1], moment[1])

    def base_rotational_inertia_about_com(self, cfg: Configuration) -> ca.SX:
        """3x3 locked-body rotational inertia about the CoM, base axes (composite inertia of CRBA)."""
        composite = self._composite_inertias(cfg)[1]
        cx = sp.skew(self.com_local(cfg))
        return composite[3:6, 3:6] + self.total_mass * ca.mtimes(cx, cx)

    def centroidal_base_inverse(self, cfg: Configuration, momentum: ca.SX) -> ca.SX:
        """v_b = A_b(q)^-1 y: base twist (local frame) whose centroidal momentum is y (world, about CoM).

        A_b maps the base twist to the momentum of the robot frozen as one rigid body:
        h_lin = m R (v + w x c), h_ang = R I_c w. Inverting it needs only the 3x3 I_c (Table I rows 4, 6).
        """
        c = self.com_local(cfg)
        rt = cfg.base_rotation.T
        lin, ang = ca.mtimes(rt, momentum[0:3]), ca.mtimes(rt, momentum[3:6])
        omega = ca.mtimes(_inverse_3x3(self.base_rotational_inertia_about_com(cfg)), ang)
        return ca.vertcat(lin / self.total_mass - sp.cross(omega, c), omega)

    def centroidal_wrench(self, cfg: Configuration, forces: ca.SX) -> ca.SX:
        """dh_com/dt from the contact wrenches (forces in world at `contact_frames`, sole moments) and
        gravity, about the CoM."""
        com = self.com(cfg)
        lin = sp.const(self.total_mass * self.gravity)
        ang = ca.SX.zeros(3)
        for i, frame in enumerate(self.contact_frames):
            f = forces[3 * i : 3 * i + 3]
            position, rotation = self.frame_placement(cfg, frame)
            lin = lin + f
            ang = ang + sp.cross(position - com, f)
            if self.contacts[i].surface:  # a flat foot's moment, sole frame -> world
                ang = ang + ca.mtimes(rotation, forces[self.moment_slice(i)])
        return ca.vertcat(lin, ang)

    # ------------------------------------------------------------------ casadi Functions
    def functions(self) -> dict[str, ca.Function]:
        """casadi.Function of every algorithm with pinocchio-layout inputs (for checks and benchmarks)."""
        q = ca.SX.sym("q", self.nq)
        q1 = ca.SX.sym("q1", self.nq)
        v = ca.SX.sym("v", self.nv)
        a = ca.SX.sym("a", self.nv)
        dq = ca.SX.sym("dq", self.nv)
        tau_j = ca.SX.sym("tau_j", self.nv - 6)
        forces = ca.SX.sym("f", self.n_forces)
        cfg = self.configuration(q)
        motion = Motion(cfg, v)
        ee = self.robot.contact_frames[-1]
        fk_pos, fk_rot = self.frame_placement(cfg, ee)
        vel_lin, vel_ang = self.frame_velocity(cfg, motion, ee)
        frame_vel = ca.vertcat(vel_lin, vel_ang)
        return {
            "rnea": ca.Function("rnea", [q, v, a, forces], [self.rnea(cfg, motion, a, forces)]),
            "fk": ca.Function("fk", [q], [fk_pos, fk_rot]),
            "frame_velocity": ca.Function("frame_velocity", [q, v], [frame_vel]),
            "jacobian": ca.Function("jacobian", [q], [ca.jacobian(frame_vel, v)]),
            "crba": ca.Function("crba", [q], [self.mass_matrix(cfg)]),
            "nle": ca.Function("nle", [q, v], [self.rnea(cfg, motion, ca.SX.zeros(self.nv))]),
            "forward_dynamics": ca.Function(
                "forward_dynamics", [q, v, tau_j, forces], [self.forward_dynamics(cfg, motion, tau_j, forces)]
            ),
            "com": ca.Function("com", [q], [self.com(cfg)]),
            "centroidal_momentum": ca.Function("centroidal_momentum", [q, v], [self.centroidal_momentum(cfg, motion)]),
            "centroidal_momentum_rate": ca.Function(
                "centroidal_momentum_rate", [q, v, a], [self.centroidal_momentum_rate(cfg, motion, a)]
            ),
            "centroidal_base_inverse": ca.Function(
                "centroidal_base_inverse", [q, forces[:6]], [self.centroidal_base_inverse(cfg, forces[:6])]
            ),
            "centroidal_wrench": ca.Function("centroidal_wrench", [q, forces], [self.centroidal_wrench(cfg, forces)]),
            "integrate": ca.Function("integrate", [q, dq], [self.integrate(q, dq)]),
            "difference": ca.Function("difference", [q, q1], [self.difference(q, q1)]),
        }


def _first_moment_inertia(mass, com):
    """The mass and CoM part of a 6x6 spatial inertia about the joint origin (a point mass `mass` at `com`):
    [[m I, -m [c]x], [m [c]x, -m [c]x [c]x]] (numeric for NumPy inputs, SX otherwise)."""
    if isinstance(com, np.ndarray) and not isinstance(mass, ca.SX):
        cx = _skew_np(com)
        return np.vstack([np.hstack([mass * np.eye(3), -mass * cx]), np.hstack([mass * cx, -mass * cx @ cx])])
    cx = sp.skew(com)
    return ca.vertcat(ca.horzcat(mass * ca.SX.eye(3), -mass * cx), ca.horzcat(mass * cx, -mass * ca.mtimes(cx, cx)))


def _inverse_3x3(m: ca.SX) -> ca.SX:
    """Inverse of a 3x3 matrix by cofactors (rows of the inverse are cross products of columns)."""
    c0, c1, c2 = m[:, 0], m[:, 1], m[:, 2]
    r0, r1, r2 = sp.cross(c1, c2), sp.cross(c2, c0), sp.cross(c0, c1)
    det = ca.dot(c0, r0)
    return ca.horzcat(r0, r1, r2).T / det


def _dot_const(axis: np.ndarray, vec: ca.SX):
    out = 0
    for k in range(3):
        if abs(axis[k]) > 1e-14:
            out = out + (vec[k] if axis[k] == 1.0 else axis[k] * vec[k])
    return out


def _skew_np(c: np.ndarray) -> np.ndarray:
    return np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]])


def _motion_transform(rot: ca.SX, t: ca.SX) -> ca.SX:
    """6x6 motion transform parent -> child of a joint: [[R^T, -R^T [t]x], [0, R^T]]."""
    rt = rot.T
    return ca.vertcat(
        ca.horzcat(rt, -ca.mtimes(rt, sp.skew(t))),
        ca.horzcat(ca.SX.zeros(3, 3), rt),
    )


def _motion_subspace(joint: _Joint) -> ca.SX:
    axis = joint.axis
    if joint.kind == "revolute":
        return sp.const(np.concatenate([np.zeros(3), axis]).reshape(6, 1))
    return sp.const(np.concatenate([axis, np.zeros(3)]).reshape(6, 1))


def _ltdl_solve(mass: ca.SX, parents: list[int], rhs: ca.SX) -> ca.SX:
    """Solve M x = b with Featherstone's sparse L^T D L factorisation (branch-induced sparsity)."""
    n = mass.shape[0]
    h = {(i, j): mass[i, j] for i in range(n) for j in range(n) if j <= i}
    for k in range(n - 1, -1, -1):
        inv_d = 1 / h[k, k]
        i = parents[k]
        while i != -1:
            factor = h[k, i] * inv_d
            j = i
            while j != -1:
                h[i, j] = h[i, j] - factor * h[k, j]
                j = parents[j]
            h[k, i] = factor
            i = parents[i]
    x = [rhs[i] for i in range(n)]
    for i in range(n - 1, -1, -1):  # L^T y = b
        j = parents[i]
        while j != -1:
            x[j] = x[j] - h[i, j] * x[i]
            j = parents[j]
    for i in range(n):
        x[i] = x[i] / h[i, i]
    for i in range(n):  # L x = y
        j = parents[i]
        while j != -1:
            x[i] = x[i] - h[i, j] * x[j]
            j = parents[j]
    return ca.vertcat(*x)
