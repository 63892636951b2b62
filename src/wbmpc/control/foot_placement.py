"""Leg joint references consistent with the feet's motion while the base moves (a Raibert-like placement).

The posture rows of eq. (3) pull the leg joints to the nominal pose at every node. On a trot at speed v that
reference contradicts the feet: a stance foot is fixed in the world, so relative to its hip it runs from
v T_st / 2 ahead to v T_st / 2 behind (T_st the stance duration); a swing foot comes back forward. Pulled to
the nominal pose, a swing foot lands under its hip and the whole stance is behind it: the base leads its
support (go2 at 0.24 m/s: by 9 cm), the load moves onto the front foot of each diagonal, whose line then
passes beside the CoM (by the lead times the diagonal's width over its length), and the trunk sways sideways
at the gait frequency (0.17 m/s RMS on go2; 0.01 trotting in place).

`StanceReference` gives per node the foot offset (in the heading frame) that the gait and the commanded base
velocity imply, Raibert's neutral point v T_st / 2 ahead at touch-down,

    stance, fraction u of it done:  d = v_hip T_st (1/2 - u)
    swing, progress s:              d = v_hip T_st (s - 1/2)

with v_hip = v + omega x r_hip, turned into leg joint offsets through the inverse of each leg's Jacobian
(first order: a few cm). They are taken around the centred pose: the nominal pose with its feet moved
horizontally (inverse kinematics, base and foot heights fixed) until the CoM is over the centre of the feet,
where a trot's diagonals cross; a nominal pose with its CoM off that centre (anymal_b_kinova: 8.5 cm ahead,
a1: 3.7 cm behind) puts each diagonal beside the CoM even in place. The legs' posture weight decides how
closely the plan follows these targets (`control/tuning.py`, `LEG_POSTURE`).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from wbmpc.gait import Gait
from wbmpc.robots import RobotModel

CENTRING_ITERATIONS = 4  # CoM -> feet -> CoM: the legs' own mass moves with the feet (converged to < 1 mm)
IK_ITERATIONS = 20


class StanceReference:
    """Leg joint offsets from the nominal pose per MPC node (see the module docstring)."""

    def __init__(self, robot: RobotModel):
        model = robot.model
        self._data = data = model.createData()
        self._model, self._robot = model, robot
        q = robot.q_nominal.copy()
        q[3:7] = (0.0, 0.0, 0.0, 1.0)  # the base frame is the heading frame
        # q[7:] coordinate of each one-coordinate joint's velocity column (continuous joints have two)
        q_column = {model.joints[j].idx_v - 6: model.joints[j].idx_q - 7 for j in range(2, model.njoints)
                    if model.joints[j].nq == 1}
        self._frames = [robot.frame_id(foot) for foot in robot.feet]
        pin.computeJointJacobians(model, data, q)
        self._velocity_columns = []  # per foot: its leg's joints (velocity columns after the base's 6)
        for frame in self._frames:
            jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
            columns = np.flatnonzero(np.any(np.abs(jacobian) > 1e-9, axis=0))
            self._velocity_columns.append(np.array([c for c in columns if robot.leg_joint_mask[c] and c in q_column],
                                                   dtype=int))
        self._columns = [np.array([q_column[c] for c in columns], dtype=int) for columns in self._velocity_columns]
        # the pose with the CoM over the centre of the feet (where a trot's diagonals cross), by inverse kinematics
        nominal_feet = self._feet(q)
        centred = q.copy()
        for _ in range(CENTRING_ITERATIONS):
            shift = pin.centerOfMass(model, data, centred)[:2] - nominal_feet[:, :2].mean(axis=0)
            centred = self._inverse_kinematics(centred, nominal_feet + np.r_[shift, 0.0])
        self.centring_m = shift
        self._centred_offset = centred[7:] - q[7:]
        self._tiled: np.ndarray | None = None  # the centred offset on every node of the last horizon
        pin.computeJointJacobians(model, data, centred)
        pin.updateFramePlacements(model, data)
        base = data.oMi[1].translation
        self._inverse = []  # per foot: (n_leg, 2) horizontal foot displacement -> joint offsets (centred pose)
        self._hip_m = []  # per foot: horizontal position relative to the base (for the yaw rate)
        for frame, columns in zip(self._frames, self._velocity_columns):
            jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + columns]
            # the foot moves in 3D with its leg's joints; hold its height (z = 0) while it moves horizontally
            self._inverse.append(np.linalg.pinv(jacobian)[:, :2])
            self._hip_m.append(data.oMf[frame].translation[:2] - base[:2])
        self._n_coordinates = model.nq - 7
        # the same, stacked for all feet at once (`joint_offsets`, every MPC step): foot i's horizontal displacement
        # -> its leg's joint offsets, and the direction a yaw rate moves its hip
        self._displacement_to_joints = np.zeros((len(self._frames), 2, self._n_coordinates))
        for i, (columns, inverse) in enumerate(zip(self._columns, self._inverse)):
            self._displacement_to_joints[i][:, columns] = inverse.T
        self._hip_turn = np.array([[-hip[1], hip[0]] for hip in self._hip_m]).reshape(-1, 2)

    def _feet(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self._model, self._data, q)
        return np.array([self._data.oMf[frame].translation.copy() for frame in self._frames])

    def _inverse_kinematics(self, q: np.ndarray, feet_m: np.ndarray) -> np.ndarray:
        """q with each leg's joints moved so that its foot reaches feet_m (base fixed; Gauss-Newton)."""
        q = q.copy()
        for _ in range(IK_ITERATIONS):
            error = feet_m - self._feet(q)
            if np.max(np.abs(error)) < 1e-6:
                break
            pin.computeJointJacobians(self._model, self._data, q)
            for frame, columns, coordinates, e in zip(self._frames, self._velocity_columns, self._columns, error):
                jacobian = pin.getFrameJacobian(self._model, self._data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + columns]
                q[7 + coordinates] += np.linalg.lstsq(jacobian, e, rcond=None)[0]
        return q

    def joint_offsets(self, gait: Gait, times_s: np.ndarray, velocity_m_s: np.ndarray,
                      yaw_rate_rad_s: float) -> np.ndarray:
        """(len(times), nq - 7) leg joint offsets from the nominal pose at these absolute times, for a base
        velocity (x, y in the heading frame) and yaw rate: the centred pose plus the feet's motion."""
        times_s = np.asarray(times_s, dtype=float)
        if self._tiled is None or len(self._tiled) != len(times_s):  # (np.tile every MPC step: ~4 us of Python)
            self._tiled = np.tile(self._centred_offset, (len(times_s), 1))
        out = self._tiled.copy()
        duty = gait.duty_factor
        if duty >= 1:
            return np.zeros_like(out)
        if not np.any(velocity_m_s[:2]) and yaw_rate_rad_s == 0.0:
            return out
        stance_s = duty * gait.period_s
        phase = gait.phase(times_s)  # (n, feet)
        swing = phase >= duty
        lever = np.where(swing, (phase - duty) / (1 - duty) - 0.5, 0.5 - phase / duty)  # (n, feet)
        v_hip = np.asarray(velocity_m_s[:2], dtype=float) + yaw_rate_rad_s * self._hip_turn  # (feet, 2)
        per_foot = np.einsum("fk,fkc->fc", v_hip, self._displacement_to_joints)  # joint offsets per unit lever
        return out + (lever * stance_s) @ per_foot


