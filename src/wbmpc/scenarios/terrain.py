"""Off the flat floor: `stairs`, `slope` and `stepping-stones`, walked at the commanded speed in the robot's gait.

Each course runs along +x and begins `COURSE_CLEARANCE_M` ahead of the robot's front feet (the foot's own extent
beyond); the robot walks across it and on until its rear feet are past it (the default duration: that distance
at --speed, plus a second to start). A robot with an arm carries its hand across: the hand's reference is its
nominal place moving with the commanded base and rising with the terrain's support under the base's path
(`TerrainCourse.hand_reference`), tracked by velocity feedback (`ee_pos_rmse_m`; `ee_pos_rmse_course_m` counts
the time the base is over the course). Metrics beyond the common ones: the terrain contacts of
`sim/terrain_contacts.py` (steps climbed, slips, edge contacts, shin / knee contacts) added by the runner,
and the course's progress here (`course_completed`, `progress_m`).

`TerrainHand` is the hand reference of any scenario on a terrain (trot-forward / walk-forward with --terrain,
arm-track and pull on a slope); a biped's hands swing free (`carries_hand`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.mpc import Commands
from wbmpc.errors import ConfigError
from wbmpc.robots import RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.terrain import Terrain, course_end_x, load_terrain, slope, stairs, stepping_stones

COURSE_CLEARANCE_M = 0.2  # from the front feet's toes to the course's first riser, ramp or gap
START_S = 1.0  # time to start walking, added to the default duration
DEFAULT_SLOPE_DEG = 15.0
HAND_FEEDBACK_GAIN_1_S = 4.0  # as arm-track's
MAX_HAND_SPEED_M_S = 0.9
LIFT_SMOOTHING_M = 0.15  # the hand's lift follows the support height averaged over this length of the path


def stair_size(robot: RobotModel, rise_m: float | None, tread_m: float | None) -> tuple[float, float]:
    """(rise, tread) of the stairs: the options, else the robot's (scaled by its standing height on four feet)."""
    height = float(robot.q_nominal[2])
    biped = len(robot.feet) == 2
    rise = rise_m if rise_m is not None else (0.10 if biped else round(0.23 * height, 2))
    tread = tread_m if tread_m is not None else (0.30 if biped else max(0.25, round(0.57 * height, 2)))
    return rise, tread


def feet_extent(robot: RobotModel) -> tuple[float, float]:
    """(front toes x, rear heels x) of the nominal pose: the feet's contact points and their own extent."""
    positions = robot.frame_trajectories(robot.q_nominal, [robot.contact_frame(f) for f in robot.feet])
    xs = np.array([positions[robot.contact_frame(f)][0, 0] for f in robot.feet])
    extent = max([robot.foot_radius_m or 0.0] + [s.half_length_m + abs(s.centre_m[0]) for s in robot.soles.values()])
    return float(xs.max() + extent), float(xs.min() - extent)


def carries_hand(robot: RobotModel) -> bool:
    """Whether a walk over a terrain carries the hand along a reference: a legged base with an arm, not a biped."""
    return robot.arm_ee is not None and len(robot.feet) >= 3


