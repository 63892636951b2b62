"""`wipe` (section VI-C): standing, move over a board in a circle or figure-eight pressing with `--force-n`
(default 10 N) along the normal; the target also contains the board's friction along the motion.

The end-effector carries a sprung wiping pad (`CompliantPad`, `--pad-stiffness`, 0 for the rigid sphere), and the
in-plane path feedback has integral action (`--wipe-integral`) against the board's static friction, which the
force target cannot carry.
"""

from __future__ import annotations

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.scenarios.arm_statics import EE_SPHERE_RADIUS_M, check_arm_force, nominal_ee_position
from wbmpc.scenarios.base import ScenarioOptions
from wbmpc.scenarios.feedback import EeState, InPlaneIntegral, ee_velocity_feedback
from wbmpc.scenarios.force_task import ForceTask
from wbmpc.scenarios.signals import ramp
from wbmpc.sim.objects import Board, CompliantPad


class Wipe(ForceTask):
    """Standing, wipe a board in a pattern while pressing with a normal force target (section VI-C)."""

    object_name = "board"
    RAMP_S = (0.5, 1.0)
    APPROACH_END_S = 0.5
    PATTERN_START_S = 1.2
    SPEED_UP_S = 1.0  # the pattern's phase rate ramps up over this time (no velocity jump)
    GAP_M = 0.02
    DEFAULT_FORCE_N = 10.0

    def __init__(self, options: ScenarioOptions):
        super().__init__("wipe", "standing, wipe a board in a pattern pressing with a normal force",
                         "stand", 10.0, needs_arm=True, options=options)
        self.force_window_start_s = self.PATTERN_START_S
        self._board: Board | None = None
        self._centre: np.ndarray | None = None

    @property
    def force_magnitude_n(self) -> float:
        return self.options.force_n if self.options.force_n is not None else self.DEFAULT_FORCE_N

    def board(self, robot) -> Board:
        if self._board is None:
            ee = nominal_ee_position(robot)
            if self.options.board == "vertical":
                face = ee + np.array([EE_SPHERE_RADIUS_M + self.GAP_M, 0.0, 0.0])
                size, offset = (1.0, 0.8), (0.0, 0.0)
            else:  # a table whose near edge stays clear of the robot's head and arm base
                face = ee - np.array([0.0, 0.0, EE_SPHERE_RADIUS_M + self.GAP_M])
                size, offset = (0.5, 0.8), (0.2, 0.0)
            self._board = Board(orientation=self.options.board, face_m=tuple(face), size_m=size,
                                centre_offset_m=offset, friction_mu=self.options.board_friction_mu)
            self._centre = face + self._board.normal * EE_SPHERE_RADIUS_M  # EE frame when touching
        return self._board

    def _objects(self, robot):
        stiffness = self.options.wipe_pad_stiffness_n_m
        return [self.board(robot)] + ([CompliantPad(stiffness_n_m=stiffness, radius_m=EE_SPHERE_RADIUS_M)]
                                      if stiffness > 0 else [])

    def _phase(self, t_s: float) -> tuple[float, float]:
        """Pattern phase and its rate: the rate ramps linearly to 2 pi / period over SPEED_UP_S."""
        w = 2 * np.pi / self.options.wipe_period_s
        tau = t_s - self.PATTERN_START_S
        if tau <= 0:
            return 0.0, 0.0
        if tau < self.SPEED_UP_S:
            return 0.5 * w * tau**2 / self.SPEED_UP_S, w * tau / self.SPEED_UP_S
        return w * (tau - 0.5 * self.SPEED_UP_S), w

    def path(self, robot, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """End-effector frame position and velocity of the pattern on the board at time t."""
        board = self.board(robot)
        a1, a2 = board.plane_axes
        r = self.options.wipe_size_m
        phi, rate = self._phase(t_s)
        if self.options.wipe_pattern == "circle":  # through the centre, like a wiping loop
            offset = r * np.sin(phi) * a1 + r * (1 - np.cos(phi)) * a2
            d_offset = r * np.cos(phi) * a1 + r * np.sin(phi) * a2
        else:  # figure eight
            offset = r * np.sin(phi) * a1 + 0.5 * r * np.sin(2 * phi) * a2
            d_offset = r * np.cos(phi) * a1 + r * np.cos(2 * phi) * a2
        return self._centre + offset, d_offset * rate

    def ee_reference(self, robot):
        return lambda t_s: self.path(robot, t_s)[0]

    def _force_direction(self, targets):
        inward = -self.board(self._scene.robot).normal
        along = targets @ inward
        return np.tile(inward, (len(targets), 1)), along

    def check(self, robot):
        board = self.board(robot)
        force = -board.normal * self.force_magnitude_n * np.hypot(1.0, self.options.board_friction_mu)
        check_arm_force(robot, force, "wiping force target (normal force and friction)")

    def commands(self, robot):
        ee = EeState(robot)
        board = self.board(robot)
        normal = board.normal
        mu = self.options.board_friction_mu

        integral = InPlaneIntegral(normal, self.options.wipe_integral_gain_1_s2)

        def command(t_s, q, v):
            p_ref, v_ref = self.path(robot, t_s)
            p = ee.position(q)
            if t_s < self.APPROACH_END_S:
                velocity = ee_velocity_feedback(v_ref, p_ref - 0.005 * normal, p)
            else:
                velocity = ee_velocity_feedback(v_ref + integral.update(t_s, p_ref - p), p_ref, p, free_normal=normal)
            press = ramp(t_s, *self.RAMP_S) * self.force_magnitude_n
            force = -normal * press
            speed = np.linalg.norm(v_ref)
            if speed > 1e-6:  # the board's friction resists the motion: the end-effector pushes along it
                force = force + mu * press * v_ref / speed
            return Commands(ee_velocity_m_s=velocity, ee_force_n=force)

        return command

    ee_error_label = "in-plane |p - p_ref| from the pattern's start"

    def ee_tracking_error(self, robot, t_s, ee):
        """In-plane error (the normal is force-controlled) from the pattern's start."""
        reference = np.array([self.path(robot, float(ti))[0] for ti in t_s])
        normal = self.board(robot).normal
        error = ee - reference
        return error - np.outer(error @ normal, normal), np.asarray(t_s) >= self.PATTERN_START_S

    def extra_metrics(self, robot, log):
        out = super().extra_metrics(robot, log)
        a = log.arrays(("t", "q"))
        t = a["t"]
        ee = robot.frame_trajectories(a["q"], [robot.arm_ee])[robot.arm_ee]
        reference = np.array([self.path(robot, ti)[0] for ti in t])
        normal_error = (ee - reference) @ self.board(robot).normal
        in_plane, use = self.ee_tracking_error(robot, t, ee)
        dist = np.linalg.norm(in_plane[use], axis=1)
        out.update({
            "ee_pos_rmse_m": float(np.sqrt(np.mean(dist**2))) if use.any() else None,
            "ee_pos_max_err_m": float(dist.max()) if use.any() else None,
            "ee_normal_offset_mean_mm": float(1e3 * np.mean(normal_error[use])) if use.any() else None,
            "board": self.options.board,
            "wipe_pattern": self.options.wipe_pattern,
            "board_friction_mu": self.options.board_friction_mu,
            "pad_stiffness_n_m": self.options.wipe_pad_stiffness_n_m,
        })
        if self.options.wipe_pad_stiffness_n_m > 0 and use.any():
            t_pad, deflection = self._scene.recording.series("pad", "deflection_m")
            late = t_pad >= self.PATTERN_START_S
            out["pad_deflection_mean_mm"] = float(1e3 * np.mean(np.linalg.norm(deflection[late], axis=1)))
        return out