CAPTURE_GAIN = 1.0  # capture-point feedback: the foot lands (v - v_cmd) sqrt(h / g) further along the error
PLACEMENT_END_SHARE = 0.1  # the last share of a swing's path profile: its xy velocity rows are left free
MAX_STEP_PER_LEG = 0.5  # landing target at most this many leg lengths from the foot's nominal place under the hip


class SwingPlacement:
    """Horizontal velocity references of swing feet that carry each one to a landing point (a biped's step), and
    yaw rates that turn a flat foot's sole to its landing heading.

    A biped's posture cost is light (`control/biped.py`), so nothing in the OCP makes a swing foot step ahead:
    walking forward, g1's plans kept the swing foot near where it lifted off and leant the base over the
    toes of the stance foot (CoM 9 cm ahead of both soles at touch-down, ankles at their torque limit).
    The landing point of each swing is Raibert's with capture-point feedback,

        p_td = p_base + (t_td - t) v_cmd + R(psi_td) r_foot + v_hip T_st / 2 + k (v - v_cmd) sqrt(h / g),
        psi_td = psi + (t_td - t) omega_cmd,   v_hip = v_cmd + omega_cmd x R(psi_td) r_foot,

    p_base the measured base, psi its heading, r_foot the foot's place under its hip in the nominal pose (heading
    frame), T_st the stance duration, h the nominal base height; within MAX_STEP_PER_LEG leg lengths of
    p_base + (t_td - t) v_cmd + R(psi_td) r_foot. The foot's path to it follows the profile 6 s (1 - s) over swing
    progress s (zero velocity at lift-off and touch-down), rescaled every MPC step from the measured foot
    over the swing left, so the reference corrects itself; the last PLACEMENT_END_SHARE of the profile is
    left free (the rescaling would divide by almost nothing).

    A flat sole's yaw rate is free in swing in the OCP and nothing else turns it: turning in place at 0.6 rad/s,
    g1's soles stayed where they stood while the pelvis turned over them, its hip yaw joints wound up to -1.1 and
    -1.7 rad in 4 s and the sideways steps that followed crossed its feet (ankles and knees colliding) and felled
    it. So the sole turns with the same profile to its heading at touch-down, psi_td + omega_cmd T_st / 2 plus its
    heading in the nominal pose (stance then turns the base over it from half a stance ahead to half behind).
    """

    def __init__(self, robot: RobotModel):
        model = robot.model
        self._model, self._data = model, model.createData()
        self._frames = [robot.frame_id(robot.contact_frame(foot)) for foot in robot.feet]
        q = robot.q_nominal.copy()
        q[3:7] = (0.0, 0.0, 0.0, 1.0)
        pin.framesForwardKinematics(model, self._data, q)
        base = q[:2]
        self.foot_offsets_m = np.array([self._data.oMf[f].translation[:2] - base for f in self._frames])
        self._foot_yaws_rad = np.array([heading_of(self._data.oMf[f].rotation) for f in self._frames])
        self.height_m = float(robot.q_nominal[2])
        self.reach_m = MAX_STEP_PER_LEG * self.height_m

    def velocities(self, gait: Gait, t_s: float, node_times_s: np.ndarray, q: np.ndarray, v_world: np.ndarray,
                   command_world: np.ndarray, yaw: float, feet_m: np.ndarray, yaw_rate_rad_s: float = 0.0,
                   swings: list | None = None) -> np.ndarray:
        """(nodes, n_feet, 2) world xy velocity references of swing feet at t + node_times_s (NaN: stance or
        the free end of a swing). `v_world`: the measured base velocity, `command_world` the commanded one,
        both world xy; `yaw`: the base's heading; `feet_m`: measured foot positions (n_feet, >= 2);
        `yaw_rate_rad_s`: the commanded yaw rate; `swings`: `_swings`' list for these times, if already made."""
        out = np.full((len(node_times_s), len(self._frames), 2), np.nan)
        # (scalar arithmetic, term for term csrc/step_feet.c's: the compiled step's results are these bit for bit)
        cx, cy = (float(c) for c in np.asarray(command_world, dtype=float)[:2])
        vx, vy = (float(c) for c in np.asarray(v_world, dtype=float)[:2])
        root, rate = math.sqrt(self.height_m / 9.81), float(yaw_rate_rad_s)
        capture_x, capture_y = CAPTURE_GAIN * (vx - cx) * root, CAPTURE_GAIN * (vy - cy) * root
        stance_s = gait.duty_factor * gait.period_s
        starts = [np.asarray(foot[:2], dtype=float) for foot in feet_m]
        qx, qy = float(q[0]), float(q[1])
        for i, nodes, shape, ahead_s in _swings(gait, t_s, node_times_s) if swings is None else swings:
            angle = yaw + rate * ahead_s
            cos_a, sin_a = math.cos(angle), math.sin(angle)
            ox, oy = self.foot_offsets_m[i].tolist()
            lever_x, lever_y = cos_a * ox - sin_a * oy, sin_a * ox + cos_a * oy
            step_x = (cx + rate * -lever_y) * stance_s / 2 + capture_x
            step_y = (cy + rate * lever_x) * stance_s / 2 + capture_y
            reach = math.sqrt(step_x * step_x + step_y * step_y)
            if reach > self.reach_m:
                scale = self.reach_m / reach
                step_x, step_y = step_x * scale, step_y * scale
            target = np.array([((qx + ahead_s * cx) + lever_x) + step_x, ((qy + ahead_s * cy) + lever_y) + step_y])
            if shape is not None:
                out[nodes, i] = np.outer(shape, target - starts[i])
            starts[i] = target  # a later swing of this foot starts where this one lands
        return out

    def yaw_rates(self, gait: Gait, t_s: float, node_times_s: np.ndarray, yaw: float, yaw_rate_rad_s: float,
                  feet_yaw_rad: np.ndarray, swings: list | None = None) -> np.ndarray:
        """(nodes, n_feet) world yaw rates of swing soles at t + node_times_s that turn each to its heading at
        touch-down (NaN: stance or the free end of a swing). `yaw`: the base's heading, `yaw_rate_rad_s` the
        commanded yaw rate, `feet_yaw_rad` the soles' measured headings; `swings` as in `velocities`."""
        out = np.full((len(node_times_s), len(self._frames)), np.nan)
        stance_s = gait.duty_factor * gait.period_s
        starts = np.asarray(feet_yaw_rad, dtype=float).copy()
        for i, nodes, shape, ahead_s in _swings(gait, t_s, node_times_s) if swings is None else swings:
            target = yaw + yaw_rate_rad_s * (ahead_s + stance_s / 2) + self._foot_yaws_rad[i]
            turn = _wrap(target - starts[i])
            if shape is not None:
                out[nodes, i] = shape * turn
            starts[i] = starts[i] + turn
        return out

    def c_constants(self) -> np.ndarray:
        """The constants of csrc/step_feet.c's `wbsp_swing_references`: nominal height, reach, capture gain, the free
        end's share, then the feet's offsets under their hips (feet, 2) and the soles' nominal headings (feet)."""
        return np.r_[self.height_m, self.reach_m, CAPTURE_GAIN, PLACEMENT_END_SHARE, self.foot_offsets_m.ravel(),
                     self._foot_yaws_rad]

    def swings(self, gait: Gait, t_s: float, node_times_s: np.ndarray) -> list:
        """The swings `velocities` and `yaw_rates` follow at t + node_times_s, made once for both (same gait)."""
        return list(_swings(gait, t_s, node_times_s))