class TerrainHand:
    """A hand's world reference over a terrain: its nominal place moving with the commanded base velocity (world x,
    the start's heading) and lifted with the terrain's support plane under the base's commanded path, taken where
    the hand is (c0 + c1 dx: the plane's height dx ahead of the base, smoothed over LIFT_SMOOTHING_M). The MPC
    pitches the base with that plane, so the hand keeps its nominal place relative to the body; lifted by the
    height under the base alone, a hand 0.6 m ahead of b1_z1's base had to come 20 cm down relative to its pitched
    body on the 12/30 cm stairs and the Z1's elbow ran into its limit (8 cm error)."""

    def __init__(self, robot: RobotModel, terrain: Terrain, start_q: np.ndarray, speed_m_s: float, duration_s: float):
        from wbmpc.control.terrain_references import ride_height, ride_limit_m, support_footprint

        self.robot, self.speed = robot, float(speed_m_s)
        self.start = robot.frame_trajectories(start_q, [robot.arm_ee])[robot.arm_ee][0]
        self.base_x0 = float(start_q[0])
        support = support_footprint(robot, terrain)
        travel = abs(self.speed) * (duration_s + 5.0) + 1.0
        self._x = self.base_x0 + np.sign(self.speed or 1.0) * np.arange(0.0, travel, 0.01)
        ahead = float(self.start[0] - start_q[0])  # the hand's place ahead of the base (the start's heading is +x)
        plane = support.plane(np.column_stack([self._x, np.full_like(self._x, start_q[1])]), np.zeros_like(self._x))
        lift = ride_height(plane, ride_limit_m(robot)) + plane[:, 1] * ahead
        width = max(int(LIFT_SMOOTHING_M / 0.01), 1)
        padded = np.pad(lift, (width, width), mode="edge")
        smooth = np.convolve(padded, np.ones(2 * width + 1) / (2 * width + 1), mode="same")[width:-width]
        self._lift = smooth - smooth[0]
        if self.speed < 0:
            self._x, self._lift = self._x[::-1], self._lift[::-1]

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) of the hand at time t."""
        x = self.base_x0 + self.speed * t
        lift = float(np.interp(x, self._x, self._lift))
        slope_ = float(np.interp(x + 0.005, self._x, self._lift) - np.interp(x - 0.005, self._x, self._lift)) / 0.01
        return self.start + np.array([self.speed * t, 0.0, lift]), np.array([self.speed, 0.0, slope_ * self.speed])

    def command(self, base_velocity: np.ndarray):
        """Commands(t, q, v): the base velocity and the hand's velocity by feedback on its reference."""
        data = self.robot.model.createData()
        fid = self.robot.frame_id(self.robot.arm_ee)

        def command(t, q, v):
            pin.framesForwardKinematics(self.robot.model, data, q)
            position, velocity = self.reference(t)
            hand = velocity + HAND_FEEDBACK_GAIN_1_S * (position - data.oMf[fid].translation)
            speed = np.linalg.norm(hand)
            if speed > MAX_HAND_SPEED_M_S:
                hand *= MAX_HAND_SPEED_M_S / speed
            return Commands(base_velocity_m_s=base_velocity, ee_velocity_m_s=hand)

        return command


