"""The locomotion scenarios: `stand`, `trot-in-place`, `trot-forward` (0.2 m/s), `walk-in-place` and `walk-forward`
(the robot's natural gait: trot on four feet, walk on two), and `push` (a lateral base velocity kick while trotting in
place, section VI-B1 / Fig. 4).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands
from wbmpc.control.loop import Event
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.metrics import SETTLE_S, base_world_velocity, base_yaw, heading_rotation


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
        from wbmpc.scenarios.terrain import TerrainHand, carries_hand

        velocity = np.array([self.options.speed_m_s, 0.0, 0.0])
        terrain = self.terrain(robot)
        if terrain is not None and carries_hand(robot):  # the hand carried over the terrain
            return TerrainHand(robot, terrain, self.start_pose(robot), self.options.speed_m_s,
                               self.default_duration_s).command(velocity)
        return lambda t_s, q, v: Commands(base_velocity_m_s=velocity)

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
        com = com_forward_lateral_rmse(robot, a["q"][settled], a["v"][settled], command, base_yaw(a["q"][0]))
        return {"base_vel_cycle_mean_rmse": rmse, **forward_lateral_rmse(velocity[settled], command, base_yaw(a["q"][0])),
                **com}


def forward_lateral_rmse(velocity: np.ndarray, command: np.ndarray, yaw: float) -> dict:
    """`base_vel_rmse_settled` split along the start's heading (`_forward`: the speed error) and across it
    (`_lateral`: a biped's sideways sway from one stance foot to the other), per 500 Hz tick after the start
    transient; their squares add up to the planar figure's."""
    heading = heading_rotation(yaw)[:2, :2]
    error = (velocity - command) @ heading  # columns: along, across the start's heading
    if not len(error):
        return {"base_vel_rmse_settled_forward": None, "base_vel_rmse_settled_lateral": None}
    forward, lateral = np.sqrt(np.mean(error**2, axis=0))
    return {"base_vel_rmse_settled_forward": float(forward), "base_vel_rmse_settled_lateral": float(lateral)}


def com_forward_lateral_rmse(robot: RobotModel, q: np.ndarray, v: np.ndarray, command: np.ndarray, yaw: float) -> dict:
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
