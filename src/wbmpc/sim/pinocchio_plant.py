"""`PinocchioPlant`: rigid-body dynamics with hard unilateral frictional foot contacts, no simulator.

Time-stepping (semi-implicit Euler on the manifold), per step of dt:
    v_free = v + dt M^-1 (S^T tau - d * v_j - h(q, v))
    impulses lam from the contact problem at the feet (`contact_solver`): no penetration at the
    next step (v_n+ >= -gap/dt, penetration corrected at `penetration_correction_per_step`),
    Coulomb friction with coefficient `friction_mu`
    v+ = v_free + M^-1 J^T lam,   q+ = integrate(q, dt v+)
The ground is the plane z = `ground_height_m`; point feet are spheres of `robot.foot_radius_m` (the
contact point rolls with the sphere), flat feet (`robot.soles`) touch at the four corners of their
sole rectangle (four frictional point contacts: their forces span the sole's wrench cone). Only the feet touch the ground; joint limits are not
enforced (MuJoCo enforces both).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

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
from wbmpc.sim.contact_solver import ContactSolution, solve_contact_impulses

_EZ_SKEW = pin.skew(np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class PinocchioPlantConfig(PlantConfig):
    """Contact settings of the pinocchio plant on top of `PlantConfig`."""

    ground_height_m: float = 0.0
    contact_margin_m: float = 0.01  # feet closer than this enter the contact problem (> travel per step)
    penetration_correction_per_step: float = 0.2  # fraction of a penetration removed per step (Baumgarte)
    max_solver_iterations: int = 100  # projected Gauss-Seidel fallback sweeps
    solver_tolerance: float = 1e-7

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 < self.penetration_correction_per_step <= 1:
            value = self.penetration_correction_per_step
            raise PlantInputError(f"penetration_correction_per_step must be in (0, 1], got {value}")
        if self.contact_margin_m < 0 or self.max_solver_iterations < 1:
            raise PlantInputError("contact_margin_m must be >= 0 and max_solver_iterations >= 1")


class PinocchioPlant:
    """Pinocchio forward dynamics with hard foot contacts; implements `wbmpc.sim.Plant`."""

    def __init__(self, robot: RobotModel, config: PlantConfig | None = None):
        self.robot = robot
        self.config = specialised_config(config, PinocchioPlantConfig)
        self.model = pin.Model(robot.model)  # own copy: the armature is set on it
        self.model.armature = np.r_[np.zeros(6), self.config.joint_array(robot, "joint_armature_kg_m2")]
        self._damping = self.config.joint_array(robot, "joint_damping_nm_s_per_rad")
        if np.any(self.config.joint_array(robot, "joint_frictionloss_nm")):
            raise PlantInputError(
                "the pinocchio plant has no Coulomb joint friction (joint_frictionloss_nm); use the MuJoCo plant"
            )
        self.data = self.model.createData()
        self.recording = Recording()
        self._lower = np.tril_indices(self.model.nv, -1)
        self._foot_ids = [robot.frame_id(robot.contact_frame(f)) for f in robot.feet]
        # contact points of each foot in its contact frame: the sphere's centre, or a sole's four corners
        self._foot_points = [robot.soles[f].corners_m() if f in robot.soles else None for f in robot.feet]
        self.reset()

    # ------------------------------------------------------------------ Plant interface
    @property
    def time_s(self) -> float:
        return self._steps * self.config.dt_s

    @property
    def dt_s(self) -> float:
        return self.config.dt_s

    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        """Set the state (pinocchio layout; default q_nominal, v = 0); time 0; clear the recording."""
        self._q, self._v = checked_state(self.robot, q, v)
        self._steps = 0
        self._forces = np.zeros((len(self.robot.feet), 3))
        self._last_active: list[tuple[int, int]] = []
        self.last_contact_solve: ContactSolution = solve_contact_impulses(np.zeros((0, 0)), np.zeros(0), 0.0)
        self.recording.clear()
        self._record()

    def step(self, tau_joints: np.ndarray) -> np.ndarray:
        """One step of `dt_s` with joint torques clamped to +-tau_max; returns the applied torques."""
        tau = checked_torques(self.robot, tau_joints)
        cfg, model, data = self.config, self.model, self.data
        q, v, dt = self._q, self._v, cfg.dt_s
        generalized = np.zeros(self.model.nv)
        generalized[6:] = tau - self._damping * v[6:]
        v_free = v + dt * pin.aba(model, data, q, v, generalized)  # model.armature holds the armature
        Minv = pin.computeMinverse(model, data, q)
        Minv[self._lower] = Minv.T[self._lower]  # pinocchio guarantees the upper triangle
        pin.computeJointJacobians(model, data, q)

        active, jacobians, gaps = self._candidate_contacts()
        self._forces[:] = 0.0
        if active:
            J = np.vstack(jacobians)
            MinvJt = Minv @ J.T
            G = J @ MinvJt
            g = J @ v_free
            gaps = np.array(gaps)
            g[2::3] += np.where(gaps > 0, gaps, cfg.penetration_correction_per_step * gaps) / dt
            warm = self.last_contact_solve if self._last_active == active else None
            self.last_contact_solve = solve_contact_impulses(
                G, g, cfg.friction_mu, warm, cfg.max_solver_iterations, cfg.solver_tolerance
            )
            lam = self.last_contact_solve.impulses
            v_next = v_free + MinvJt @ lam
            np.add.at(self._forces, [foot for foot, _ in active], lam.reshape(-1, 3) / dt)
        else:
            v_next = v_free
            self.last_contact_solve = solve_contact_impulses(np.zeros((0, 0)), np.zeros(0), cfg.friction_mu)
        self._last_active = active
        q_next = pin.integrate(model, q, v_next * dt)
        if not (np.all(np.isfinite(q_next)) and np.all(np.isfinite(v_next))):
            raise PlantDivergedError(
                f"pinocchio plant diverged at t = {self.time_s:.4f} s (non-finite state); reduce dt_s, gains or "
                "velocities, then reset() the plant"
            )
        q_next[3:7] /= np.linalg.norm(q_next[3:7])
        self._q, self._v = q_next, v_next
        self._steps += 1
        self._record()
        return tau

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) in pinocchio layout (copies)."""
        return self._q.copy(), self._v.copy()

    def apply_base_velocity_kick(self, dv_world_m_s: np.ndarray) -> None:
        """Add `dv_world_m_s` (m/s, world frame) to the base linear velocity (a push)."""
        dv = checked_vector3("dv_world_m_s", dv_world_m_s)
        self._v[:3] += quat_xyzw_to_matrix(self._q[3:7]).T @ dv

    def contact_forces(self) -> np.ndarray:
        """World-frame ground force (N) on each foot during the last step, shape (n_feet, 3)."""
        return self._forces.copy()

    # ------------------------------------------------------------------ internals
    def _candidate_contacts(self) -> tuple[list[tuple[int, int]], list[np.ndarray], list[float]]:
        """Contact points that may touch the ground within this step: (foot, point) indices, 3 x nv
        contact Jacobians, gaps (m)."""
        model, data, cfg = self.model, self.data, self.config
        radius = self.robot.foot_radius_m
        active, jacobians, gaps = [], [], []
        for k, fid in enumerate(self._foot_ids):
            placement = pin.updateFramePlacement(model, data, fid)
            corners = self._foot_points[k]
            if corners is None:  # point foot: a sphere
                gap = placement.translation[2] - radius - cfg.ground_height_m
                if gap > cfg.contact_margin_m:
                    continue
                J6 = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
                active.append((k, 0))
                jacobians.append(J6[:3] + radius * _EZ_SKEW @ J6[3:])  # velocity of the sphere's lowest point
                gaps.append(gap)
                continue
            offsets = corners @ placement.rotation.T  # flat foot: the sole's corners
            corner_gaps = placement.translation[2] + offsets[:, 2] - cfg.ground_height_m
            if corner_gaps.min() > cfg.contact_margin_m:
                continue
            J6 = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            for c, (offset, gap) in enumerate(zip(offsets, corner_gaps)):
                if gap > cfg.contact_margin_m:
                    continue
                active.append((k, c))
                jacobians.append(J6[:3] - pin.skew(offset) @ J6[3:])  # v + omega x offset
                gaps.append(gap)
        return active, jacobians, gaps

    def _record(self) -> None:
        every = self.config.record_every_n_steps
        if every and self._steps % every == 0:
            self.recording.append(self.time_s, self._q)
