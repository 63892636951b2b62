"""Loco-manipulation scenarios of section VI-C, in MuJoCo where the forces can be measured.

The MPC never models the objects (unless `--object-model`, issue 22: push-box and pull then plan with the box or the
load inside the OCP, `wbmpc.ocp.objects`): it receives the end-effector force target F_arm^des and the
end-effector velocity command v_arm^des of eq. (7) (`Commands.ee_force_n`, `ee_velocity_m_s`).
The velocity command comes from a position reference by feedback (v = v_ref + K (p_ref - p)),
except along a contact normal, where the force target alone presses the end-effector on.

- `pull`: a load on the floor tied to the end-effector by a cable; the robot walks backwards
  (`--gait trot|walk`) or, in stance (`--gait stand`), leans back and retracts the arm. The force target is the
  cable tension that makes the load slide: T = mu m g / (cos(theta) + mu sin(theta)) along the
  cable (theta above horizontal), unless `--force-n` sets it.
- `push-box`: trotting in place, press a box against a wall with `--force-n` (default 20 N); or (`--box-path turn`,
  `--object-model`) push a free box along a path at 0.1 m/s with a 90 degree turn (`scenarios/object_paths.py`),
  measured by `box_pos_rmse_m`.
- `wipe`: standing, move over a board in a circle or figure-eight pressing with `--force-n`
  (default 10 N) along the normal; the target also contains the board's friction along the motion.
  The end-effector carries a sprung wiping pad (`CompliantPad`, `--pad-stiffness`, 0 for the rigid
  sphere), and the in-plane path feedback has integral action (`--wipe-integral`) against the
  board's static friction, which the force target cannot carry.
- `compliant`: arm PD gains lowered, end-effector force target zero and velocity target zero
  plus a slow return to the nominal place (`--compliant-return 0` for the paper's pure zero); a
  scripted hand moves the end-effector back, left and down through a capped spring.

Force metric (all scenarios with a force target): `ee_force_err_rel` = mean over the time the
full target is applied of |F_meas . u - F_target| / F_target, where F_meas is the force the
end-effector applies on the object (cable tension or contact force, measured by MuJoCo at every
physics step and passed through a first-order low-pass of `FORCE_SENSOR_BANDWIDTH_HZ`, the
bandwidth of a wrist force sensor), u the unit direction of the target (the board normal for
`wipe`) and F_target the target's magnitude along u. The same error of the unfiltered contact
force is `ee_force_err_rel_raw`. With the rigid end-effector sphere sliding on the board with
friction, MuJoCo's contact makes and breaks at ~200 Hz with micrometre motions of the light wrist
(a squeal no sensor resolves; it stays with other cones, integrators, time steps, contact softness
and margins): 23 % filtered, ~100 % raw error. The sprung pad keeps the contact closed, and the
raw and filtered errors agree (about 2 %).
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pinocchio as pin

from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import Event, RunLog
from wbmpc.control.mpc import Commands, CostWeights
from wbmpc.errors import ConfigError
from wbmpc.robots import GRAVITY_M_S2, RobotModel
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.sim.objects import (
    Board,
    BoxAtWall,
    CableLoad,
    CompliantPad,
    ExternalHand,
    FreeBox,
    HandPush,
    Scene,
)

EE_SPHERE_RADIUS_M = 0.03  # MujocoPlantConfig.ee_sphere_radius_m default: contact offset of the EE frame
FEEDBACK_GAIN_1_S = 4.0
MAX_EE_SPEED_M_S = 0.5
TORQUE_WARNING_RATIO = 0.8
FORCE_SENSOR_BANDWIDTH_HZ = 30.0


# ----------------------------------------------------------------------------- helpers
def ramp(t: float, start_s: float, end_s: float) -> float:
    """0 before start, 1 after end, linear in between."""
    return float(np.clip((t - start_s) / (end_s - start_s), 0.0, 1.0))


def nominal_ee_position(robot: RobotModel) -> np.ndarray:
    return robot.frame_trajectories(robot.q_nominal, [robot.arm_ee])[robot.arm_ee][0]


def static_arm_torques(robot: RobotModel, force_applied_n: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
    """Arm joint torques holding the pose `q` (nominal by default) while the end-effector applies
    `force_applied_n` (world) on the environment: tau = g(q) + J^T F (static eq. 2 with F_arm = -F)."""
    q = robot.q_nominal if q is None else q
    model, data = robot.model, robot.model.createData()
    gravity = pin.computeGeneralizedGravity(model, data, q)
    jac = pin.computeFrameJacobian(model, data, q, robot.frame_id(robot.arm_ee), pin.LOCAL_WORLD_ALIGNED)[:3]
    tau = gravity[6:] + jac[:, 6:].T @ np.asarray(force_applied_n, dtype=float)
    return tau[~robot.leg_joint_mask]


def support_centre_of_pressure(robot: RobotModel, force_applied_n: np.ndarray) -> np.ndarray:
    """Ground centre of pressure (x, y) holding the nominal pose statically against gravity and the
    end-effector applying `force_applied_n` (moment balance of eq. 2 without motion)."""
    q = robot.q_nominal
    weight = robot.mass_kg * GRAVITY_M_S2
    com = pin.centerOfMass(robot.model, robot.model.createData(), q)
    p_ee = nominal_ee_position(robot)
    on_robot = -np.asarray(force_applied_n, dtype=float)
    reaction_z = weight - on_robot[2]
    if reaction_z <= 0:
        return np.array([np.inf, np.inf])
    moment = np.cross(com, [0.0, 0.0, -weight]) + np.cross(p_ee, on_robot)
    return np.array([moment[1], -moment[0]]) / reaction_z


def _support_points(robot: RobotModel) -> np.ndarray:
    """(n, 2) ground points of the feet at the nominal pose: point feet, and the corners of flat feet's soles
    (two point feet side by side support no fore-aft moment; two soles do)."""
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, robot.q_nominal)
    points = []
    for foot in robot.feet:
        placement = data.oMf[robot.frame_id(robot.contact_frame(foot))]
        local = robot.soles[foot].corners_m() if foot in robot.soles else np.zeros((1, 3))
        points.extend(placement.rotation @ corner + placement.translation for corner in local)
    return np.array(points)[:, :2]


def check_arm_force(robot: RobotModel, force_applied_n: np.ndarray, what: str) -> np.ndarray:
    """Raise `ConfigError` when the arm cannot hold the force target at its nominal pose, or the
    force would tip the standing robot over its feet; warn near the arm's torque limits.

    Returns the ratio |tau| / tau_max per arm joint."""
    tau = static_arm_torques(robot, force_applied_n)
    limits = robot.tau_max[~robot.leg_joint_mask]
    ratio = np.abs(tau) / limits
    names = [n for n, leg in zip(robot.joint_names, robot.leg_joint_mask) if not leg]
    worst = int(np.argmax(ratio))
    magnitude = float(np.linalg.norm(force_applied_n))
    detail = (f"{what} of {magnitude:.1f} N needs {abs(tau[worst]):.1f} Nm on {names[worst]} at the nominal arm "
              f"pose (limit {limits[worst]:.1f} Nm)")
    if ratio[worst] > 1.0:
        raise ConfigError(f"{detail}: beyond the arm's torque limits; lower the force (--force-n) or the load (--load-kg)")
    xy = _support_points(robot)
    cop = support_centre_of_pressure(robot, force_applied_n)
    if not (np.all(cop >= xy.min(axis=0)) and np.all(cop <= xy.max(axis=0))):
        raise ConfigError(f"{what} of {magnitude:.1f} N would tip the robot over: the centre of pressure it needs "
                          f"({cop[0]:.2f}, {cop[1]:.2f}) m lies outside the feet; lower the force (--force-n)")
    if ratio[worst] > TORQUE_WARNING_RATIO:
        warnings.warn(f"{detail}: {100 * ratio[worst]:.0f} % of the limit, little margin left for motion", stacklevel=2)
    return ratio


class _EeState:
    """End-effector position from a measured configuration (pinocchio FK)."""

    def __init__(self, robot: RobotModel):
        self.robot = robot
        self.data = robot.model.createData()
        self.fid = robot.frame_id(robot.arm_ee)

    def position(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self.robot.model, self.data, q)
        return self.data.oMf[self.fid].translation.copy()


def _feedback(v_ref: np.ndarray, p_ref: np.ndarray, p: np.ndarray, free_normal: np.ndarray | None = None) -> np.ndarray:
    """v = v_ref + K (p_ref - p), without the component along `free_normal` (force-controlled), clipped."""
    velocity = v_ref + FEEDBACK_GAIN_1_S * (p_ref - p)
    if free_normal is not None:
        velocity = velocity - free_normal * (velocity @ free_normal)
    speed = np.linalg.norm(velocity)
    return velocity * (MAX_EE_SPEED_M_S / speed) if speed > MAX_EE_SPEED_M_S else velocity


class _InPlaneIntegral:
    """Integral action on the in-plane end-effector error: a velocity term Ki * int(e dt), clipped to
    MAX_INTEGRAL_SPEED_M_S. On a board the pad's friction is an unmodelled force in the plane (the
    force target only carries it along the motion; standing still, static friction acts in any
    direction), which proportional feedback alone leaves as a steady offset of millimetres."""

    MAX_INTEGRAL_SPEED_M_S = 0.05

    def __init__(self, normal: np.ndarray, gain_1_s2: float):
        self.normal, self.gain = np.asarray(normal, dtype=float), gain_1_s2
        self.value = np.zeros(3)
        self.last_t: float | None = None

    def update(self, t: float, error_m: np.ndarray) -> np.ndarray:
        """Integrate the in-plane part of `error_m` up to time t; the velocity term (m/s)."""
        error = error_m - self.normal * (error_m @ self.normal)
        if self.last_t is not None and self.gain > 0:
            self.value = self.value + error * max(t - self.last_t, 0.0)
            speed = self.gain * np.linalg.norm(self.value)
            if speed > self.MAX_INTEGRAL_SPEED_M_S:
                self.value *= self.MAX_INTEGRAL_SPEED_M_S / speed
        self.last_t = t
        return self.gain * self.value


def _yaw_rotation(q: np.ndarray) -> np.ndarray:
    rot = pin.Quaternion(q[3:7]).toRotationMatrix()
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _hold(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Zero-order hold of per-MPC-step values at other times."""
    index = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 1)
    return values[index]


