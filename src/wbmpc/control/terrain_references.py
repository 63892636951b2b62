"""What the MPC takes from a known terrain each step: swing splines, footholds, cone normals, base height and pitch.

The OCP is the same on any ground (`ocp/problem.py`): the terrain enters through per-step data only, so one built
(and compiled) solver serves a flat floor and stairs alike:

- footholds: each swing's landing point is Raibert's (`foot_placement.SwingPlacement`: under the hip at touch-down,
  half a stance of commanded motion ahead, capture-point feedback), moved to the nearest safe cell of the terrain
  (`terrain.FootholdMap`: a keep-out band on both sides of every edge) and, where the shin (`LegShins`: the leg
  as two links from the hip at its target to the landing point) would touch the terrain (a knee-backward leg
  coming down a step, its shin over the nose above), to the nearest safe point along the heading where it clears. The swing feet's horizontal velocity rows
  carry them there (the 6 s (1 - s) profile of `SwingPlacement`, rescaled from the measured foot every step);
- eq. (6)'s swing spline between the terrain's heights (`gait.swing_between`): from the lift-off height up to an
  apex the swing height above the highest ground between lift-off and landing, down to the landing point's
  height. Where the ground ahead rises above the lift-off height (a riser), the apex comes early enough for the
  foot to be half the swing height over it when it gets there; where the foot comes down past a step's nose with
  its shin trailing (a knee-backward leg going forward), late enough for the shin to pass over the nose (the
  share of APEX_SHARES nearest 1/2 that does); else midway, as on a flat floor. A swing in progress is re-planned from the measured foot height (the error is taken out linearly
  until touch-down), so that the plan lands on the terrain, not where the integrated velocities would;
- stance feet stay where they stand (eq. 6's zero velocity), at the terrain's height by construction;
- friction and wrench cones about the terrain's normal under each foot, per node (the OCP's "contact_normal");
- base targets: height above the support plane of the terrain under the feet (`terrain.SupportFootprint`) and, on
  three or more feet, its pitch (the plane's slope along the heading), with the leg joints' posture targets of
  the pitched base with the feet still under the hips (a table of inverse-kinematics solutions over pitch, built
  once). A biped keeps its pelvis upright.

Everything is vectorised over nodes; the loops run over feet and the (one or two) swings of each in the horizon.
A swing's landing point and heights are kept from step to step while what they depend on moves less than a cell of
the foothold raster (`REPLAN_M`); the splines of all swings are evaluated at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.control.foot_placement import CAPTURE_GAIN, PLACEMENT_END_SHARE, SwingPlacement, swings_in_horizon
from wbmpc.control.leg_shins import LegShins, shin_radius_m
from wbmpc.gait import Gait, SwingProfile, swing_between
from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.terrain import FootholdConfig, FootholdMap, Terrain
from wbmpc.terrain.support import SupportFootprint

# a swing over a riser or down past a step's nose reaches its apex at the first of these shares of it that clears
APEX_SHARES = np.array([0.5, 0.45, 0.55, 0.4, 0.6, 0.35, 0.65, 0.3, 0.7])
RISE_M = 0.02  # ground this much above the lift-off point counts as something to step over
MAX_HEIGHT_CORRECTION_M_S = 1.0  # at most this vertical velocity re-plans a swing in progress onto the terrain
KEEP_OUT_MARGIN_M = 0.05  # keep-out band: the foot's own extent (sphere radius, half a sole) plus this
SOLE_MARGIN_M = 0.02  # ... plus this for a flat foot (g1: 11 cm, leaving 8 cm of a 30 cm tread)
SUPPORT_REACH = 0.3  # support plane samples reach this share of the leg length ahead of and behind each foot
PITCH_TABLE_RAD = np.deg2rad(np.arange(-40.0, 40.1, 2.0))  # base pitches of the leg posture table
IK_ITERATIONS = 30
SUPPORT_RAMP_SAMPLES = 9  # a biped's support weights averaged at this many times over two double supports
# a swing's landing point and heights are planned again when what they depend on (Raibert's point, the lift-off point,
# the heading as a move of the foot's extent, the base's place at touch-down and its height) moved by more than this
# since they were planned: a cell of the foothold raster (the landing stays on a safe cell). Planned on every step,
# they took 3.6 ms of thread CPU of b1_z1's 9.6 ms MPC step on the stairs (flat trot-forward: 5.3 ms in the same
# sitting), the cause of 7 % late plans in real time. (Half a cell: Raibert's point moves that much with the
# capture point's feedback on a trot's velocity ripple, and 1.6 of the ~5 swings in the horizon were planned again.)
# A swing to come is not planned again for the base's measured place: that guess moves with the velocity's ripple.
REPLAN_M = 0.01
RIDE_GAIN = 2.0  # the base rides this many RMS of the terrain about its support plane higher (`ride_height`)
RIDE_LEAN = 0.8  # ... at most until the shins lean this much (`ride_limit_m`)
HIP_SAG_M = 0.03  # the hip may come this much lower than the measured base's height predicts (`_hips`)
SHIN_CLEARANCE_M = 0.04  # room kept between a shin's surface and the terrain (its axis: plus `shin_radius_m`)
SHIN_FROM = 0.2  # the shin's points checked: from this share of the way from the foot to the knee (below: the foot)
SHIN_POINTS = 9
# landing points tried along the heading when the shin would touch (at most a quarter of b1_z1's leg: 30 cm made
# strides of 55 cm that the shin did not clear in the end)
SHIN_SHIFTS_M = np.r_[np.arange(-0.15, 0.0, 0.01), np.arange(0.01, 0.151, 0.01)]


def default_footholds(robot: RobotModel) -> FootholdConfig:
    """The keep-out band of a robot: its feet's extent from their contact point (a sphere's radius, half a sole's
    length) plus KEEP_OUT_MARGIN_M (a point foot rolls on its sphere) or SOLE_MARGIN_M (a sole lies flat)."""
    extent = foot_extent_m(robot)
    return FootholdConfig(keep_out_m=extent + (SOLE_MARGIN_M if robot.soles else KEEP_OUT_MARGIN_M))


def foot_extent_m(robot: RobotModel) -> float:
    """How far a foot reaches from its contact point: a sphere's radius, half a sole's length (or width)."""
    return max([robot.foot_radius_m or 0.0] + [max(s.half_length_m, s.half_width_m) for s in robot.soles.values()])


@dataclass
class TerrainStep:
    """One step's terrain data: swing v_z and xy velocity references (bounds) and cone normals (parameters)."""

    swing_vz_m_s: np.ndarray  # (nodes, n_feet)
    swing_vxy_m_s: np.ndarray  # (nodes, n_feet, 2), NaN: free
    contact_normal: np.ndarray  # (3 n_feet, N): the OCP parameter
    footholds_m: np.ndarray  # (nodes, n_feet, 3) where each foot stands (or will land) at each node
    apex_m: np.ndarray  # (nodes, n_feet) planned swing heights (NaN in stance), for plots and tests
    # (nodes, 2) world xy: a biped's base target moved with the footholds of its support (`support_shift`); None: not
    support_shift_m: np.ndarray | None = None


