"""`arm-track` (Fig. 3): trot forward while the end-effector tracks a low/high reference; the position error becomes a
velocity command by feedback. Also `--target-path behind-base` (through the trunk's rear: self-collisions) and
`around-obstacle` (through a post in front of the robot). The feedback has integral action (`--arm-integral`): the
MPC plans with its model, and an arm heavier than it sags by a steady offset under proportional feedback alone.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.feedback import EeIntegral

# --target-path behind-base: (time s, hand position relative to the base at the start, in its heading frame;
# None: the nominal hand position). Behind the trunk's rear face (-0.32 m on b1_z1) at its mid height: the
# straight line there crosses the trunk's rear top, and the point itself lies beyond the Z1's reach from the
# nominal base pose (the whole body reaches it: the base leans back)
BEHIND_BASE_TARGET_M = (-0.45, 0.0, -0.05)
BEHIND_BASE_KEYS = ((0.0, None), (1.0, None), (5.0, BEHIND_BASE_TARGET_M), (6.5, BEHIND_BASE_TARGET_M), (8.0, None))
# --target-path around-obstacle: front left to front right of the robot through a post (a box from the floor to
# 0.47 m above the base, its axis 3 cm beyond the path's line so that the near side is the way around). On b1_z1
# the hand stays clear of the post's capsule (radius 7 cm) by its own (6.6 cm) plus the 3 cm margin 0.17 m
# from the post's axis: the way around passes 0.58 m ahead of the base, within the Z1's reach
AROUND_LEFT_M, AROUND_RIGHT_M = (0.72, 0.30, 0.30), (0.72, -0.30, 0.30)
AROUND_KEYS = ((0.0, None), (1.0, None), (2.5, AROUND_LEFT_M), (3.0, AROUND_LEFT_M), (6.5, AROUND_RIGHT_M),
               (7.0, AROUND_RIGHT_M), (8.0, None))
AROUND_POST_CENTRE_M = (0.75, 0.0)  # x, y relative to the base at the start; it stands on the floor
AROUND_POST_HALF_M = (0.05, 0.05)  # half sizes along x, y
AROUND_POST_TOP_M = 0.47  # above the base's start height
AROUND_ARM_POSTURE_SCALE = 0.05
# the integral's anti-windup (`--arm-integral`): its velocity term at most this, integrated while the error is within
# INTEGRAL_WITHIN_M (the behind-base and around-obstacle paths leave the collision-free reach: P feedback alone there)
INTEGRAL_MAX_SPEED_M_S = 0.1
INTEGRAL_WITHIN_M = 0.02


class ArmTrack(Scenario):
    sweeps_ee = True  # its paths bring the hand near the body (collision avoidance on with an arm)

    def __init__(self, options: ScenarioOptions):
        super().__init__("arm-track", "trot forward while the end-effector tracks a low/high reference (Fig. 3)",
                         "trot", 8.0, needs_arm=True, options=options)
        self._start: np.ndarray | None = None
        self._base_start: np.ndarray | None = None
        self._scene = None
        self._terrain_hand = None  # on a terrain: the lift of the reference (scenarios/terrain.TerrainHand)

    def terrain(self, robot):
        """--terrain FILE, or a ramp up along the path (--slope-deg), else the flat floor."""
        if not hasattr(self, "_terrain"):
            from wbmpc.scenarios.terrain import file_terrain, ramp_along_path

            self._terrain = file_terrain(self.options) or (
                ramp_along_path(robot, self.options.slope_deg, backwards=self.base_speed_m_s < 0)
                if self.options.slope_deg is not None and self.base_speed_m_s != 0 else None)
        return self._terrain

    def _reference(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The path's reference, raised on a terrain with the support under the base's path (`TerrainHand`)."""
        position, velocity = self._flat_reference(t_s)
        if self._terrain_hand is None:
            return position, velocity
        lifted, carried = self._terrain_hand.reference(t_s)
        return position + np.array([0.0, 0.0, lifted[2] - self._terrain_hand.start[2]]), \
            velocity + np.array([0.0, 0.0, carried[2]])

    def _flat_reference(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        o = self.options
        start = self._start
        drift = np.array([o.speed_m_s * t_s, 0.0, 0.0])
        if o.arm_target_path == "behind-base":
            position, velocity = self._keyed(BEHIND_BASE_KEYS, t_s)
            return position + drift, velocity + np.array([o.speed_m_s, 0.0, 0.0])
        if o.arm_target_path == "around-obstacle":  # trotting in place: the post stands in the world
            return self._keyed(AROUND_KEYS, t_s)
        w = 2 * np.pi / o.arm_period_s
        position = start + drift + np.array([0.0, 0.0, o.arm_amplitude_m * np.sin(w * t_s)])
        velocity = np.array([o.speed_m_s, 0.0, o.arm_amplitude_m * w * np.cos(w * t_s)])
        return position, velocity

    @property
    def base_speed_m_s(self) -> float:
        return 0.0 if self.options.arm_target_path == "around-obstacle" else self.options.speed_m_s

    def _keyed(self, keys, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Piecewise linear between `keys` ((time s, point relative to the base's start or None: the nominal
        hand position); held after the last key), without the forward drift."""
        times = np.array([key for key, _ in keys])
        points = np.array([self._start if p is None else self._base_start + np.asarray(p) for _, p in keys])
        k = int(np.clip(np.searchsorted(times, t_s, side="right") - 1, 0, len(times) - 2))
        if t_s >= times[-1]:
            return points[-1].copy(), np.zeros(3)
        share = (t_s - times[k]) / (times[k + 1] - times[k])
        velocity = (points[k + 1] - points[k]) / (times[k + 1] - times[k])
        return points[k] + share * (points[k + 1] - points[k]), velocity

    def ee_reference(self, robot):
        if self._start is None:
            start_q = self.start_pose(robot)
            self._start = robot.frame_trajectories(start_q, [robot.arm_ee])[robot.arm_ee][0]
            self._base_start = np.asarray(start_q[:3], dtype=float)
            terrain = self.terrain(robot)
            if terrain is not None:
                from wbmpc.scenarios.terrain import TerrainHand

                self._terrain_hand = TerrainHand(robot, terrain, start_q, self.base_speed_m_s, self.default_duration_s)
        return lambda t_s: self._reference(t_s)[0]

    def reachable(self, robot, t_s: np.ndarray) -> np.ndarray:
        """Samples whose reference the hand can reach: within the arm's reach of its first joint and outside
        the base and the legs (their capsules at the nominal pose) and the scene's obstacles by the hand
        capsule's radius plus 3 cm."""
        from wbmpc.robots.collision_model import arm_workspace

        self.ee_reference(robot)
        base_start = self._base_start
        points = np.array([self._reference(float(tk))[0] for tk in t_s])
        drift = np.outer(t_s, [self.base_speed_m_s, 0.0, 0.0])
        workspace = arm_workspace(robot)
        out = workspace.reaches(points - drift - base_start + robot.q_nominal[:3])
        for box in self.obstacles(robot):  # exact distance of the point to the box
            outside = np.maximum(np.abs(points - np.asarray(box.centre_m)) - np.asarray(box.half_size_m), 0.0)
            out &= np.linalg.norm(outside, axis=1) >= workspace.clearance_m
        return out

    def post(self, robot):
        """The post of --target-path around-obstacle (`wbmpc.sim.objects.FixedBox`), or None."""
        from wbmpc.sim.objects import FixedBox

        if self.options.arm_target_path != "around-obstacle":
            return None
        self.ee_reference(robot)
        x, y, z = (float(c) for c in self._base_start)
        top = z + AROUND_POST_TOP_M
        return FixedBox((x + AROUND_POST_CENTRE_M[0], y + AROUND_POST_CENTRE_M[1], top / 2),
                        (*AROUND_POST_HALF_M, top / 2), name="post")

    def cost_weights(self, weights):
        """around-obstacle: the arm's posture weight AROUND_ARM_POSTURE_SCALE times the robot's, so the arm reaches
        and the base stays (at the robot's weight the plan walked the base 0.3 m forward and 0.33 m left to bring
        the hand to the path's left end, and a front hip met the post)."""
        if self.options.arm_target_path != "around-obstacle":
            return weights
        from dataclasses import replace

        return replace(weights, arm_joint_position=weights.arm_joint_position * AROUND_ARM_POSTURE_SCALE)

    def obstacles(self, robot):
        post = self.post(robot)  # at the hand's height, 0.4 m ahead of the front feet trotting in place: kept off the arm
        return (post.obstacle(keep_off=("arm",)),) if post is not None else ()

    def scene(self, robot):
        from wbmpc.sim.objects import Scene

        post = self.post(robot)
        self._scene = Scene(robot, [post]) if post is not None else None
        return self._scene

    def commands(self, robot):
        self.ee_reference(robot)
        data = robot.model.createData()
        fid = robot.frame_id(robot.arm_ee)
        base = np.array([self.base_speed_m_s, 0.0, 0.0])
        gain = self.options.arm_feedback_gain_1_s
        integral = EeIntegral(self.options.arm_integral_gain_1_s2, max_speed_m_s=INTEGRAL_MAX_SPEED_M_S,
                              within_m=INTEGRAL_WITHIN_M)

        def command(t_s, q, v):
            pin.framesForwardKinematics(robot.model, data, q)
            position, velocity = self._reference(t_s)
            error = position - data.oMf[fid].translation
            ee_velocity = velocity + gain * error + integral.update(t_s, error)
            speed = np.linalg.norm(ee_velocity)
            if speed > 0.9:  # stay inside the MPC's command limit
                ee_velocity *= 0.9 / speed
            return Commands(base_velocity_m_s=base, ee_velocity_m_s=ee_velocity)

        return command

    def extra_metrics(self, robot, log):
        a = log.arrays(("t", "q"))
        ee = robot.frame_trajectories(a["q"], [robot.arm_ee])[robot.arm_ee]
        error, _ = self.ee_tracking_error(robot, a["t"], ee)
        distance = np.linalg.norm(error, axis=1)
        out = {"ee_pos_rmse_m": float(np.sqrt(np.mean(distance**2))), "ee_pos_max_err_m": float(distance.max()),
               "target_path": self.options.arm_target_path}
        if self.options.arm_target_path != "sine":  # the path leaves the arm's collision-free reach
            reachable = self.reachable(robot, a["t"])
            out["ee_pos_rmse_reachable_m"] = float(np.sqrt(np.mean(distance[reachable] ** 2))) if reachable.any() else None
            out["ee_reachable_share"] = float(np.mean(reachable))
        if self._scene is not None and self._scene.recording.t:  # the robot touching the post in MuJoCo
            from wbmpc.sim.objects import contact_count

            count = contact_count(*self._scene.recording.series("post", "touching"))
            out["obstacle_contacts"], out["obstacle_contact_time_s"] = count["contacts"], count["time_s"]
        return out