def force_tracking(t: np.ndarray, measured_n: np.ndarray, direction: np.ndarray, target_n: np.ndarray,
                   window: np.ndarray) -> dict:
    """`ee_force_err_rel` and friends: measured force along `direction` against `target_n` (> 0) in `window`."""
    along = np.einsum("ij,ij->i", measured_n, direction)
    use = window & (target_n > 1e-6)
    if not use.any():
        return {"ee_force_err_rel": None}
    rel = np.abs(along[use] - target_n[use]) / target_n[use]
    return {
        "ee_force_err_rel": float(np.mean(rel)),
        "ee_force_err_rel_p95": float(np.percentile(rel, 95)),
        "ee_force_measured_mean_n": float(np.mean(along[use])),
        "ee_force_target_mean_n": float(np.mean(target_n[use])),
        "ee_force_bias_rel": float(np.mean(along[use] - target_n[use]) / np.mean(target_n[use])),
    }


def low_pass(t: np.ndarray, values: np.ndarray, bandwidth_hz: float) -> np.ndarray:
    """First-order low-pass (a force sensor's filter) of samples `values` (n, ...) at times `t`."""
    out = np.array(values, dtype=float, copy=True)
    tau = 1.0 / (2 * np.pi * bandwidth_hz)
    for k in range(1, len(t)):
        alpha = (t[k] - t[k - 1]) / (t[k] - t[k - 1] + tau)
        out[k] = out[k - 1] + alpha * (values[k] - out[k - 1])
    return out