class TerrainReferences:
    """The terrain's per-step data for the MPC of `robot` (see the module docstring)."""

    def __init__(self, robot: RobotModel, terrain: Terrain, swing: SwingProfile,
                 footholds: FootholdConfig | None = None, support_lead_s: float = 0.0):
        self.robot, self.terrain, self.swing = robot, terrain, swing
        self.support_lead_s = support_lead_s  # a biped's base leans over the feet that stand this much later
        self.follows_footholds = len(robot.feet) == 2  # (`support_shift`)
        self.footholds = FootholdMap(terrain, footholds or default_footholds(robot))
        self.raster = self.footholds.raster
        self._placement = SwingPlacement(robot)
        self._contact_height = np.array([robot.contact_height_m(f) for f in robot.feet])
        self.shins = LegShins(robot)
        self._shin_margin_m = SHIN_CLEARANCE_M + shin_radius_m(robot)
        self._base_height_m = float(robot.q_nominal[2])
        self.ride_max_m = ride_limit_m(robot)
        self._foot_extent = foot_extent_m(robot)
        self.support = support_footprint(robot, terrain)
        self.follows_pitch = len(robot.feet) >= 3
        self._pitch_offsets = _pitch_posture_table(robot, PITCH_TABLE_RAD) if self.follows_pitch else None
        share = np.linspace(0.0, 1.0, 201)
        self._progress_of_share = (3 * share**2 - 2 * share**3, share)  # xy path share -> swing progress
        self.reset()

    def reset(self) -> None:
        self._stance_xy: np.ndarray | None = None  # where each foot last stood (a swing's lift-off point)
        self._committed: dict[int, tuple[float, np.ndarray, float]] = {}  # foot -> (lift-off t, landing, its height)
        # (foot, lift-off t, in the air) -> (the inputs it was planned from, landing point, swing heights)
        self._moved_m = np.zeros((len(self.robot.feet), 2))  # each foot's landing less its Raibert point
        self._moved_since: dict[int, tuple[float, np.ndarray]] = {}  # ... taken at (the swing's lift-off t, landing)
        self._plans: dict[tuple[int, float, bool], tuple[np.ndarray, np.ndarray, tuple]] = {}

    # ------------------------------------------------------------------ base
    def shape_base_targets(self, targets: np.ndarray, yaws: np.ndarray) -> None:
        """Base height over the support plane, pitch along it (3+ feet) and the leg postures of that pitch, in
        place on the configuration targets (nodes, nq) whose base xy and yaw are set."""
        plane = self.support.plane(targets[:, :2], yaws)
        targets[:, 2] += ride_height(plane, self.ride_max_m)
        if not self.follows_pitch:
            return
        pitch = np.clip(-np.arctan(plane[:, 1]), PITCH_TABLE_RAD[0], PITCH_TABLE_RAD[-1])
        targets[:, 3:7] = _yaw_pitch_quaternions(yaws, pitch)
        offsets = self._pitch_offsets
        position = np.interp(pitch, PITCH_TABLE_RAD, np.arange(len(PITCH_TABLE_RAD)))
        low = np.minimum(np.floor(position).astype(int), len(PITCH_TABLE_RAD) - 2)
        share = (position - low)[:, None]
        targets[:, 7:] += (1 - share) * offsets[low] + share * offsets[low + 1]

    # ------------------------------------------------------------------ feet
    def step(self, gait: Gait, t: float, node_times_s: np.ndarray, q: np.ndarray, v_world: np.ndarray,
             command_world: np.ndarray, yaw: float, feet_m: np.ndarray) -> TerrainStep:
        """Swing references, footholds and cone normals of the horizon at t + node_times_s from the measured base
        (q, world velocity), the commanded world velocity, the heading and the measured feet (n_feet, 3)."""
        times = t + np.asarray(node_times_s, dtype=float)
        n, n_feet = len(times), len(self.robot.feet)
        feet_m = np.asarray(feet_m, dtype=float)
        stance_now = gait.contact(np.array([t]))[0] > 0
        if self._stance_xy is None:
            self._stance_xy = feet_m[:, :2].copy()
        self._stance_xy[stance_now] = feet_m[stance_now, :2]
        vz = np.zeros((n, n_feet))
        vxy = np.full((n, n_feet, 2), np.nan)
        apex_plan = np.full((n, n_feet), np.nan)
        stand = np.repeat(feet_m[None, :, :2], n, axis=0)  # where each foot stands per node
        moved = np.repeat(self._moved_m[None], n, axis=0)  # ... less Raibert's point there
        points = list(feet_m[:, :2])  # ... the few points it takes: the feet and the swings' landings
        which = np.tile(np.arange(n_feet), (n, 1))  # ... the index of each node's and foot's among them
        duty = gait.duty_factor
        if duty < 1:
            swing_s, stance_s = gait.swing_duration_s, duty * gait.period_s
            placement = self._placement
            heading = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
            command = np.asarray(command_world, dtype=float)[:2]
            step = self._raibert_step(command, np.asarray(v_world, dtype=float)[:2], stance_s)
            segments = []  # (foot, nodes, progress, heights, progress now, measured height in the air or NaN)
            for foot, nodes, s, lift_off_t, touch_down_t, s_now in swings_in_horizon(gait, t, times):
                in_progress = lift_off_t <= t
                lift_off_xy = self._stance_xy[foot] if in_progress else stand[nodes[0] - 1, foot] if nodes[0] > 0 \
                    else feet_m[foot, :2]
                base_xy = q[:2] + (touch_down_t - t) * command
                raw = base_xy + heading @ placement.foot_offsets_m[foot] + step
                s0 = s_now if in_progress else 0.0
                target, heights = self._plan(foot, lift_off_t, s0, in_progress, raw, lift_off_xy, base_xy,
                                             q[:2] + (touch_down_t - t) * np.asarray(v_world)[:2], q, yaw, heading)
                start_xy = feet_m[foot, :2] if in_progress else lift_off_xy
                # the 6 s (1 - s) profile over what is left of the path (at least PLACEMENT_END_SHARE of it, so that
                # the rescaling stays bounded); unlike a biped's step on the floor the end is not left free: a foot
                # free to go on after 90 % of its way slid into the keep-out band of a riser
                left = max(1 - 3 * s0**2 + 2 * s0**3, PLACEMENT_END_SHARE)
                vxy[nodes, foot] = np.outer(6 * s * (1 - s) / (swing_s * left), target - start_xy)
                stand[nodes[0]:, foot] = target
                moved[nodes[0]:, foot] = self._moved(foot, target - raw, target, lift_off_t) if in_progress \
                    else target - raw
                which[nodes[0]:, foot] = len(points)
                points.append(target)
                segments.append((foot, nodes, s, heights, s0, feet_m[foot, 2] if in_progress else np.nan))
            if segments:  # eq. (6)'s splines of all the swings at once
                apex_plan, vz = self._swing_plans(segments, swing_s, apex_plan, vz)
            self._plans = {key: plan for key, plan in self._plans.items() if key[1] + swing_s >= t}  # swings to come
        heights, normals = (values[which] for values in self.terrain.height_normal(np.array(points)))  # exact
        footholds = np.concatenate([stand, (heights + self._contact_height)[..., None]], axis=-1)
        N = n - 1
        return TerrainStep(vz, vxy, normals[:N].reshape(N, 3 * n_feet).T.copy(), footholds, apex_plan,
                           self.support_shift(gait, times, moved) if self.follows_footholds else None)

    def _moved(self, foot: int, moved_m: np.ndarray, target: np.ndarray, lift_off_t: float) -> np.ndarray:
        """How far a swing in the air lands from Raibert's point, as at its first step in the air (Raibert's point
        follows the base: a base moving ahead over a landing moved forward took the move back) unless its landing
        moved by more than the keep-out band since (another tread)."""
        since = self._moved_since.get(foot)
        if since is None or abs(since[0] - lift_off_t) > 1e-3 or \
                np.linalg.norm(since[1] - target) > self.footholds.config.keep_out_m:
            self._moved_m[foot], self._moved_since[foot] = moved_m, (lift_off_t, target)
        return self._moved_m[foot]

    def support_shift(self, gait: Gait, times: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """(nodes, 2) world: the mean move from Raibert's points of the footholds of each node's support, each foot
        weighted by its contact averaged over the next two `support_lead_s` (a ramp over a double support centred
        a double support later, as `support_sway` leans). The footholds move off step edges by up to half a tread;
        a biped's base kept on its commanded path left g1's CoM 1-6 cm behind the heel of a foot moved 10 cm up
        onto a step when the other foot lifted, and it fell; moved at once (not ramped) its target jumped 11 cm
        ahead of the base, the solves failed and it fell too."""
        ramp = np.linspace(0.0, 2.0, SUPPORT_RAMP_SAMPLES)
        support = np.mean([gait.contact(times + a * self.support_lead_s) for a in ramp], axis=0)
        support[support.sum(axis=1) == 0] = 1.0
        return np.einsum("nf,nfk->nk", support, moved) / support.sum(axis=1, keepdims=True)

    def _raibert_step(self, command_xy: np.ndarray, velocity_xy: np.ndarray, stance_s: float) -> np.ndarray:
        """Raibert's landing point ahead of the hip (half a stance of commanded motion, capture-point feedback),
        at most the placement's reach."""
        placement = self._placement
        step = command_xy * stance_s / 2 + CAPTURE_GAIN * (velocity_xy - command_xy) * np.sqrt(
            placement.height_m / GRAVITY_M_S2)
        reach = np.linalg.norm(step)
        return step * placement.reach_m / reach if reach > placement.reach_m else step

    def _plan(self, foot: int, lift_off_t: float, s0: float, in_progress: bool, raw: np.ndarray,
              lift_off_xy: np.ndarray, base_xy: np.ndarray, measured_xy: np.ndarray, q: np.ndarray, yaw: float,
              heading: np.ndarray) -> tuple[np.ndarray, tuple]:
        """(landing point, swing heights) of a swing: kept from an earlier step while what they depend on moved
        less than REPLAN_M (a swing to come: its hips from the measured velocity are a guess, planned again at
        lift-off), else planned again."""
        inputs = np.r_[raw, lift_off_xy, yaw * self._foot_extent, measured_xy, q[2]]
        key = (foot, round(lift_off_t, 4), in_progress)
        plan = self._plans.get(key)
        if plan is None or np.any(np.abs(inputs - plan[0])[:None if in_progress else 5] > REPLAN_M):
            hips = self._hips(foot, q, base_xy, measured_xy, yaw)
            target = self._landing(foot, raw, in_progress, lift_off_t, heading, hips, s0)
            plan = self._plans[key] = (inputs, target, self._swing_heights(foot, lift_off_xy, target, heading, hips))
        return plan[1], plan[2]

    def _swing_plans(self, segments: list, swing_s: float, apex_plan: np.ndarray, vz: np.ndarray):
        """Heights and vertical velocities of eq. (6)'s splines between (lift-off, apex, touch-down heights, apex
        share) at each swing's progress, written into the (nodes, feet) arrays; a swing in progress (its measured
        height, at progress s0; NaN: to come) planned from the measured height, its error taken out linearly until
        touch-down. All swings (foot, nodes, progress, heights, progress now, measured height) in one pass."""
        lengths = [len(seg[1]) for seg in segments]
        s = np.concatenate([seg[2] for seg in segments])
        heights = np.array([seg[3] for seg in segments])  # (swings, 4): lift-off, apex, touch-down, apex share
        s0, measured = np.array([seg[4] for seg in segments]), np.array([seg[5] for seg in segments])
        lift_off, touch_down = self.swing.liftoff_velocity_m_s, self.swing.touchdown_velocity_m_s
        each = np.repeat(heights, lengths, axis=0)
        height, velocity = swing_between(s, swing_s, *each.T, lift_off, touch_down)
        flying = np.isfinite(measured)
        error, correction = np.zeros(len(segments)), np.zeros(len(segments))
        if flying.any():  # swings in progress: planned from the measured height (its error out until touch-down)
            planned_now, _ = swing_between(s0[flying], swing_s, *heights[flying].T, lift_off, touch_down)
            error[flying] = measured[flying] - planned_now
            correction[flying] = np.clip(error[flying] / np.maximum((1 - s0[flying]) * swing_s, 1e-3),
                                         -MAX_HEIGHT_CORRECTION_M_S, MAX_HEIGHT_CORRECTION_M_S)
        height = height + np.repeat(error, lengths) * (1 - s) / np.repeat(np.maximum(1 - s0, 1e-3), lengths)
        velocity = velocity - np.repeat(correction, lengths)
        rows = np.concatenate([seg[1] for seg in segments])
        columns = np.repeat([seg[0] for seg in segments], lengths)
        apex_plan[rows, columns], vz[rows, columns] = height, velocity
        return apex_plan, vz

    def _shin_clearance(self, foot: int, hips: np.ndarray, heading: np.ndarray, feet_xy: np.ndarray) -> np.ndarray:
        """For landing points feet_xy (n, 2): the smallest height (m) of the shin (knee -> foot, from the planar leg
        with its hip at each of `hips` (k, 3)) over terrain beneath it that rises above the foot's own ground, less
        the shin's radius and SHIN_CLEARANCE_M (at most that margin: nothing under the shin rises); negative: it
        would touch."""
        hips = np.atleast_2d(hips)[:, None, :]  # (k, 1, 3), against the n points
        direction = heading[:, 0]
        ground = self.raster.height(feet_xy)
        along = (feet_xy[None] - hips[..., :2]) @ direction  # (k, n): the feet along the heading from each hip
        feet = np.stack([along, np.broadcast_to(ground + self._contact_height[foot], along.shape)], axis=-1)
        knees = self.shins.knees(foot, np.stack([np.zeros_like(along), np.broadcast_to(hips[..., 2], along.shape)],
                                                axis=-1), feet)
        share = np.linspace(SHIN_FROM, 1.0, SHIN_POINTS)[:, None, None, None]
        points = feet[None] + share * (knees - feet)[None]  # (points, k, n, 2): along the heading from the hip, up
        xy = feet_xy + (points[..., 0] - along)[..., None] * direction  # the points' ground, beside the foot's line
        under = self.raster.height(xy)
        above = np.where(under > ground + RISE_M, points[..., 1] - under, np.inf)  # only over ground above the foot's
        return np.minimum(above.min(axis=(0, 1)) - self._shin_margin_m, self._shin_margin_m)

    def _clear_of_shin(self, foot: int, target_xy: np.ndarray, hips: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """`target_xy`, or if the shin would touch the terrain there (a knee-backward leg coming down a step, its shin
        over the nose above), the safe landing point nearest it along the heading whose shin clears the terrain."""
        if not self.shins.legged[foot] or self._shin_clearance(foot, hips, heading, target_xy[None])[0] >= 0:
            return target_xy
        candidates = self.footholds.adapt(target_xy + np.outer(SHIN_SHIFTS_M, heading[:, 0]))
        clear = self._shin_clearance(foot, hips, heading, candidates) >= 0
        clear &= self.footholds.is_safe(candidates)
        if not clear.any():
            return target_xy
        distance = np.linalg.norm(candidates - target_xy, axis=1)
        return candidates[np.flatnonzero(clear)[np.argmin(distance[clear])]]

    def _hips(self, foot: int, q: np.ndarray, base_xy: np.ndarray, measured_xy: np.ndarray, yaw: float) -> np.ndarray:
        """(2, 3) world positions of a leg's hip at a touch-down: the base over base_xy (commanded motion) at its height
        target, and the base over measured_xy (its measured velocity) at its measured height carried by the change of
        the support's height, less HIP_SAG_M, each pitched as the support there (a base that lags its height target lowers the hip: the shin must clear the terrain from both).
        b1_z1 coming down 12 cm steps: the base ran 2-5 cm under its target, and sagged 3 cm more while a rear foot
        swung: predicted from the measured height alone, its rear shins still touched the steps' noses."""
        plane = self.support.plane(np.stack([q[:2], base_xy, measured_xy]), np.full(3, yaw))
        ride = ride_height(plane, self.ride_max_m)
        hips = []
        for k, z in ((1, ride[1] + self._base_height_m), (2, q[2] + ride[2] - ride[0] - HIP_SAG_M)):
            pitch = -np.arctan(plane[k, 1]) if self.follows_pitch else 0.0
            c, s, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
            rotation = np.array([[c * cp, -s, c * sp], [s * cp, c, s * sp], [-sp, 0.0, cp]])
            hips.append(np.r_[base_xy if k == 1 else measured_xy, z]
                        + rotation @ self.shins.hip_offsets_m[foot])
        return np.stack(hips)

    def _landing(self, foot: int, raw_xy: np.ndarray, in_progress: bool, lift_off_t: float,
                 heading: np.ndarray, hips: np.ndarray, progress: float = 0.0) -> np.ndarray:
        """The safe landing point of a swing (`FootholdMap.adapt` of Raibert's target). A swing in progress keeps the
        ground level it was given at its first step in the air: the target still follows the capture point while it
        stays on that level (within EDGE's height), else the committed point is kept. Without this a raw target
        near a riser flipped between the step's top and its foot from one MPC step to the next. `progress`: of the
        swing in progress."""
        target = self._clear_of_shin(foot, self.footholds.adapt(raw_xy), hips, heading)
        committed = self._committed.get(foot)
        if not in_progress:
            return target
        if committed is None or abs(committed[0] - lift_off_t) > 1e-3:  # a new swing
            self._committed[foot] = (lift_off_t, target, float(self.raster.height(target)))
            return target
        _, kept, level = committed
        same_level = abs(float(self.raster.height(target)) - level) <= self.footholds.config.edge_height_m
        # ... unless, in the first half of the swing, the kept point's shin would now touch (the base came lower or
        # further than foreseen at lift-off)
        touching = progress < 0.5 and self._shin_clearance(foot, hips, heading, kept[None])[0] < 0
        if same_level or touching:
            self._committed[foot] = (lift_off_t, target, float(self.raster.height(target)))
            return target
        return kept

    def _landing_lean(self, foot: int, target_xy: np.ndarray, hips: np.ndarray, heading: np.ndarray) -> float:
        """The shin's lean at the landing point (horizontal along the heading per vertical metre, knee from foot), the
        larger of those from `hips` (k, 3)."""
        if not self.shins.legged[foot]:
            return 0.0
        leans = []
        for hip_xyz in np.atleast_2d(hips):
            foot_sz = np.array([[(target_xy - hip_xyz[:2]) @ heading[:, 0],
                                 float(self.raster.height(target_xy)) + self._contact_height[foot]]])
            knee = self.shins.knees(foot, np.array([0.0, hip_xyz[2]]), foot_sz)[0]
            leans.append(float((knee[0] - foot_sz[0, 0]) / max(knee[1] - foot_sz[0, 1], 1e-3)))
        return max(leans, key=abs)

    def _swing_heights(self, foot: int, lift_off_xy: np.ndarray, target_xy: np.ndarray,
                       heading: np.ndarray | None = None, hips: np.ndarray | None = None):
        """(lift-off, apex, touch-down heights of the contact frame, apex share) of a swing between two points."""
        contact = self._contact_height[foot]
        ground = self.raster.height(np.stack([lift_off_xy, target_xy]))
        profile = self.raster.path_heights(lift_off_xy, target_xy, self._foot_extent)  # under the foot's centre path
        h0, h1 = ground[0] + contact, ground[1] + contact
        apex = max(float(profile.max()), float(ground.max())) + contact + self.swing.apex_height_m
        # lowest heights of the contact frame along the path: half the swing height over each rising edge (a riser,
        # a box's side) where the foot gets there; and, where the shin trails the foot (a knee-backward leg going
        # forward), its axis clear of the ground behind by its radius and SHIN_CLEARANCE_M (down past a step's nose)
        n = len(profile)
        needed = np.full(n, -np.inf)
        edges = np.flatnonzero(np.diff(profile) > RISE_M) + 1
        if profile[0] > ground[0] + RISE_M:
            edges = np.r_[0, edges]
        needed[edges] = profile[edges] + contact + 0.5 * self.swing.apex_height_m
        length = float(np.linalg.norm(target_xy - lift_off_xy))
        lean = self._landing_lean(foot, target_xy, hips, heading) if hips is not None else 0.0
        if heading is not None and abs(lean) > 1e-3 and length > 1e-6:
            motion = (target_xy - lift_off_xy) / length
            if np.sign(lean) * float(heading[:, 0] @ motion) < 0:  # the shin trails the foot
                # the foot at sample i, its shin over the ground behind (samples j < i) that rises above the foot's own
                along = np.linspace(0.0, length, n)
                behind = (np.arange(n)[None, :] < np.arange(n)[:, None]) & (profile[None, :] > profile[:, None] + RISE_M)
                shin = np.where(behind, profile[None, :] - (along[:, None] - along[None, :]) / abs(lean), -np.inf)
                needed = np.maximum(needed, shin.max(axis=1) + self._shin_margin_m / abs(lean) + contact)
        checked = np.flatnonzero(np.isfinite(needed))
        if not checked.size:
            return h0, apex, h1, 0.5
        apex = max(apex, float(needed.max()) + 0.25 * self.swing.apex_height_m)
        # the apex share nearest eq. (6)'s 1/2 whose spline clears them where the foot's xy path (3 s^2 - 2 s^3 of
        # the way) gets there
        progress = np.interp(checked / max(n - 1, 1), *self._progress_of_share)
        height, _ = swing_between(np.broadcast_to(progress, (len(APEX_SHARES), len(progress))), 1.0, h0, apex, h1,
                                  APEX_SHARES[:, None])
        clears = np.flatnonzero(np.all(height >= needed[checked], axis=1))
        return h0, apex, h1, float(APEX_SHARES[clears[0]]) if clears.size else 0.5


def ride_height(plane: np.ndarray, ride_max_m: float) -> np.ndarray:
    """The base target's height over the nominal one: the support plane's height under the base, raised on rough
    ground by RIDE_GAIN times the terrain's RMS about the plane, at most `ride_max_m` (`ride_limit_m`)."""
    return plane[..., 0] + np.minimum(RIDE_GAIN * plane[..., 3], ride_max_m)


def ride_limit_m(robot: RobotModel) -> float:
    """How much higher than nominal the base rides on rough ground: until the shins lean at most RIDE_LEAN (horizontal
    per vertical, knee from foot) in the leg's straighter pose, 0 where they do already. Straighter legs keep the
    knees of knee-backward legs over step edges: b1_z1's nominal shin leans 1.03 (45 deg, its knee 25 cm behind the
    foot), so a foot coming down a 12 cm step had to land 16 cm past the nose for the shin to clear it, on a 30 cm
    tread, and the shins touched the noses; 5.9 cm higher they lean 0.8 (none touched). go2's lean 0.77: no raise
    (raised by 5 cm, its legs near their reach, its plans failed on the stairs)."""
    shins = LegShins(robot)
    raises = []
    for foot, (thigh, shin), legged, hip in zip(robot.feet, shins.lengths_m, shins.legged, shins.hip_offsets_m):
        if not legged or abs(thigh - shin) > 0.2 * max(thigh, shin):
            continue
        length = 0.5 * (thigh + shin)
        reach = float(robot.q_nominal[2]) + hip[2] - robot.contact_height_m(foot)  # hip -> contact point, nominal
        straighter = 2 * length / np.sqrt(1 + RIDE_LEAN**2)  # hip -> foot distance at which the shin leans RIDE_LEAN
        raises.append(max(0.0, straighter - reach))
    return float(np.mean(raises)) if raises else 0.0


def support_footprint(robot: RobotModel, terrain: Terrain) -> SupportFootprint:
    """The terrain's support plane under `robot` (its feet's nominal places, SUPPORT_REACH leg lengths either way)."""
    return SupportFootprint(terrain, SwingPlacement(robot).foot_offsets_m, SUPPORT_REACH * float(robot.q_nominal[2]))


def _yaw_pitch_quaternions(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """(n, 4) xyzw quaternions of R = Rz(yaw) Ry(pitch)."""
    cz, sz = np.cos(yaw / 2), np.sin(yaw / 2)
    cy, sy = np.cos(pitch / 2), np.sin(pitch / 2)
    return np.column_stack([-sz * sy, cz * sy, sz * cy, cz * cy])


def _pitch_posture_table(robot: RobotModel, pitches_rad: np.ndarray) -> np.ndarray:
    """(len(pitches), nq - 7) leg joint offsets from the nominal pose that keep each foot at its nominal horizontal
    place under a base pitched by each angle, on a ground of that slope (inverse kinematics, base fixed)."""
    model, data = robot.model, robot.model.createData()
    frames = [robot.frame_id(robot.contact_frame(foot)) for foot in robot.feet]
    q0 = robot.q_nominal.copy()
    q0[:2] = 0.0
    q0[3:7] = (0.0, 0.0, 0.0, 1.0)
    pin.framesForwardKinematics(model, data, q0)
    nominal = np.array([data.oMf[f].translation.copy() for f in frames])
    q_column = {model.joints[j].idx_v - 6: model.joints[j].idx_q - 7 for j in range(2, model.njoints)
                if model.joints[j].nq == 1}
    pin.computeJointJacobians(model, data, q0)
    legs = []
    for frame in frames:
        jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
        columns = [c for c in np.flatnonzero(np.any(np.abs(jacobian) > 1e-9, axis=0))
                   if robot.leg_joint_mask[c] and c in q_column]
        legs.append(np.array(columns, dtype=int))
    table = np.zeros((len(pitches_rad), robot.nq - 7))
    for k, pitch in enumerate(pitches_rad):
        q = q0.copy()
        q[3:7] = _yaw_pitch_quaternions(np.array([0.0]), np.array([pitch]))[0]
        slope = -np.tan(pitch)
        target = nominal.copy()
        target[:, 2] += slope * nominal[:, 0]  # the ground of that slope through the point under the base
        for _ in range(IK_ITERATIONS):
            pin.framesForwardKinematics(model, data, q)
            error = target - np.array([data.oMf[f].translation for f in frames])
            if np.max(np.abs(error)) < 1e-7:
                break
            pin.computeJointJacobians(model, data, q)
            for frame, columns, e in zip(frames, legs, error):
                jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + columns]
                q[7 + np.array([q_column[c] for c in columns], dtype=int)] += np.linalg.lstsq(jacobian, e, rcond=None)[0]
        table[k] = q[7:] - q0[7:]
    return table - table[np.argmin(np.abs(pitches_rad))]
