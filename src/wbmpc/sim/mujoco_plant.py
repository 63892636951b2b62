"""`MujocoPlant`: the robot in a MuJoCo scene, stepped with joint torques, states in pinocchio layout.

MuJoCo free joint: qpos = [p, quat wxyz], qvel = [linear velocity in WORLD, angular velocity in
the body frame]. Pinocchio: q = [p, quat xyzw], v = [linear velocity in the BASE frame, angular
velocity in the base frame]. Joints are matched by name, so extra scene objects with their own
joints may appear anywhere in MuJoCo's vectors. With a plant model (`MujocoPlantConfig.plant_model`,
`wbmpc.sim.plant_model`) MuJoCo simulates another file of the robot; `SceneRobot` says where the controller's
joints (their signs and offsets), actuators, bodies and feet are in it, and `plant_model_report()` what it is.
"""

from __future__ import annotations

import mujoco
import numpy as np

from wbmpc.robots import RobotModel
from wbmpc.sim.base import (
    PlantConfig,
    PlantDivergedError,
    PlantInputError,
    Recording,
    checked_state,
    checked_torques,
    checked_vector3,
    quat_xyzw_to_matrix,
    specialised_config,
)
from wbmpc.sim.mujoco_scene import MujocoPlantConfig, build_scene

_INSTABILITY_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC)