def _commanded_forces(log: RunLog, at: np.ndarray) -> np.ndarray:
    forces = log.command_array()[:, 7:10]  # ee_force_n (see wbmpc.control.loop.command_row)
    return _hold(np.array(log.mpc_t), forces, at)


def _arm_metrics(robot: RobotModel, log: RunLog) -> dict:
    """Torque ratio of each arm joint (joint3 is what limited the paper's pull on hardware)."""
    tau = np.abs(log.arrays(("tau",))["tau"]) / robot.tau_max
    return {f"torque_ratio_{name}": float(tau[:, k].max())
            for k, name in enumerate(robot.joint_names) if not robot.leg_joint_mask[k]}


class _ForceTask(Scenario):
    """Shared by the scenarios whose metric is force tracking against a scene object."""

    object_name = ""
    force_window_start_s = 1.0

    def __post_init__(self):
        super().__post_init__()
        self._scene: Scene | None = None

    def scene(self, robot):
        self._scene = Scene(robot, self._objects(robot))
        return self._scene

    def _objects(self, robot) -> list:
        raise NotImplementedError

    def _force_direction(self, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(unit directions, magnitudes) of the target along which the measured force is compared."""
        magnitude = np.linalg.norm(targets, axis=1)
        return targets / np.maximum(magnitude, 1e-9)[:, None], magnitude

    def measured_force(self) -> tuple[np.ndarray, np.ndarray]:
        if self._scene is None or not self._scene.recording.t:
            raise ConfigError(f"scenario '{self.name}' has no scene measurements; run it on the MuJoCo plant")
        return self._scene.recording.series(self.object_name, "force_n")

    def force_series(self, log: RunLog) -> dict:
        """Measured force along the target direction, and the target, at every physics step."""
        t, raw = self.measured_force()
        measured = low_pass(t, raw, FORCE_SENSOR_BANDWIDTH_HZ)
        direction, target = self._force_direction(_commanded_forces(log, t))
        return {"t": t, "measured_n": np.einsum("ij,ij->i", measured, direction), "target_n": target,
                "measured_vec_n": measured, "raw_vec_n": raw, "direction": direction}

    def extra_metrics(self, robot, log):
        s = self.force_series(log)
        t_end = float(log.last_tick("t")) if log.n_ticks else 0.0
        window = (s["t"] >= self.force_window_start_s) & (s["t"] <= t_end + 1e-9)
        out = force_tracking(s["t"], s["measured_vec_n"], s["direction"], s["target_n"], window)
        raw = force_tracking(s["t"], s["raw_vec_n"], s["direction"], s["target_n"], window)
        out["ee_force_err_rel_raw"] = raw["ee_force_err_rel"]
        out["force_sensor_bandwidth_hz"] = FORCE_SENSOR_BANDWIDTH_HZ
        out["force_window_start_s"] = self.force_window_start_s
        out.update(_arm_metrics(robot, log))
        return out

    def extra_plots(self, robot, log, out_dir):
        from wbmpc.viz.plots import RunMarks, plot_ee_force

        s = self.force_series(log)
        return [plot_ee_force(s["t"], s["measured_n"], s["target_n"], out_dir / "ee_force.png",
                              title=f"{self.name}: end-effector force on the {self.object_name}",
                              marks=RunMarks.from_log(log))]


# ----------------------------------------------------------------------------- pull
class Pull(_ForceTask):
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

        def reference(t):
            moving = np.maximum(np.asarray(t, dtype=float) - self.MOVE_START_S, 0.0)
            return np.column_stack([x0_m - speed * moving, np.where(moving > 0, -speed, 0.0)])

        return reference

    def _object_command(self, robot, t):
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
        ee = _EeState(robot)
        offset0 = _yaw_rotation(robot.q_nominal).T @ (nominal_ee_position(robot) - robot.q_nominal[:3])
        speed = self.options.pull_speed_m_s
        travel = self.STANCE_RETRACT_M + self.STANCE_BASE_SHIFT_M
        window = travel / max(speed, 1e-9)
        retract_end = self.MOVE_START_S + window

        def command(t, q, v):
            moving = t >= self.MOVE_START_S
            heading = _yaw_rotation(q)
            offset = offset0.copy()
            base_velocity = np.zeros(3)
            ee_velocity_ref = np.zeros(3)
            if self.walking and moving:
                base_velocity[0] = -speed
                ee_velocity_ref = heading @ base_velocity
            elif not self.walking and moving:
                share = (min(t, retract_end) - self.MOVE_START_S) / window
                offset[0] -= self.STANCE_RETRACT_M * share
                if t < retract_end:
                    base_velocity[0] = -self.STANCE_BASE_SHIFT_M / window
                    ee_velocity_ref = heading @ np.array([-speed, 0.0, 0.0])
            if self.options.object_model:  # the MPC plans the hand's force and motion on the load's speed
                return Commands(base_velocity_m_s=base_velocity, object_command=self._object_command(robot, t))
            # hold the end-effector at its (retracting) place relative to the base, in the heading frame
            p_ref = q[:3] + heading @ offset
            return Commands(base_velocity_m_s=base_velocity,
                            ee_velocity_m_s=_feedback(ee_velocity_ref, p_ref, ee.position(q)),
                            ee_force_n=ramp(t, *self.RAMP_S) * force)

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


# ----------------------------------------------------------------------------- push-box
class PushBox(_ForceTask):
    """Press a box against a wall while trotting in place, with a force target (section VI-C); or (`--box-path
    turn`, implied by `--object-model`) push a free box along a path with a 90 degree turn (issue 22: with the
    box inside the MPC, or with a force command as the paper's MPC would)."""

    object_name = "box"
    RAMP_S = (0.4, 0.9)
    APPROACH_END_S = 0.4
    GAP_M = 0.02
    DEFAULT_FORCE_N = 20.0
    PATH_DURATION_AFTER_S = 1.0  # the run continues this long after the path's turn
    # --push-height with --object-model (SlidingBox.push_height_m): the base crouched to CROUCH of its nominal height
    # and the arm's posture weight ARM_WEIGHT. Lower pushes tracked the turn worse (b1_z1, 16 s: 0.82 / 0.74 m, 6.2 /
    # 13.1 cm RMSE against 5.6 cm at 0.87 m, docs/design/object-model.md), and the MPC brought the hand no lower than
    # ~0.67-0.71 m
    CROUCH = 0.85
    ARM_WEIGHT = 100.0

    def __init__(self, options: ScenarioOptions):
        super().__init__("push-box", "press a box against the wall while trotting in place (or push it along a "
                         "path: --box-path turn, --object-model)", "trot", 6.0, needs_arm=True, options=options)
        self.force_window_start_s = self.RAMP_S[1] + 0.2
        if self.follows_path:
            from wbmpc.scenarios.object_paths import BoxPath

            path = BoxPath(radius_m=self.options.box_turn_radius_m)
            self.default_duration_s = round(path.start_s + path.moving_s + self.PATH_DURATION_AFTER_S)

    @property
    def follows_path(self) -> bool:
        return self.options.object_model or self.options.box_path == "turn"

    def free_box(self, robot) -> FreeBox:
        return FreeBox(near_face_x_m=self._face_x(robot), mass_kg=self.options.box_kg)

    def box_path(self, robot):
        """The commanded path of the free box's centre, from where the box starts."""
        from wbmpc.scenarios.object_paths import BoxPath

        return BoxPath(start_xy_m=tuple(self.free_box(robot).centre_xy_m), radius_m=self.options.box_turn_radius_m)

    def object_model(self, robot):
        """The OCP's model of the scene's box (`--object-model`)."""
        from wbmpc.ocp.objects import SlidingBox

        return SlidingBox.from_scene(self.free_box(robot), EE_SPHERE_RADIUS_M, push_height_m=self.push_height_m)

    def cost_weights(self, weights: CostWeights) -> CostWeights:
        """With a push height: the arm's posture weight ARM_WEIGHT (lower: the arm, not only the crouch, reaches it)."""
        if self.push_height_m is not None:
            return replace(weights, arm_joint_position=self.ARM_WEIGHT)
        return weights

    @property
    def push_height_m(self) -> float | None:
        """The hand's height on the box's face with the object model (None: where the nominal posture holds it)."""
        return self.options.push_height_m if self.options.object_model else None

    def _base_height_m(self, robot) -> float | None:
        return self.CROUCH * float(robot.q_nominal[2]) if self.push_height_m is not None else None

    @property
    def force_magnitude_n(self) -> float:
        return self.options.force_n if self.options.force_n is not None else self.DEFAULT_FORCE_N

    def _face_x(self, robot) -> float:
        return float(nominal_ee_position(robot)[0] + EE_SPHERE_RADIUS_M + self.GAP_M)

    def push_pad(self, robot) -> CompliantPad:
        """With --object-model the hand carries a stiff sprung pad (`CompliantPad`): the rigid sphere on the box made
        and broke contact (on the box 60 % of the time, force std 15 N), the pad keeps it closed (92 %, 9 N) and the
        box nearer its path (b1_z1, 16 s: 4.6 cm RMSE instead of 5.6; 8000 / 12000 / 16000 N/m: 4.7 / 4.6 / 4.6 cm).
        Its stiffness: the push that slides the box, mu m g, compresses it by half the OCP's contact tolerance (the MPC
        does not model the pad: its plan's hand stays within that tolerance of the face)."""
        from wbmpc.ocp.objects import CONTACT_TOLERANCE_M

        box = self.free_box(robot)
        push_n = box.friction_mu * box.mass_kg * GRAVITY_M_S2
        return CompliantPad(stiffness_n_m=push_n / (0.5 * CONTACT_TOLERANCE_M), radius_m=EE_SPHERE_RADIUS_M)

    def _objects(self, robot):
        if self.options.object_model:
            return [self.free_box(robot), self.push_pad(robot)]
        if self.follows_path:
            return [self.free_box(robot)]
        return [BoxAtWall(near_face_x_m=self._face_x(robot), mass_kg=self.options.box_kg)]

    def check(self, robot):
        if self.follows_path:
            box = self.free_box(robot)
            force = box.friction_mu * box.mass_kg * GRAVITY_M_S2
            check_arm_force(robot, np.array([force, 0.0, 0.0]), "force that slides the box")
            return
        check_arm_force(robot, np.array([self.force_magnitude_n, 0.0, 0.0]), "pushing force target")

    def commands(self, robot):
        if self.follows_path:
            return self._path_commands(robot)
        ee = _EeState(robot)
        normal = np.array([1.0, 0.0, 0.0])  # into the box
        p_ref = nominal_ee_position(robot)
        p_ref[0] = self._face_x(robot) - EE_SPHERE_RADIUS_M + 0.005
        force = self.force_magnitude_n * normal

        def command(t, q, v):
            free = None if t < self.APPROACH_END_S else normal
            return Commands(ee_velocity_m_s=_feedback(np.zeros(3), p_ref, ee.position(q), free),
                            ee_force_n=ramp(t, *self.RAMP_S) * force)

        return command

    def _push_pivot_m(self, robot) -> float:
        """Where the box's floor load centres under the sliding push at the hand's height h: mu h ahead of its centre
        (`object_paths.sideslip_lead`)."""
        height = self.push_height_m
        return self.free_box(robot).friction_mu * float(nominal_ee_position(robot)[2] if height is None else height)

    def _path_commands(self, robot):
        """The base follows the box's path; the hand pushes by force command, or (object model) the MPC plans it."""
        from wbmpc.scenarios.object_paths import PathFollower, force_command, object_command

        path, box, ee = self.box_path(robot), self.free_box(robot), _EeState(robot)
        follower = PathFollower(path, robot.q_nominal[:2])
        height = float(nominal_ee_position(robot)[2])
        pivot = self._push_pivot_m(robot)

        def command(t, q, v):
            measured = object_command(path, self._scene, self.object_name, t, pivot)
            base = follower.base_command(t, q, measured.state)
            if self.options.object_model:
                return Commands(**base, object_command=measured, base_height_m=self._base_height_m(robot))
            velocity, force = force_command(path, t, box, EE_SPHERE_RADIUS_M, height, ee.position(q), _feedback)
            return Commands(**base, ee_velocity_m_s=velocity, ee_force_n=force)

        return command

    def extra_metrics(self, robot, log):
        out = super().extra_metrics(robot, log)
        out["object_model"] = bool(self.options.object_model)
        if self.follows_path:
            from wbmpc.scenarios.object_paths import path_metrics

            t, states = self._scene.recording.series(self.object_name, "planar_state")
            pivot = self._push_pivot_m(robot) if self.options.object_model else 0.0
            out.update(path_metrics(self.box_path(robot), t, states, pivot_m=pivot))
            out["box_kg"] = self.options.box_kg
        return out


# ----------------------------------------------------------------------------- wipe
class Wipe(_ForceTask):
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

    def _phase(self, t: float) -> tuple[float, float]:
        """Pattern phase and its rate: the rate ramps linearly to 2 pi / period over SPEED_UP_S."""
        w = 2 * np.pi / self.options.wipe_period_s
        tau = t - self.PATTERN_START_S
        if tau <= 0:
            return 0.0, 0.0
        if tau < self.SPEED_UP_S:
            return 0.5 * w * tau**2 / self.SPEED_UP_S, w * tau / self.SPEED_UP_S
        return w * (tau - 0.5 * self.SPEED_UP_S), w

    def path(self, robot, t: float) -> tuple[np.ndarray, np.ndarray]:
        """End-effector frame position and velocity of the pattern on the board at time t."""
        board = self.board(robot)
        a1, a2 = board.plane_axes
        r = self.options.wipe_size_m
        phi, rate = self._phase(t)
        if self.options.wipe_pattern == "circle":  # through the centre, like a wiping loop
            offset = r * np.sin(phi) * a1 + r * (1 - np.cos(phi)) * a2
            d_offset = r * np.cos(phi) * a1 + r * np.sin(phi) * a2
        else:  # figure eight
            offset = r * np.sin(phi) * a1 + 0.5 * r * np.sin(2 * phi) * a2
            d_offset = r * np.cos(phi) * a1 + r * np.cos(2 * phi) * a2
        return self._centre + offset, d_offset * rate

    def ee_reference(self, robot):
        return lambda t: self.path(robot, t)[0]

    def _force_direction(self, targets):
        inward = -self.board(self._scene.robot).normal
        along = targets @ inward
        return np.tile(inward, (len(targets), 1)), along

    def check(self, robot):
        board = self.board(robot)
        force = -board.normal * self.force_magnitude_n * np.hypot(1.0, self.options.board_friction_mu)
        check_arm_force(robot, force, "wiping force target (normal force and friction)")

    def commands(self, robot):
        ee = _EeState(robot)
        board = self.board(robot)
        normal = board.normal
        mu = self.options.board_friction_mu

        integral = _InPlaneIntegral(normal, self.options.wipe_integral_gain_1_s2)

        def command(t, q, v):
            p_ref, v_ref = self.path(robot, t)
            p = ee.position(q)
            if t < self.APPROACH_END_S:
                velocity = _feedback(v_ref, p_ref - 0.005 * normal, p)
            else:
                velocity = _feedback(v_ref + integral.update(t, p_ref - p), p_ref, p, free_normal=normal)
            press = ramp(t, *self.RAMP_S) * self.force_magnitude_n
            force = -normal * press
            speed = np.linalg.norm(v_ref)
            if speed > 1e-6:  # the board's friction resists the motion: the end-effector pushes along it
                force = force + mu * press * v_ref / speed
            return Commands(ee_velocity_m_s=velocity, ee_force_n=force)

        return command

    ee_error_label = "in-plane |p - p_ref| from the pattern's start"

    def ee_tracking_error(self, robot, t, ee):
        """In-plane error (the normal is force-controlled) from the pattern's start."""
        reference = np.array([self.path(robot, float(ti))[0] for ti in t])
        normal = self.board(robot).normal
        error = ee - reference
        return error - np.outer(error @ normal, normal), np.asarray(t) >= self.PATTERN_START_S

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


# ----------------------------------------------------------------------------- compliant
class Compliant(Scenario):
    """Arm PD gains lowered, end-effector force target zero: a scripted hand moves the end-effector
    back, left and down (each `HAND_TRAVEL_M` in `HAND_MOVE_S`, held, then let go) while the robot
    keeps its balance (section VI-C). Measured: how far the end-effector followed the hand and the
    force the hand needed (a stiff arm needs the cap, `--hand-force`)."""

    PUSHES = ((1.0, (-1.0, 0.0, 0.0)), (3.0, (0.0, 1.0, 0.0)), (5.0, (0.0, 0.0, -1.0)))
    HAND_TRAVEL_M, HAND_MOVE_S, HOLD_S = 0.12, 0.8, 0.5

    def __init__(self, options: ScenarioOptions):
        super().__init__("compliant", "low arm gains, zero end-effector targets: yield to a pushing hand",
                         "stand", 7.0, needs_arm=True, options=options)
        self._scene: Scene | None = None

    def hand(self) -> ExternalHand:
        pushes = tuple(HandPush(start, tuple(self.HAND_TRAVEL_M * np.asarray(direction)), self.HAND_MOVE_S, self.HOLD_S)
                       for start, direction in self.PUSHES)
        return ExternalHand(pushes=pushes, max_force_n=self.options.hand_force_n)

    def scene(self, robot):
        self._scene = Scene(robot, [self.hand()])
        return self._scene

    def pd_gains(self, gains: PdGains) -> PdGains:
        return replace(gains, kp_arm=self.options.compliant_kp_arm, kd_arm=self.options.compliant_kd_arm)

    def events(self, robot):
        """The hand acts through the scene at every physics step; these only mark its pushes' starts in the log."""
        return [Event(start, lambda plant: None, name="hand push") for start, _ in self.PUSHES]

    def commands(self, robot):
        """Zero force target; the velocity target is zero too, plus (when `compliant_return_gain_1_s` > 0)
        a slow drift back to the nominal end-effector place on the base once the hand lets go: pure
        zero leaves the arm wherever it was pushed, at a joint limit after a strong push, where the
        OCP degenerates (Fatrop stalls, the IPOPT fallback takes seconds per solve)."""
        ee = _EeState(robot)
        offset = _yaw_rotation(robot.q_nominal).T @ (nominal_ee_position(robot) - robot.q_nominal[:3])
        gain = self.options.compliant_return_gain_1_s

        def command(t, q, v):
            velocity = np.zeros(3)
            if gain > 0:
                velocity = gain * (q[:3] + _yaw_rotation(q) @ offset - ee.position(q))
                speed = np.linalg.norm(velocity)
                if speed > 0.1:
                    velocity *= 0.1 / speed
            return Commands(ee_velocity_m_s=velocity, ee_force_n=np.zeros(3))

        return command

    def extra_metrics(self, robot, log):
        a = log.arrays(("t", "q"))
        t, q = a["t"], a["q"]
        ee = robot.frame_trajectories(q, [robot.arm_ee])[robot.arm_ee]
        yields, peak_forces = [], []
        t_hand, force = self._scene.recording.series("hand", "hand_force_n")
        for start, direction in self.PUSHES:
            before = np.searchsorted(t, start) - 1
            during = (t >= start) & (t <= start + self.HAND_MOVE_S + self.HOLD_S)
            if before < 0 or not during.any():
                continue
            yields.append(float(((ee[during] - ee[before]) @ np.asarray(direction)).max()))
            pushing = (t_hand >= start) & (t_hand <= start + self.HAND_MOVE_S + self.HOLD_S)
            peak_forces.append(float(np.linalg.norm(force[pushing], axis=1).max()))
        tilt = np.degrees(np.arccos(np.clip([pin.Quaternion(x[3:7]).toRotationMatrix()[2, 2] for x in q], -1, 1)))
        out = {
            "hand_travel_m": self.HAND_TRAVEL_M,
            "hand_force_cap_n": self.options.hand_force_n,
            "ee_yield_m": yields,  # how far the end-effector followed each push
            "hand_force_peak_n": peak_forces,  # the force each push needed (the cap: the arm resisted)
            "base_tilt_max_deg": float(tilt.max()),
            "base_height_min_m": float(q[:, 2].min()),
            "arm_gains": {"kp": self.options.compliant_kp_arm, "kd": self.options.compliant_kd_arm},
            "kept_balance": bool(not log.fell),
        }
        out.update(_arm_metrics(robot, log))
        return out
