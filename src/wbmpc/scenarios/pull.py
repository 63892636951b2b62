"""`pull` (section VI-C): a load on the floor tied to the end-effector by a cable.

The robot walks backwards (`--gait trot|walk`) or, in stance (`--gait stand`), leans back and retracts the arm.
The force target is the cable tension that makes the load slide: T = mu m g / (cos(theta) + mu sin(theta)) along
the cable (theta above horizontal), unless `--force-n` sets it. With `--object-model` the MPC plans with the load
inside the OCP and the load's speed is the command.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.control.weights import CostWeights
from wbmpc.errors import ConfigError
from wbmpc.robots import GRAVITY_M_S2
from wbmpc.scenarios.arm_statics import check_arm_force, nominal_ee_position
from wbmpc.scenarios.base import ScenarioOptions
from wbmpc.scenarios.feedback import EeState, ee_velocity_feedback, yaw_rotation
from wbmpc.scenarios.force_task import ForceTask
from wbmpc.scenarios.signals import ramp
from wbmpc.sim.objects import CableLoad


class Pull(ForceTask):
    """Pull a load on the floor through a cable, walking backwards or in stance (section VI-C)."""

    object_name = "load"
    RAMP_S = (0.2, 1.0)
    MOVE_START_S = 1.2
    STANCE_RETRACT_M = 0.03
    STANCE_BASE_SHIFT_M = 0.05
    SLACK_M = 0.01
    HOOK_HEIGHT_M = 0.1

    def __init__(self, options: ScenarioOptions):
        super().__init__("pull", "pull a load through a cable while walking backwards (or in stance: --gait stand)",
                         "trot", 8.0, needs_arm=True, options=options)
        self.force_window_start_s = self.MOVE_START_S + 0.5

    def cost_weights(self, weights: CostWeights) -> CostWeights:
        """The legs' posture weight the paper pulled with, at most (tuning.LEG_POSTURE times less on a
        quadruped): the stiffer posture that keeps a trot from swaying biased the cable tension low (b1_z1,
        14 kg: 39.5 N for 40.4 N, -2.2 %, and the load did not slide; x5: -0.8 %, still stuck; the paper's:
        -0.2 %, pulled 0.64 m). A biped's lighter posture weight (control/biped.py) stays."""
        return replace(weights, leg_joint_position=min(weights.leg_joint_position, CostWeights().leg_joint_position))

    def _hook(self, robot) -> np.ndarray:
        ee = nominal_ee_position(robot)
        dz = ee[2] - self.HOOK_HEIGHT_M
        reach = self.options.cable_length_m - self.SLACK_M
        if reach <= dz:
            raise ConfigError(f"the cable ({self.options.cable_length_m} m) must be longer than the end-effector "
                              f"height above the hook ({dz:.2f} m)")
        return ee + np.array([np.sqrt(reach**2 - dz**2), 0.0, -dz])

    def target_force(self, robot) -> np.ndarray:
        """Force the end-effector applies on the cable (towards itself) to slide the load."""
        ee, hook = nominal_ee_position(robot), self._hook(robot)
        u = (ee - hook) / np.linalg.norm(ee - hook)
        cos_t, sin_t = np.linalg.norm(u[:2]), u[2]
        o = self.options
        tension = o.force_n if o.force_n is not None else \
            o.load_friction_mu * o.load_kg * GRAVITY_M_S2 / (cos_t + o.load_friction_mu * sin_t)
        return tension * u

    def _objects(self, robot):
        hook = self._hook(robot)
        size = (0.3, 0.3, 0.2)
        return [CableLoad(mass_kg=self.options.load_kg, friction_mu=self.options.load_friction_mu,
                          position_m=(hook[0] + size[0] / 2, hook[1]), size_m=size, hook_height_m=self.HOOK_HEIGHT_M,
                          cable_length_m=self.options.cable_length_m)]

    def check(self, robot):
        check_arm_force(robot, self.target_force(robot), "pulling force target")
        if self.options.object_model and not self.walking:
            raise ConfigError("pull --object-model commands the load's speed while the robot walks backwards; "
                              "--gait stand has no steady speed to command: use --gait trot or walk")

    SPEED_WINDOW_AFTER_MOVE_S = 1.0  # load_speed_rmse_m_s counts from this long after the move starts

    def object_model(self, robot):
        """The OCP's model of the scene's load and cable (`--object-model`)."""
        from wbmpc.ocp.objects import CableLoad1D

        return CableLoad1D.from_scene(self._objects(robot)[0])

    def load_reference(self, x0_m: float):
        """The load's commanded state [x, vx] at times t: at rest until the move starts, then towards the robot
        (-x) at the pull speed."""
        speed = self.options.pull_speed_m_s

        def reference(t_s):
            moving = np.maximum(np.asarray(t_s, dtype=float) - self.MOVE_START_S, 0.0)
            return np.column_stack([x0_m - speed * moving, np.where(moving > 0, -speed, 0.0)])

        return reference

    def _object_command(self, robot, t_s):
        from wbmpc.ocp.objects import ObjectCommand

        load = self._objects(robot)[0]
        values = self._scene.recording.values.get(self.object_name, {}).get("planar_state") if self._scene else None
        state = np.array([values[-1][0], values[-1][3]]) if values else np.array([load.position_m[0], 0.0])
        return ObjectCommand(state=state, reference=self.load_reference(load.position_m[0]))

    @property
    def walking(self) -> bool:
        return self.gait != "stand"

    def terrain(self, robot):
        """--terrain FILE, or a ramp up behind the robot that it pulls the load walking up backwards (--slope-deg),
        else the flat floor."""
        if not hasattr(self, "_terrain"):
            from wbmpc.scenarios.terrain import file_terrain, ramp_along_path

            self._terrain = file_terrain(self.options) or (
                ramp_along_path(robot, self.options.slope_deg, backwards=True)
                if self.options.slope_deg is not None and self.walking else None)
        return self._terrain

    def commands(self, robot):
        """Walking: base backwards at the pull speed, the end-effector held at its place on the base.
        Stance: the body leans back by STANCE_BASE_SHIFT_M while the arm retracts STANCE_RETRACT_M
        relative to it (more arm retraction alone drives joint2 into its lower limit, where the OCP
        degenerates), so the end-effector moves back at the pull speed."""
        force = self.target_force(robot)
        ee = EeState(robot)
        offset0 = yaw_rotation(robot.q_nominal).T @ (nominal_ee_position(robot) - robot.q_nominal[:3])
        speed = self.options.pull_speed_m_s
        travel = self.STANCE_RETRACT_M + self.STANCE_BASE_SHIFT_M
        window = travel / max(speed, 1e-9)
        retract_end = self.MOVE_START_S + window

        def command(t_s, q, v):
            moving = t_s >= self.MOVE_START_S
            heading = yaw_rotation(q)
            offset = offset0.copy()
            base_velocity = np.zeros(3)
            ee_velocity_ref = np.zeros(3)
            if self.walking and moving:
                base_velocity[0] = -speed
                ee_velocity_ref = heading @ base_velocity
            elif not self.walking and moving:
                share = (min(t_s, retract_end) - self.MOVE_START_S) / window
                offset[0] -= self.STANCE_RETRACT_M * share
                if t_s < retract_end:
                    base_velocity[0] = -self.STANCE_BASE_SHIFT_M / window
                    ee_velocity_ref = heading @ np.array([-speed, 0.0, 0.0])
            if self.options.object_model:  # the MPC plans the hand's force and motion on the load's speed
                return Commands(base_velocity_m_s=base_velocity, object_command=self._object_command(robot, t_s))
            # hold the end-effector at its (retracting) place relative to the base, in the heading frame
            p_ref = q[:3] + heading @ offset
            return Commands(base_velocity_m_s=base_velocity,
                            ee_velocity_m_s=ee_velocity_feedback(ee_velocity_ref, p_ref, ee.position(q)),
                            ee_force_n=ramp(t_s, *self.RAMP_S) * force)

        return command

    def extra_metrics(self, robot, log):
        out = super().extra_metrics(robot, log)
        t, position = self._scene.recording.series(self.object_name, "object_position_m")
        _, tension = self._scene.recording.series(self.object_name, "tension_n")
        moved = float(np.linalg.norm(position[-1, :2] - position[0, :2]))
        t_end = t[-1]
        if self.walking:
            expected = self.options.pull_speed_m_s * max(t_end - self.MOVE_START_S, 0.0)
        else:
            expected = min(self.STANCE_RETRACT_M + self.STANCE_BASE_SHIFT_M,
                           self.options.pull_speed_m_s * max(t_end - self.MOVE_START_S, 0.0))
        late = t >= self.force_window_start_s
        out.update({
            "load_kg": self.options.load_kg,
            "load_friction_mu": self.options.load_friction_mu,
            "gait": self.gait,
            "target_tension_n": float(np.linalg.norm(self.target_force(robot))),
            "tension_mean_n": float(np.mean(tension[late])) if late.any() else None,
            "tension_max_n": float(np.max(tension)),
            "load_moved_m": moved,
            "load_expected_move_m": expected,
            "pulled": bool(not log.fell and expected > 0 and moved >= 0.5 * expected),
            "object_model": bool(self.options.object_model),
            **self._speed_metrics(),
        })
        return out

    def _speed_metrics(self) -> dict:
        """`load_speed_rmse_m_s`: the load's measured velocity along the pull (-x) against the pull speed, from
        SPEED_WINDOW_AFTER_MOVE_S after the move starts (walking gaits)."""
        t, state = self._scene.recording.series(self.object_name, "planar_state")
        use = t >= self.MOVE_START_S + self.SPEED_WINDOW_AFTER_MOVE_S
        if not self.walking or not use.any():
            return {"load_speed_rmse_m_s": None}
        speed = -state[use, 3]
        error = speed - self.options.pull_speed_m_s
        return {"load_speed_rmse_m_s": float(np.sqrt(np.mean(error**2))), "load_speed_mean_m_s": float(np.mean(speed)),
                "load_speed_window_start_s": self.MOVE_START_S + self.SPEED_WINDOW_AFTER_MOVE_S}

    def failure(self, metrics):
        if not metrics.get("interrupted") and not metrics.get("fell") and metrics.get("pulled") is False:
            return "the load was not pulled (it moved less than half the commanded way)"
        return super().failure(metrics)