class TerrainCourse(Scenario):
    """Walk across a course built for the robot (`course`), at --speed, in the robot's gait."""

    def __init__(self, name: str, description: str, options: ScenarioOptions):
        Scenario.__init__(self, name, description, "trot", 30.0, options=options)
        self._robot: RobotModel | None = None
        self._terrain: Terrain | None = None
        self._hand: TerrainHand | None = None

    def course(self, robot: RobotModel, start_x_m: float) -> Terrain:
        raise NotImplementedError

    def course_start_x(self, terrain: Terrain) -> float:
        """Where the course begins along x (its first riser, ramp or gap)."""
        return float(terrain.bounds()[0])

    def course_end_x(self, terrain: Terrain) -> float:
        """Where the course ends along x: a run crosses it when the rear feet are past this."""
        return course_end_x(terrain)

    def check(self, robot: RobotModel) -> None:
        """Build the course for `robot` (and the default duration: across it at --speed)."""
        if abs(self.options.speed_m_s) < 0.02:
            raise ConfigError.for_field("speed_m_s", f"must be at least 0.02 m/s to cross the {self.name} course, "
                                        f"got {self.options.speed_m_s:g}")
        self.terrain(robot)

    def terrain(self, robot: RobotModel) -> Terrain:
        if self._terrain is None or self._robot is not robot:
            front, rear = feet_extent(robot)
            self._robot = robot
            self._terrain = self.course(robot, front + COURSE_CLEARANCE_M)
            self._hand = None
            distance = self.course_end_x(self._terrain) - rear + COURSE_CLEARANCE_M
            self.default_duration_s = round(START_S + distance / abs(self.options.speed_m_s), 1)
        return self._terrain

    def hand(self, robot: RobotModel) -> TerrainHand | None:
        """The hand's reference of a legged base carrying an arm; None without an arm and on two feet (a humanoid's
        hands swing free as it walks: `ReferenceConfig.free_ee_without_command`)."""
        if not carries_hand(robot):
            return None
        if self._hand is None:
            self._hand = TerrainHand(robot, self.terrain(robot), self.start_pose(robot), self.options.speed_m_s,
                                     self.default_duration_s)
        return self._hand

    def commands(self, robot):
        velocity = np.array([self.options.speed_m_s, 0.0, 0.0])
        hand = self.hand(robot)
        return hand.command(velocity) if hand is not None else (lambda t, q, v: Commands(base_velocity_m_s=velocity))

    def ee_reference(self, robot):
        hand = self.hand(robot)
        return None if hand is None else (lambda t: hand.reference(t)[0])

    def extra_metrics(self, robot, log):
        from wbmpc.scenarios.locomotion import TrotForward

        out = TrotForward.extra_metrics(self, robot, log)  # the velocity tracking of walking forward
        a = log.arrays(("t", "q"))
        terrain = self.terrain(robot)
        _, rear = feet_extent(robot)
        start_x, end_x = self.course_start_x(terrain), self.course_end_x(terrain)
        base_x = a["q"][:, 0]
        start_q = self.start_pose(robot)
        out.update({"progress_m": float(base_x[-1] - start_q[0]),
                    # every foot past the course's end (the rear heels beyond its last edge)
                    "course_completed": bool(not log.fell and base_x[-1] + (rear - start_q[0]) > end_x),
                    "course_length_m": float(end_x - start_x)})
        hand = self.hand(robot)
        if hand is not None:
            ee = robot.frame_trajectories(a["q"], [robot.arm_ee])[robot.arm_ee]
            error = np.linalg.norm(ee - np.array([hand.reference(float(tk))[0] for tk in a["t"]]), axis=1)
            over = (base_x > start_x) & (base_x < end_x)
            out.update({"ee_pos_rmse_m": float(np.sqrt(np.mean(error**2))), "ee_pos_max_err_m": float(error.max()),
                        "ee_pos_rmse_course_m": float(np.sqrt(np.mean(error[over] ** 2))) if over.any() else None})
        return out

    def failure(self, metrics: dict) -> str | None:
        fell = super().failure(metrics)
        if fell:
            return fell
        if metrics.get("interrupted") or metrics.get("requested_duration_s", 0) < self.default_duration_s - 1e-6:
            return None  # a shorter run than the crossing is not asked to complete it
        if not metrics.get("course_completed"):
            return f"the robot did not cross the {self.name} course ({metrics.get('progress_m', 0.0):.2f} m walked)"
        return None


class Stairs(TerrainCourse):
    def __init__(self, options: ScenarioOptions):
        super().__init__("stairs", "climb a staircase (--steps, --step-rise, --step-tread; up, down or up-down)",
                         options)

    def course(self, robot, start_x_m):
        rise, tread = stair_size(robot, self.options.step_rise_m, self.options.step_tread_m)
        front, rear = feet_extent(robot)
        if self.options.stairs_direction == "down":  # the robot starts on the landing, which ends at start_x_m
            landing = start_x_m - (rear - 2 * COURSE_CLEARANCE_M)
        else:  # room for the whole robot at the top (up: where it ends, its rear feet past the last riser)
            landing = max(1.2 * (front - rear), 2 * tread)
            if self.options.stairs_direction == "up":
                landing = max(landing, front - rear + 3 * COURSE_CLEARANCE_M)
        return stairs(self.options.steps, rise, tread, start_x_m, landing_m=landing,
                      direction=self.options.stairs_direction)

    def course_end_x(self, terrain):
        """Up: the last riser (the run ends with the robot on the landing, not walking off its far end)."""
        if self.options.stairs_direction == "up":
            return float(next(p for p in terrain.pieces if p.name == "landing").corners()[:, 0].min())
        return course_end_x(terrain)


