"""Named closed-loop scenarios: commands, disturbances and the metrics each one adds.

`stand`, `trot-in-place`, `trot-forward` (0.2 m/s), `walk-in-place` and `walk-forward` (the robot's
natural gait: trot on four feet, walk on two), `push` (lateral base velocity kick while
trotting in place, section VI-B1 / Fig. 4) and `arm-track` (trot forward while the end-effector
tracks a low/high reference, Fig. 3; position error becomes a velocity command by feedback);
the loco-manipulation tasks of section VI-C (`pull`, `push-box`, `wipe`, `compliant`) live in
`wbmpc.scenarios.manipulation`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.loop import Event
from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError, unknown_name
from wbmpc.gait import gaits_for, natural_gait
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.manipulation import Compliant, Pull, PushBox, Wipe
from wbmpc.scenarios.metrics import SETTLE_S, base_world_velocity, base_yaw, heading_rotation
from wbmpc.scenarios.terrain import Slope, Stairs, SteppingStones


class Stand(Scenario):
    def __init__(self, options: ScenarioOptions):
        super().__init__("stand", "stand still on all feet", "stand", 3.0, options=options)


class TrotInPlace(Scenario):
    def __init__(self, options: ScenarioOptions):
        super().__init__("trot-in-place", "trot without moving (base drift, section VI-B2)", "trot", 10.0, options=options)


class TrotForward(Scenario):
    def __init__(self, options: ScenarioOptions):
        super().__init__("trot-forward", "trot forward at the commanded speed", "trot", 6.0, options=options)

    def terrain(self, robot):
        """--terrain FILE, else the flat floor."""
        if not hasattr(self, "_file_terrain"):
            from wbmpc.scenarios.terrain import file_terrain

            self._file_terrain = file_terrain(self.options)
        return self._file_terrain

    def commands(self, robot):
        velocity = np.array([self.options.speed_m_s, 0.0, 0.0])
        terrain = self.terrain(robot)
        if terrain is not None and robot.arm_ee is not None:  # the hand carried over the terrain
            from wbmpc.scenarios.terrain import TerrainHand

            return TerrainHand(robot, terrain, self.start_pose(robot), self.options.speed_m_s,
                               self.default_duration_s).command(velocity)
        return lambda t, q, v: Commands(base_velocity_m_s=velocity)

    def extra_metrics(self, robot, log):
        """`base_vel_cycle_mean_rmse`: the planar base velocity averaged over each whole gait cycle after the
        start transient, against the command (RMS over the cycles): the mean speed a cycle at a time, the
        sway within a cycle averaged away. The per-tick figure is `base_vel_rmse_settled`."""
        from wbmpc.control.tuning import tuning_for
        from wbmpc.gait import make_gait

        period_s = make_gait(self.gait, len(robot.feet), tuning_for(robot).gait_period_s).period_s
        a = log.arrays(("t", "q", "v"))
        t = a["t"]
        velocity = base_world_velocity(a["q"], a["v"])[:, :2]
        command = heading_rotation(base_yaw(a["q"][0]))[:2, :2] @ np.array([self.options.speed_m_s, 0.0])
        start = t[0] + min(SETTLE_S, 0.5 * (t[-1] - t[0]))
        cycles = int((t[-1] - start) // period_s)
        means = [velocity[(t >= start + k * period_s) & (t < start + (k + 1) * period_s)].mean(axis=0)
                 for k in range(cycles)]
        rmse = float(np.sqrt(np.mean(np.sum((np.array(means) - command) ** 2, axis=1)))) if cycles else None
        settled = t >= start
        com = _com_forward_lateral_rmse(robot, a["q"][settled], a["v"][settled], command, base_yaw(a["q"][0]))
        return {"base_vel_cycle_mean_rmse": rmse, **_forward_lateral_rmse(velocity[settled], command, base_yaw(a["q"][0])),
                **com}


def _forward_lateral_rmse(velocity: np.ndarray, command: np.ndarray, yaw: float) -> dict:
    """`base_vel_rmse_settled` split along the start's heading (`_forward`: the speed error) and across it
    (`_lateral`: a biped's sideways sway from one stance foot to the other), per 500 Hz tick after the start
    transient; their squares add up to the planar figure's."""
    heading = heading_rotation(yaw)[:2, :2]
    error = (velocity - command) @ heading  # columns: along, across the start's heading
    if not len(error):
        return {"base_vel_rmse_settled_forward": None, "base_vel_rmse_settled_lateral": None}
    forward, lateral = np.sqrt(np.mean(error**2, axis=0))
    return {"base_vel_rmse_settled_forward": float(forward), "base_vel_rmse_settled_lateral": float(lateral)}


def _com_forward_lateral_rmse(robot: RobotModel, q: np.ndarray, v: np.ndarray, command: np.ndarray, yaw: float) -> dict:
    """`com_vel_rmse_settled` (`_forward`, `_lateral`): as `base_vel_rmse_settled` (and its split) for the
    whole body's centre of mass instead of the base frame, per 500 Hz tick after the start transient. A walking
    biped's CoM must sway over each stance sole; its pelvis can move steadily while the hips and trunk take up
    the sway, so the two figures differ."""
    if not len(q):
        return {"com_vel_rmse_settled": None, "com_vel_rmse_settled_forward": None, "com_vel_rmse_settled_lateral": None}
    data = robot.model.createData()
    velocity = np.empty((len(q), 2))
    for i in range(len(q)):
        pin.centerOfMass(robot.model, data, q[i], v[i])
        velocity[i] = data.vcom[0][:2]
    error = (velocity - command) @ heading_rotation(yaw)[:2, :2]
    forward, lateral = np.sqrt(np.mean(error**2, axis=0))
    return {"com_vel_rmse_settled": float(np.hypot(forward, lateral)), "com_vel_rmse_settled_forward": float(forward),
            "com_vel_rmse_settled_lateral": float(lateral)}


class WalkInPlace(Scenario):
    """Step in place in the robot's natural gait (trot on four feet, walk on two)."""

    def __init__(self, options: ScenarioOptions):
        super().__init__("walk-in-place", "step in place in the robot's gait (trot on four feet, walk on two)",
                         "trot", 10.0, options=options)


class WalkForward(TrotForward):
    """Move forward at the commanded speed in the robot's natural gait."""

    def __init__(self, options: ScenarioOptions):
        Scenario.__init__(self, "walk-forward", "walk forward at the commanded speed (trot on four feet, walk on two)",
                          "trot", 6.0, options=options)


class Push(Scenario):
    def __init__(self, options: ScenarioOptions):
        super().__init__("push", "lateral base velocity kick while trotting in place (Fig. 4)", "trot", 5.0, options=options)

    def events(self, robot):
        angle = np.deg2rad(self.options.push_direction_deg)
        speed = self.options.push_speed_m_s

        def kick(plant):
            q, _ = plant.state()
            rot = pin.Quaternion(q[3:7]).toRotationMatrix()
            heading = np.arctan2(rot[1, 0], rot[0, 0])
            plant.apply_base_velocity_kick(speed * np.array([np.cos(heading + angle), np.sin(heading + angle), 0.0]))

        return [Event(self.options.push_time_s, kick, name="push")]

    def extra_metrics(self, robot, log):
        a = log.arrays(("t", "tau"))
        after = a["t"] >= self.options.push_time_s
        return {
            "push_speed_m_s": self.options.push_speed_m_s,
            "push_time_s": self.options.push_time_s,
            "max_torque_ratio_after_push": float(np.max(np.abs(a["tau"][after]) / robot.tau_max)) if after.any() else None,
        }


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


class ArmTrack(Scenario):
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

    def _lifted(self, position: np.ndarray, velocity: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """On a terrain, the reference rises with the support under the base's path (`TerrainHand`)."""
        if self._terrain_hand is None:
            return position, velocity
        lifted, carried = self._terrain_hand.reference(t)
        return position + np.array([0.0, 0.0, lifted[2] - self._terrain_hand.start[2]]), \
            velocity + np.array([0.0, 0.0, carried[2]])

    def _reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self._lifted(*self._flat_reference(t), t)

    def _flat_reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        o = self.options
        start = self._start
        drift = np.array([o.speed_m_s * t, 0.0, 0.0])
        if o.arm_target_path == "behind-base":
            position, velocity = self._keyed(BEHIND_BASE_KEYS, t)
            return position + drift, velocity + np.array([o.speed_m_s, 0.0, 0.0])
        if o.arm_target_path == "around-obstacle":  # trotting in place: the post stands in the world
            return self._keyed(AROUND_KEYS, t)
        w = 2 * np.pi / o.arm_period_s
        position = start + drift + np.array([0.0, 0.0, o.arm_amplitude_m * np.sin(w * t)])
        velocity = np.array([o.speed_m_s, 0.0, o.arm_amplitude_m * w * np.cos(w * t)])
        return position, velocity

    @property
    def base_speed_m_s(self) -> float:
        return 0.0 if self.options.arm_target_path == "around-obstacle" else self.options.speed_m_s

    def _keyed(self, keys, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Piecewise linear between `keys` ((time s, point relative to the base's start or None: the nominal
        hand position); held after the last key), without the forward drift."""
        times = np.array([key for key, _ in keys])
        points = np.array([self._start if p is None else self._base_start + np.asarray(p) for _, p in keys])
        k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
        if t >= times[-1]:
            return points[-1].copy(), np.zeros(3)
        share = (t - times[k]) / (times[k + 1] - times[k])
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
        return lambda t: self._reference(t)[0]

    def reachable(self, robot, t: np.ndarray) -> np.ndarray:
        """Samples whose reference the hand can reach: within the arm's reach of its first joint and outside
        the base and the legs (their capsules at the nominal pose) and the scene's obstacles by the hand
        capsule's radius plus 3 cm."""
        from wbmpc.robots.collision_model import arm_workspace

        self.ee_reference(robot)
        base_start = self._base_start
        points = np.array([self._reference(float(tk))[0] for tk in t])
        drift = np.outer(t, [self.base_speed_m_s, 0.0, 0.0])
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

        def command(t, q, v):
            pin.framesForwardKinematics(robot.model, data, q)
            position, velocity = self._reference(t)
            ee_velocity = velocity + gain * (position - data.oMf[fid].translation)
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


SCENARIOS = {cls(ScenarioOptions()).name: cls for cls in (Stand, TrotInPlace, TrotForward, WalkInPlace, WalkForward,
                                                                 Push, ArmTrack, Pull, PushBox, Wipe, Compliant, Stairs,
                                                                 Slope, SteppingStones)}
TROT_SCENARIOS = ("trot-in-place", "trot-forward")  # trot by name: refused on robots without a trot


def make_scenario(name: str, robot: RobotModel | None, options: ScenarioOptions | None = None) -> Scenario:
    """The scenario `name` for `robot` (its gait fitted to the robot's feet, checked against it); with no
    robot, the scenario as declared (configuration tests)."""
    if name not in SCENARIOS:
        raise ConfigError(unknown_name("scenario", name, SCENARIOS))
    scenario = SCENARIOS[name](options or ScenarioOptions())
    if robot is None:
        return scenario
    gaits = gaits_for(len(robot.feet))
    if scenario.gait not in gaits:
        if name in TROT_SCENARIOS or (options is not None and options.gait is not None):
            raise ConfigError(f"scenario '{name}' runs the {scenario.gait} gait, which {robot.name} "
                              f"({len(robot.feet)} feet) does not have; its gaits: {', '.join(gaits)}"
                              + (" (walk-in-place / walk-forward walk it)" if "walk" in gaits else ""))
        scenario.gait = natural_gait(len(robot.feet))  # tasks that step: the robot's own gait
    if scenario.needs_arm and robot.arm_ee is None:
        raise ConfigError(f"scenario '{name}' needs a robot with an arm (--arm-ee); {robot.name} has none")
    scenario.check(robot)
    return scenario
