"""The paper's two-stage state estimator (section V-B) from IMU and joint encoders.

Stage 1, attitude: the base orientation is the IMU's (its onboard attitude filter), the base
angular velocity is the gyro's. Stage 2, a linear Kalman filter (the formulation of Bledt et al.,
"MIT Cheetah 3", IROS 2018) with state x = [p, v, p_foot_1..n] in the world frame:

    predict:  p += v dt + a dt^2 / 2,  v += a dt,  feet held;  a = R accel + g  (IMU acceleration)
    update, per foot i, trusted where the gait schedule (or a contact switch) says stance:
        p_foot_i - p = R r_i(q_j)                  (leg kinematics)
        v = -R (omega x r_i + J_i(q_j) dq_j)       (a stance foot does not slide)
        p_foot_i,z = ground height + foot radius   (the terrain's height under the foot, issue 35)

Swing feet get a large noise, so they follow the base and re-anchor at touch-down; the trust of
a stance foot ramps over the first and last `contact_ramp` share of its stance phase. Joint
velocities pass a first-order low-pass filter (50 Hz in the paper) before they reach the MPC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError
from wbmpc.estimation.sensors import SensorReadings
from wbmpc.gait import Gait
from wbmpc.robots import GRAVITY_M_S2, RobotModel


@dataclass(frozen=True)
class EstimatorConfig:
    """Noise figures of the Kalman filter (standard deviations) and the joint velocity filter."""

    velocity_filter_hz: float | None = 50.0
    accel_noise_m_s2: float = 0.5  # process noise of the base velocity (IMU acceleration error)
    position_process_noise_m_s: float = 0.02  # random walk of the base position
    foot_process_noise_m_s: float = 0.002  # random walk of a stance foot (slip)
    swing_foot_noise_m_s: float = 100.0  # random walk of a swing foot
    kinematics_noise_m: float = 0.005  # leg-kinematics foot position
    foot_velocity_noise_m_s: float = 0.05  # leg-kinematics base velocity
    foot_height_noise_m: float = 0.005
    untrusted_noise_scale: float = 1e3  # noise multiplier on a foot not in stance
    contact_ramp: float = 0.1  # share of the stance phase over which the trust ramps at each end
    ground_height_m: float = 0.0
    use_contact_sensors: bool = False  # stance from the foot contact switches instead of the gait

    def __post_init__(self):
        if self.velocity_filter_hz is not None and not self.velocity_filter_hz > 0:
            raise ConfigError(f"velocity_filter_hz must be positive or None, got {self.velocity_filter_hz}")
        for name, value in vars(self).items():
            if isinstance(value, float) and name not in ("ground_height_m", "velocity_filter_hz") and not value > 0:
                if name == "contact_ramp" and value == 0:
                    continue
                raise ConfigError(f"estimator setting {name} must be positive, got {value}")


def contact_trust(gait: Gait, t_s: float, ramp: float) -> np.ndarray:
    """Per foot trust in [0, 1]: 0 in swing, ramping up/down over `ramp` of the stance phase at its ends."""
    phase = gait.phase(np.array([t_s]))[0]
    stance = phase < gait.duty_factor
    if gait.duty_factor >= 1 or ramp <= 0:
        return stance.astype(float)
    progress = phase / gait.duty_factor
    trust = np.clip(np.minimum(progress, 1.0 - progress) / ramp, 0.0, 1.0)
    return np.where(stance, trust, 0.0)


class StateEstimator:
    """IMU + encoders (+ gait schedule) -> (q, v) in pinocchio layout, like the simulator's state."""

    def __init__(self, robot: RobotModel, gait: Gait | None, config: EstimatorConfig = EstimatorConfig(),
                 terrain=None):
        """`terrain` (`wbmpc.terrain.Terrain`, None: the flat floor at `config.ground_height_m`): a stance foot's
        height is the terrain's under its estimated position."""
        if gait is None and not config.use_contact_sensors:
            raise ConfigError("the estimator needs the gait schedule or use_contact_sensors=True to know the stance feet")
        if gait is not None and len(gait.phase_offsets) != len(robot.feet):
            raise ConfigError(f"the gait has {len(gait.phase_offsets)} feet, the robot {len(robot.feet)}")
        self.robot, self.gait, self.config = robot, gait, config
        self.terrain = terrain if terrain is not None and not terrain.is_flat else None
        self._data = robot.model.createData()
        # stance kinematics at each foot's contact frame: the sole centre of a flat foot (on the ground), the
        # foot frame of a point foot (a radius above it); the filter's states are translational, the soles'
        # orientation in stance adds nothing the IMU's attitude does not give
        self._feet = [robot.frame_id(robot.contact_frame(f)) for f in robot.feet]
        self._contact_height_m = np.array([robot.contact_height_m(f) for f in robot.feet])
        self._nf = len(self._feet)
        self.n_state = 6 + 3 * self._nf
        self._gravity = np.array([0.0, 0.0, -GRAVITY_M_S2])
        self._q_rel = pin.neutral(robot.model)
        self._v_rel = np.zeros(robot.nv)
        self.x: np.ndarray | None = None
        self.gait_t0_s = 0.0  # the gait's phase starts at this sensor time (switch gaits with it)
        self._trust_now = np.ones(self._nf)
        self.P: np.ndarray | None = None
        self._t: float | None = None
        self._dq_filtered: np.ndarray | None = None
        self.q = robot.q_nominal.copy()
        self.v = np.zeros(robot.nv)

    def reset(self) -> None:
        self.x = self.P = self._t = self._dq_filtered = None

    # ------------------------------------------------------------------ kinematics
    def _legs(self, joint_q: np.ndarray, joint_dq: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Foot positions r_i and velocities omega x r_i + J_i dq_j in the base frame, (n_feet, 3) each."""
        model, data = self.robot.model, self._data
        self._q_rel[7:] = joint_q
        self._v_rel[3:6] = omega
        self._v_rel[6:] = joint_dq
        pin.forwardKinematics(model, data, self._q_rel, self._v_rel)
        r = np.empty((self._nf, 3))
        dr = np.empty((self._nf, 3))
        for k, fid in enumerate(self._feet):
            r[k] = pin.updateFramePlacement(model, data, fid).translation
            dr[k] = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
        return r, dr

    def _ground(self, feet_xy: np.ndarray) -> np.ndarray | float:
        """Ground height under each foot: the terrain's, or the flat floor's."""
        return self.config.ground_height_m if self.terrain is None else self.terrain.height(feet_xy)

    def _initialise(self, reading: SensorReadings, rot: np.ndarray, r: np.ndarray, start_xy: np.ndarray) -> None:
        foot_z = self._ground(start_xy + (r @ rot.T)[:, :2]) + self._contact_height_m
        p = np.array([start_xy[0], start_xy[1], np.mean(foot_z - (r @ rot.T)[:, 2])])
        feet = p + r @ rot.T
        self.x = np.concatenate([p, np.zeros(3), feet.ravel()])
        self.P = np.diag(np.concatenate([[1e-4] * 3, [1e-2] * 3, [1e-4] * 3 * self._nf]))

    # ------------------------------------------------------------------ filter
    def update(self, reading: SensorReadings, start_xy: np.ndarray = np.zeros(2)) -> tuple[np.ndarray, np.ndarray]:
        """Fuse one reading; returns the estimated (q, v). `start_xy` places the first estimate."""
        cfg = self.config
        t = reading.time_s
        dt = 0.0 if self._t is None else t - self._t
        if dt < 0:
            raise ConfigError(f"sensor time went backwards ({self._t} -> {t} s); reset() the estimator")
        # 50 Hz low-pass on joint velocities (paper, section V-B)
        dq = np.asarray(reading.joint_velocity_rad_s, dtype=float)
        if self._dq_filtered is None or not cfg.velocity_filter_hz:
            self._dq_filtered = dq.copy()
        elif dt > 0:
            alpha = dt / (dt + 1.0 / (2 * np.pi * cfg.velocity_filter_hz))
            self._dq_filtered += alpha * (dq - self._dq_filtered)
        rot = pin.Quaternion(np.asarray(reading.quaternion_xyzw, dtype=float)).normalized().toRotationMatrix()
        omega = np.asarray(reading.gyro_rad_s, dtype=float)
        r, dr = self._legs(reading.joint_position_rad, self._dq_filtered, omega)
        if self.x is None:
            self._initialise(reading, rot, r, start_xy)
        elif dt > 0:
            self._trust_now = self._trust(reading)
            self._predict(rot @ reading.accel_m_s2 + self._gravity, dt)
            self._correct(rot, r, dr, self._trust_now)
        self._t = t
        p, v_world = self.x[:3], self.x[3:6]
        self.q = np.concatenate([p, pin.Quaternion(rot).coeffs(), reading.joint_position_rad])
        self.v = np.concatenate([rot.T @ v_world, omega, self._dq_filtered])
        return self.q.copy(), self.v.copy()

    def _trust(self, reading: SensorReadings) -> np.ndarray:
        if self.config.use_contact_sensors:
            return np.asarray(reading.foot_contact, dtype=float)
        return contact_trust(self.gait, reading.time_s - self.gait_t0_s, self.config.contact_ramp)

    def _predict(self, accel_world: np.ndarray, dt: float) -> None:
        cfg, n = self.config, self.n_state
        x = self.x
        x[:3] += x[3:6] * dt + 0.5 * accel_world * dt**2
        x[3:6] += accel_world * dt
        A = np.eye(n)
        A[:3, 3:6] = dt * np.eye(3)
        trust = self._trust_now
        foot_q = [(cfg.foot_process_noise_m_s if w > 0.5 else cfg.swing_foot_noise_m_s) ** 2 * dt for w in trust]
        Q = np.diag(np.concatenate([[cfg.position_process_noise_m_s**2 * dt] * 3, [cfg.accel_noise_m_s2**2 * dt] * 3,
                                    np.repeat(foot_q, 3)]))
        self.P = A @ self.P @ A.T + Q

    def _correct(self, rot: np.ndarray, r: np.ndarray, dr: np.ndarray, trust: np.ndarray) -> None:
        cfg, nf, n = self.config, self._nf, self.n_state
        rows = 7 * nf
        H = np.zeros((rows, n))
        z = np.zeros(rows)
        noise = np.zeros(rows)
        foot_z = self._ground(self.x[6:].reshape(nf, 3)[:, :2]) + self._contact_height_m
        for i in range(nf):
            scale = 1.0 + (1.0 - trust[i]) * cfg.untrusted_noise_scale
            k = 3 * i
            H[k:k + 3, :3] = -np.eye(3)  # p_foot - p = R r_i
            H[k:k + 3, 6 + k:9 + k] = np.eye(3)
            z[k:k + 3] = rot @ r[i]
            noise[k:k + 3] = cfg.kinematics_noise_m**2  # kinematics hold in swing too
            j = 3 * nf + k  # v = -R (omega x r + J dq)
            H[j:j + 3, 3:6] = np.eye(3)
            z[j:j + 3] = -rot @ dr[i]
            noise[j:j + 3] = (cfg.foot_velocity_noise_m_s * scale) ** 2
            h = 6 * nf + i  # stance foot on the ground
            H[h, 6 + k + 2] = 1.0
            z[h] = foot_z[i]
            noise[h] = (cfg.foot_height_noise_m * scale) ** 2
        y = z - H @ self.x
        S = H @ self.P @ H.T + np.diag(noise)
        K = np.linalg.solve(S, H @ self.P).T
        self.x = self.x + K @ y
        self.P = (np.eye(n) - K @ H) @ self.P
        self.P = 0.5 * (self.P + self.P.T)