class MujocoPlant:
    """MuJoCo simulation of `robot` (see `MujocoPlantConfig`); implements `wbmpc.sim.Plant`."""

    def __init__(self, robot: RobotModel, config: PlantConfig | None = None):
        self.robot = robot
        self.config = specialised_config(config, MujocoPlantConfig)
        self.model, self.layout = build_scene(robot, self.config)
        self.data = mujoco.MjData(self.model)
        self.recording = Recording()
        m, layout = self.model, self.layout
        root = m.joint(layout.root_joint)
        self._root_qadr, self._root_vadr = int(root.qposadr[0]), int(root.dofadr[0])
        self._qadr = np.array([m.joint(n).qposadr[0] for n in layout.joints])
        self._vadr = np.array([m.joint(n).dofadr[0] for n in layout.joints])
        self._sign, self._offset = layout.joint_sign, layout.joint_offset
        self._act = np.array(layout.actuators)
        self._foot_index = {g: k for k, geoms in enumerate(layout.foot_geoms) for g in geoms}
        self._body_names = list(layout.bodies.names)
        self._steps = 0
        self._robot_geom = layout.robot_geoms
        self.self_contacts = SelfContactCounter()
        self._force = np.zeros(6)
        self._step_hooks: list = []
        self.ee_body: str | None = None
        self._ee_geoms: set[int] = set()
        if robot.arm_ee:
            frame = robot.model.frames[robot.frame_id(robot.arm_ee)]
            self.ee_body = self._body_names[frame.parentJoint - 1]
            body = m.body(self.ee_body).id
            # the last link's shapes and those of any body mounted on it (a tool, a wiping pad)
            self._ee_geoms = {g for g in range(m.ngeom) if _in_subtree(m, int(m.geom_bodyid[g]), body)}
        self.reset()

    @property
    def ee_geoms(self) -> frozenset[int]:
        """MuJoCo geoms of the end-effector: the last link's shapes and those of any body mounted on it (a tool, a
        wiping pad); empty without an arm."""
        return frozenset(self._ee_geoms)

    # ------------------------------------------------------------------ Plant interface
    @property
    def time_s(self) -> float:
        return float(self.data.time)

    @property
    def dt_s(self) -> float:
        return float(self.model.opt.timestep)

    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        """Set the robot state (pinocchio layout; default q_nominal, v = 0); time 0; clear the recording."""
        q, v = checked_state(self.robot, q, v)
        mujoco.mj_resetData(self.model, self.data)
        self.set_state(q, v)
        self._steps = 0
        self.self_contacts = SelfContactCounter()
        self.recording.clear()
        self._record()

    def set_state(self, q: np.ndarray, v: np.ndarray) -> None:
        """Overwrite the robot state without resetting time, objects or the recording."""
        q, v = checked_state(self.robot, q, v)
        d = self.data
        d.qpos[self._root_qadr : self._root_qadr + 3] = q[:3]
        d.qpos[self._root_qadr + 3 : self._root_qadr + 7] = q[[6, 3, 4, 5]]
        d.qpos[self._qadr] = self._offset + self._sign * self.robot.joint_positions(q)
        d.qvel[self._root_vadr : self._root_vadr + 3] = quat_xyzw_to_matrix(q[3:7]) @ v[:3]
        d.qvel[self._root_vadr + 3 : self._root_vadr + 6] = v[3:6]
        d.qvel[self._vadr] = self._sign * v[6:]
        mujoco.mj_forward(self.model, self.data)

    def step(self, tau_joints: np.ndarray) -> np.ndarray:
        """One physics step of `dt_s` with joint torques clamped to +-tau_max; returns the applied torques."""
        tau = checked_torques(self.robot, tau_joints)
        self.data.ctrl[self._act] = self._sign * tau
        for hook in self._step_hooks:
            hook.before_step(self)
        mujoco.mj_step(self.model, self.data)
        unstable = [w.name for w in _INSTABILITY_WARNINGS if self.data.warning[w].number > 0]
        if unstable or not np.all(np.isfinite(self.data.qpos)):
            t_s = self._steps * self.dt_s
            raise PlantDivergedError(
                f"MuJoCo became unstable after t = {t_s:.4f} s ({', '.join(unstable) or 'non-finite qpos'}; MuJoCo "
                "reset its state); reduce dt_s, gains or velocities, then reset() the plant"
            )
        self._steps += 1
        if self.config.self_collision:
            self._count_self_contacts()
        self._record()
        for hook in self._step_hooks:
            hook.after_step(self)
        return tau

    def applied_torques(self) -> np.ndarray:
        """The joint torques of the current step (clamped), robot joint order (step hooks read them)."""
        return self._sign * np.array(self.data.ctrl[self._act])

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) in pinocchio layout."""
        d = self.data
        qw = d.qpos[self._root_qadr + 3 : self._root_qadr + 7]
        quat_xyzw = qw[[1, 2, 3, 0]] / np.linalg.norm(qw)
        base = np.concatenate([d.qpos[self._root_qadr : self._root_qadr + 3], quat_xyzw])
        angles = self._sign * (d.qpos[self._qadr] - self._offset)
        q = self.robot.with_joint_positions(np.concatenate([base, np.zeros(self.robot.nq - 7)]), angles)
        v_world = d.qvel[self._root_vadr : self._root_vadr + 3]
        v = np.concatenate([quat_xyzw_to_matrix(quat_xyzw).T @ v_world, d.qvel[self._root_vadr + 3 : self._root_vadr + 6],
                            self._sign * d.qvel[self._vadr]])
        return q, v

    def apply_base_velocity_kick(self, dv_world_m_s: np.ndarray) -> None:
        """Add `dv_world_m_s` (m/s, world frame) to the base linear velocity (a push)."""
        dv = checked_vector3("dv_world_m_s", dv_world_m_s)
        self.data.qvel[self._root_vadr : self._root_vadr + 3] += dv
        mujoco.mj_forward(self.model, self.data)

    def contact_forces(self) -> np.ndarray:
        """World-frame force (N) on each foot from the floor and scene objects, shape (n_feet, 3)."""
        m, d = self.model, self.data
        forces = np.zeros((len(self.robot.feet), 3))
        geoms = d.contact.geom
        for i in range(d.ncon):
            g1, g2 = geoms[i]
            for sign, foot, other in ((1.0, g2, g1), (-1.0, g1, g2)):
                k = self._foot_index.get(int(foot))
                if k is not None and not self._robot_geom[other]:
                    mujoco.mj_contactForce(m, d, i, self._force)
                    # contact frame rows: normal (from geom1 to geom2), tangent 1, tangent 2;
                    # the force acts on geom2 along the normal and on geom1 opposite
                    forces[k] += sign * d.contact.frame[i].reshape(3, 3).T @ self._force[:3]
        return forces

    def sole_pressure(self) -> dict[str, tuple[np.ndarray, float] | None]:
        """Measured centre of pressure of each flat foot's box sole: {foot: ((x, y) in the sole frame, normal
        force N)}, None while the sole carries no load. The contact points' positions weighted by their
        normal forces (floor and scene objects), expressed in the sole frame (the box's bottom face)."""
        m, d = self.model, self.data
        out: dict[str, tuple[np.ndarray, float] | None] = {}
        for k, foot in enumerate(self.robot.feet):
            if foot not in self.robot.soles:
                continue
            geoms = set(self.layout.foot_geoms[k])
            weighted, total = np.zeros(3), 0.0
            for i in range(d.ncon):
                g1, g2 = (int(g) for g in d.contact.geom[i])
                other = g1 if g2 in geoms else g2 if g1 in geoms else None
                if other is None or self._robot_geom[other]:
                    continue
                mujoco.mj_contactForce(m, d, i, self._force)
                normal = float(self._force[0])
                weighted += normal * d.contact.pos[i]
                total += normal
            if total <= 1e-9:
                out[foot] = None
                continue
            body, placement = self.layout.bodies.frame(self.robot, self.robot.soles[foot].frame)
            b = m.body(body).id
            rotation = d.xmat[b].reshape(3, 3) @ placement.rotation
            origin = d.xpos[b] + d.xmat[b].reshape(3, 3) @ placement.translation
            local = rotation.T @ (weighted / total - origin)
            out[foot] = (local[:2], total)
        return out

    # ------------------------------------------------------------------ extras
    def add_step_hook(self, hook) -> None:
        """`hook.before_step(plant)` runs before and `hook.after_step(plant)` after every physics step
        (scripted forces on scene objects, measurements; see `wbmpc.sim.objects`)."""
        self._step_hooks.append(hook)

    def ee_contact_force(self, geom_names) -> np.ndarray:
        """World-frame force (N) ON the arm's last link (the end-effector sphere and the gripper's
        shapes) from contacts with the named geoms."""
        if not self._ee_geoms:
            raise PlantInputError("the arm's last link has no collision geom (ee_sphere_radius_m is None or no arm)")
        m, d = self.model, self.data
        others = {int(m.geom(name).id) for name in geom_names}
        force = np.zeros(3)
        for i in range(d.ncon):
            g1, g2 = (int(g) for g in d.contact.geom[i])
            for sign, ee, other in ((1.0, g2, g1), (-1.0, g1, g2)):
                if ee in self._ee_geoms and other in others:
                    mujoco.mj_contactForce(m, d, i, self._force)
                    force += sign * d.contact.frame[i].reshape(3, 3).T @ self._force[:3]
        return force

    def qpos_from_q(self, q: np.ndarray) -> np.ndarray:
        """MuJoCo qpos (current objects kept) for a pinocchio configuration, e.g. to replay a recording."""
        qpos = self.data.qpos.copy()
        qpos[self._root_qadr : self._root_qadr + 3] = q[:3]
        qpos[self._root_qadr + 3 : self._root_qadr + 7] = np.asarray(q)[[6, 3, 4, 5]]
        qpos[self._qadr] = self._offset + self._sign * self.robot.joint_positions(q)
        return qpos

    def plant_model_report(self) -> dict | None:
        """What the plant simulates when it is not the controller's model (`wbmpc.sim.plant_model`), else None."""
        return self.layout.plant_model

    def body_name(self, joint_id: int) -> str:
        """MuJoCo body carrying pinocchio joint `joint_id` (1 = base)."""
        return self._body_names[joint_id - 1]

    def _count_self_contacts(self) -> None:
        d, n = self.data, self.data.ncon
        if not n:
            self.self_contacts.update(self, ())
            return
        geoms = d.contact.geom[:n]
        robot = self._robot_geom[geoms[:, 0]] & self._robot_geom[geoms[:, 1]]
        self.self_contacts.update(self, np.sort(geoms[robot], axis=1) if robot.any() else ())

    def _record(self) -> None:
        every = self.config.record_every_n_steps
        if every and self._steps % every == 0:
            self.recording.append(self.time_s, self.state()[0])


class SelfContactCounter:
    """Robot-robot contacts over a run: `contacts` counts each touch once (a geom pair touching at a step
    where it did not touch at the step before), `steps` the physics steps with any, `pairs` the touches
    per pair of bodies ("link04 / base")."""

    def __init__(self):
        self.contacts = 0
        self.steps = 0
        self.pairs: dict[str, int] = {}
        self._touching: set[tuple[int, int]] = set()

    def update(self, plant: "MujocoPlant", geom_pairs) -> None:
        touching = {(int(a), int(b)) for a, b in geom_pairs}
        if touching:
            self.steps += 1
            m = plant.model
            for a, b in touching - self._touching:
                self.contacts += 1
                name = " / ".join(sorted((m.body(int(m.geom_bodyid[a])).name, m.body(int(m.geom_bodyid[b])).name)))
                self.pairs[name] = self.pairs.get(name, 0) + 1
        self._touching = touching

    def metrics(self, dt_s: float) -> dict:
        return {"self_collision_contacts": self.contacts, "self_collision_time_s": self.steps * dt_s,
                "self_collision_pairs": dict(sorted(self.pairs.items(), key=lambda item: -item[1]))}


def _in_subtree(m: mujoco.MjModel, body: int, root: int) -> bool:
    """Whether `body` is `root` or one of its descendants."""
    while body > 0:
        if body == root:
            return True
        body = int(m.body_parentid[body])
    return root == 0