class Slope(TerrainCourse):
    def __init__(self, options: ScenarioOptions):
        super().__init__("slope", "walk up a ramp (--slope-deg), across a plateau and down", options)

    def course(self, robot, start_x_m):
        angle = self.options.slope_deg if self.options.slope_deg is not None else DEFAULT_SLOPE_DEG
        front, rear = feet_extent(robot)
        return slope(angle, start_x_m, run_m=max(1.5, 2 * (front - rear)), plateau_m=max(1.0, 1.2 * (front - rear)))


class SteppingStones(TerrainCourse):
    def __init__(self, options: ScenarioOptions):
        super().__init__("stepping-stones", "walk across square stones with gaps between them (--gap, --stone-size)",
                         options)

    def course(self, robot, start_x_m):
        front, rear = feet_extent(robot)
        # the end platform holds the whole robot with room ahead once its rear feet are off the stones
        return stepping_stones(self.options.gap_m, start_x_m, stone_m=self.options.stone_size_m,
                               platform_m=max(1.5, front - rear + 1.0))

    def course_start_x(self, terrain):
        return float(next(p for p in terrain.pieces if p.name == "start").corners()[:, 0].max())

    def course_end_x(self, terrain):
        return float(next(p for p in terrain.pieces if p.name == "end").corners()[:, 0].min())


def file_terrain(options: ScenarioOptions) -> Terrain | None:
    """The terrain of --terrain FILE, or None."""
    return load_terrain(options.terrain_file) if options.terrain_file else None


def ramp_along_path(robot: RobotModel, angle_deg: float, backwards: bool = False) -> Terrain:
    """A ramp rising at `angle_deg` from just beyond the robot's feet along its path (+x, or -x walking backwards),
    long enough for any default run."""
    from wbmpc.terrain import Ramp

    front, rear = feet_extent(robot)
    run = 3.0
    rise = run * float(np.tan(np.deg2rad(angle_deg)))
    if backwards:
        x0 = rear - COURSE_CLEARANCE_M
        return Terrain((Ramp((x0, 0.0, 0.0), (x0 - run, 0.0, rise), 3.0, name="slope"),), name=f"slope {angle_deg:g} deg")
    x0 = front + COURSE_CLEARANCE_M
    return Terrain((Ramp((x0, 0.0, 0.0), (x0 + run, 0.0, rise), 3.0, name="slope"),), name=f"slope {angle_deg:g} deg")


def contact_monitor(robot: RobotModel, plant, terrain: Terrain | None):
    """The terrain's contact metrics in MuJoCo (`sim/terrain_contacts.py`), counted from the plant's steps; None
    on the flat floor."""
    if terrain is None:
        return None
    from wbmpc.sim.terrain_contacts import TerrainContactMonitor

    monitor = TerrainContactMonitor(plant.model, robot, terrain)
    plant.add_step_hook(monitor)
    return monitor


def check_terrain(robot: RobotModel, scenario: Scenario, plant: str) -> None:
    """A scenario on a terrain needs MuJoCo (the pinocchio plant's ground is a plane) and a start pose on the
    terrain, not inside it (`sim.terrain_geoms.check_start_pose`); checked before anything is built."""
    terrain = scenario.terrain(robot)
    if terrain is None:
        return
    if plant != "mujoco":
        raise ConfigError(f"scenario '{scenario.name}' walks on a terrain ({terrain.name}), which only the MuJoCo plant "
                          "builds: use --plant mujoco")
    from wbmpc.sim.terrain_geoms import check_start_pose

    check_start_pose(robot, terrain, scenario.start_pose(robot))