def swings_in_horizon(gait: Gait, t_s: float, times_s: np.ndarray):
    """(foot, its nodes, swing progress s at those nodes, lift-off time, touch-down time, progress now) of every
    swing at the absolute node times `times_s`, in time order per foot; a new swing starts where progress drops
    (or at the first swing node). Nothing for a gait without swings. (Every MPC step, twice on flat feet: the
    nodes' flags go through Python lists, a swing's nodes being the run from its start while the foot swings.)"""
    duty = gait.duty_factor
    if duty >= 1:
        return
    swing_s = gait.swing_duration_s
    phase = gait.phase(times_s)  # (n, feet)
    progress = np.where(phase >= duty, (phase - duty) / (1 - duty), -1.0)
    now_phase = gait.phase(np.array([t_s]))[0]
    swinging = progress >= 0
    starts = swinging.copy()  # a swing starts after a stance node or where its progress drops
    starts[1:] &= (progress[:-1] < 0) | (progress[1:] < progress[:-1])
    for foot, (foot_swinging, foot_starts) in enumerate(zip(swinging.T.tolist(), starts.T.tolist())):
        if not any(foot_swinging):
            continue
        s_now = (now_phase[foot] - duty) / (1 - duty) if now_phase[foot] >= duty else 0.0
        n, first = len(foot_starts), 0
        while True in foot_starts[first:]:
            first = foot_starts.index(True, first)
            last = first + 1
            while last < n and foot_swinging[last] and not foot_starts[last]:
                last += 1
            nodes = np.arange(first, last)
            s = progress[first:last, foot].copy()
            lift_off_t = times_s[first] - s[0] * swing_s
            yield foot, nodes, s, lift_off_t, lift_off_t + swing_s, s_now
            first = last


def _swings(gait: Gait, t_s: float, node_times_s: np.ndarray):
    """The swings within the horizon (`swings_in_horizon`) as the placement uses them: (foot, its nodes, the
    profile 6 s (1 - s) rescaled to the swing left (None: in the free end), time from t_s to its touch-down)."""
    swing_s = gait.swing_duration_s
    times_s = t_s + np.asarray(node_times_s, dtype=float)
    for i, nodes, s, lift_off_t, touch_down_t, s_now in swings_in_horizon(gait, t_s, times_s):
        s0 = s_now if lift_off_t <= t_s else 0.0
        left = 1 - 3 * (s0 * s0) + 2 * (s0 * s0 * s0)  # integral of 6 s (1 - s) from s0 to 1
        shape = 6 * s * (1 - s) / (swing_s * left) if left > PLACEMENT_END_SHARE else None
        yield i, nodes, shape, float(touch_down_t - t_s)


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def heading_of(rotation: np.ndarray) -> float:
    """The heading (yaw about world z) of a rotation matrix's x axis."""
    return float(np.arctan2(rotation[1, 0], rotation[0, 0]))
