"""Robot sensors read from a MuJoCo plant: IMU and joint encoders, as a Unitree robot reports them.

The IMU sits at the base frame origin (Unitree's IMU is in the trunk). Each channel has Gaussian
noise, a constant bias drawn once per run, quantisation, a sample rate (sample-and-hold between
samples) and dropouts (the previous sample is repeated and the reading is flagged `lost`).
Orientation is what the IMU's onboard attitude filter reports: roll and pitch accurate to the
noise, yaw drifting slowly (no magnetometer), as on Unitree robots.

Default figures (stated, not measured on hardware): IMU and encoders at 500 Hz (Unitree's
LowState rate); gyro noise 0.005 rad/s and bias 0.002 rad/s; accelerometer noise 0.05 m/s^2 and
bias 0.02 m/s^2; orientation noise 0.002 rad, yaw drift 0.001 rad/s; encoders: quantisation
2 pi / 2^15 / 9.1 rad (15-bit rotor encoder behind a 9.1:1 gearbox, like the A1/B1 motors),
velocity noise 0.02 rad/s; 0.1 % dropouts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import mujoco
import numpy as np
import pinocchio as pin

from wbmpc.errors import ConfigError


@dataclass(frozen=True)
class ImuConfig:
    rate_hz: float = 500.0
    gyro_noise_rad_s: float = 0.005
    gyro_bias_rad_s: float = 0.002  # std of the constant bias drawn at the start
    accel_noise_m_s2: float = 0.05
    accel_bias_m_s2: float = 0.02
    orientation_noise_rad: float = 0.002
    yaw_drift_rad_s: float = 0.001
    dropout_probability: float = 0.001


@dataclass(frozen=True)
class EncoderConfig:
    rate_hz: float = 500.0
    position_quantum_rad: float = 2 * np.pi / 2**15 / 9.1
    position_noise_rad: float = 0.0
    velocity_noise_rad_s: float = 0.02
    velocity_quantum_rad_s: float = 0.0
    dropout_probability: float = 0.001


@dataclass(frozen=True)
class SensorConfig:
    """Sensor models; `noiseless()` gives perfect sensors (for tests against the truth)."""

    imu: ImuConfig = field(default_factory=ImuConfig)
    encoders: EncoderConfig = field(default_factory=EncoderConfig)
    foot_contact_threshold_n: float = 20.0  # optional foot contact switches: force above this
    seed: int = 0

    def __post_init__(self):
        for part in (self.imu, self.encoders):
            for name, value in vars(part).items():
                if not (np.isfinite(value) and value >= 0):
                    raise ConfigError(f"sensor setting {type(part).__name__}.{name} must be a finite number >= 0, got {value}")
            if not part.rate_hz > 0:
                raise ConfigError(f"{type(part).__name__}.rate_hz must be positive, got {part.rate_hz}")
            if part.dropout_probability >= 1:
                raise ConfigError(f"{type(part).__name__}.dropout_probability must be < 1, got {part.dropout_probability}")

    def scaled(self, factor: float) -> "SensorConfig":
        """Every noise, bias and drift x `factor` (rates, quantisation and dropouts kept): a sensor set better or
        worse than these defaults (the reality-gap campaign's `sensor_noise_scale`)."""
        if not (np.isfinite(factor) and factor >= 0):
            raise ConfigError(f"sensor noise factor must be a finite number >= 0, got {factor}")
        noisy = ("noise", "bias", "drift")
        parts = [dataclasses.replace(part, **{name: value * factor for name, value in vars(part).items()
                                              if any(word in name for word in noisy)})
                 for part in (self.imu, self.encoders)]
        return dataclasses.replace(self, imu=parts[0], encoders=parts[1])

    @staticmethod
    def noiseless(rate_hz: float = 500.0) -> "SensorConfig":
        return SensorConfig(
            imu=ImuConfig(rate_hz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            encoders=EncoderConfig(rate_hz, 0.0, 0.0, 0.0, 0.0, 0.0),
        )


@dataclass
class SensorReadings:
    """One sample of everything the robot reports (what LowState carries).

    quaternion_xyzw: base orientation in the world (IMU attitude filter); gyro_rad_s and
    accel_m_s2: angular velocity and specific force (acceleration minus gravity) in the base frame;
    joint positions/velocities in `robot.joint_names` order; foot_contact: switches in `robot.feet` order.
    """

    time_s: float
    quaternion_xyzw: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    joint_position_rad: np.ndarray
    joint_velocity_rad_s: np.ndarray
    foot_contact: np.ndarray
    imu_lost: bool = False
    encoders_lost: bool = False


class Sensors:
    """Samples `SensorReadings` from a `MujocoPlant` at the configured rates."""

    def __init__(self, plant, config: SensorConfig = SensorConfig()):
        if not hasattr(plant, "model") or not isinstance(plant.model, mujoco.MjModel):
            raise ConfigError("sensors read a MuJoCo plant (accelerations and contacts); use --plant mujoco")
        self.plant, self.config, self.robot = plant, config, plant.robot
        self._base_body = plant.model.body(plant.body_name(1)).id
        self._rng = np.random.default_rng(config.seed)
        imu, n = config.imu, self.robot.n_joints
        self._gyro_bias = self._rng.normal(0, imu.gyro_bias_rad_s, 3) if imu.gyro_bias_rad_s else np.zeros(3)
        self._accel_bias = self._rng.normal(0, imu.accel_bias_m_s2, 3) if imu.accel_bias_m_s2 else np.zeros(3)
        self._acc6 = np.zeros(6)
        self._last: SensorReadings | None = None
        self._next_imu_s = self._next_enc_s = -np.inf
        self._n = n

    def read(self) -> SensorReadings:
        """The current sample: new channels where their rate is due, the held sample otherwise."""
        t, cfg, rng = self.plant.time_s, self.config, self._rng
        imu_due, enc_due = t >= self._next_imu_s - 1e-9, t >= self._next_enc_s - 1e-9
        if self._last is not None and not (imu_due or enc_due):
            return self._last
        q, v = self.plant.state()
        if self._last is None:  # first sample: every channel, no dropout
            reading = SensorReadings(t, *self._imu(q, v, t), *self._encoders(q, v), self._foot_contacts())
        else:
            reading = dataclasses.replace(self._last, time_s=t, foot_contact=self._foot_contacts(),
                                          imu_lost=False, encoders_lost=False)
            if imu_due:
                if rng.random() < cfg.imu.dropout_probability:
                    reading.imu_lost = True
                else:
                    reading.quaternion_xyzw, reading.gyro_rad_s, reading.accel_m_s2 = self._imu(q, v, t)
            if enc_due:
                if rng.random() < cfg.encoders.dropout_probability:
                    reading.encoders_lost = True
                else:
                    reading.joint_position_rad, reading.joint_velocity_rad_s = self._encoders(q, v)
        if imu_due:
            self._next_imu_s = _next_sample(self._next_imu_s, t, cfg.imu.rate_hz)
        if enc_due:
            self._next_enc_s = _next_sample(self._next_enc_s, t, cfg.encoders.rate_hz)
        self._last = reading
        return reading

    def _imu(self, q: np.ndarray, v: np.ndarray, t: float):
        imu, rng, m, d = self.config.imu, self._rng, self.plant.model, self.plant.data
        mujoco.mj_rnePostConstraint(m, d)
        # [angular; linear] acceleration of the base frame origin (XBODY, not the inertial frame) in
        # base axes; MuJoCo's cacc starts from -gravity, so this is the specific force measured
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_XBODY, self._base_body, self._acc6, 1)
        accel = self._acc6[3:] + self._accel_bias + rng.normal(0, imu.accel_noise_m_s2, 3)
        gyro = v[3:6] + self._gyro_bias + rng.normal(0, imu.gyro_noise_rad_s, 3)
        error = rng.normal(0, imu.orientation_noise_rad, 3) + np.array([0.0, 0.0, imu.yaw_drift_rad_s * t])
        rot = pin.exp3(error) @ pin.Quaternion(q[3:7]).toRotationMatrix()  # error in the world frame
        quat = pin.Quaternion(rot).coeffs().copy()
        return quat, gyro, accel

    def _encoders(self, q: np.ndarray, v: np.ndarray):
        enc, rng = self.config.encoders, self._rng
        position = q[7:] + (rng.normal(0, enc.position_noise_rad, self._n) if enc.position_noise_rad else 0.0)
        velocity = v[6:] + (rng.normal(0, enc.velocity_noise_rad_s, self._n) if enc.velocity_noise_rad_s else 0.0)
        if enc.position_quantum_rad:
            position = np.round(position / enc.position_quantum_rad) * enc.position_quantum_rad
        if enc.velocity_quantum_rad_s:
            velocity = np.round(velocity / enc.velocity_quantum_rad_s) * enc.velocity_quantum_rad_s
        return position, velocity

    def _foot_contacts(self) -> np.ndarray:
        forces = self.plant.contact_forces()
        return np.linalg.norm(forces, axis=1) > self.config.foot_contact_threshold_n


def _next_sample(previous_s: float, t_s: float, rate_hz: float) -> float:
    """Next sample time on the rate's grid (re-anchored at t when the reader fell behind)."""
    period = 1.0 / rate_hz
    following = previous_s + period
    return following if following > t_s + 1e-9 else t_s + period
