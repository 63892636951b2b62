"""What every plant shares: the `Plant` protocol, its base configuration, input checks, recording.

State convention (all plants): pinocchio layout. q = [base position in world (m), base
quaternion xyzw, joint angles (rad) in `robot.joint_names` order]; v = [base linear velocity in
the BASE frame (m/s), base angular velocity in the base frame (rad/s), joint velocities (rad/s)].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

from wbmpc.errors import ConfigError, ModelError, WbmpcError
from wbmpc.robots import JointValues, RobotModel, joint_values

C = TypeVar("C", bound="PlantConfig")
DRIVE_TRAIN_FIELDS = ("joint_armature_kg_m2", "joint_damping_nm_s_per_rad", "joint_frictionloss_nm")


class PlantInputError(ConfigError, ValueError):
    """A plant was given an input of the wrong size, a non-finite value or an invalid setting."""


class PlantDivergedError(WbmpcError, RuntimeError):
    """The simulation produced non-finite accelerations or states (usually too large a step or gains)."""


@dataclass(frozen=True)
class PlantConfig:
    """Settings shared by every plant (units in the names).

    The plant's drive train is independent of the controller's model (`RobotSpec.armature_kg_m2`,
    ...), so a controller can be run against a robot whose rotors and friction it ignores or
    misestimates (paper section VI-D). Each is one value for all joints or {joint name: value}:
    `joint_armature_kg_m2` (rotor inertia), `joint_damping_nm_s_per_rad` (viscous friction) and
    `joint_frictionloss_nm` (Coulomb / dry friction; MuJoCo only).
    """

    dt_s: float = 1e-3
    friction_mu: float = 0.8
    joint_damping_nm_s_per_rad: JointValues = 0.0
    joint_armature_kg_m2: JointValues = 0.0
    joint_frictionloss_nm: JointValues = 0.0
    record_every_n_steps: int = 1  # 0 disables recording

    def joint_array(self, robot: RobotModel, name: str) -> np.ndarray:
        """The drive-train field `name` as one value per joint of `robot` (robot.joint_names order)."""
        try:
            return joint_values(getattr(self, name), robot.joint_names, name)
        except ModelError as exc:
            raise PlantInputError(str(exc)) from exc

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt_s) and 0 < self.dt_s <= 0.05):
            raise PlantInputError(f"dt_s must be in (0, 0.05] s, got {self.dt_s}")
        if not (np.isfinite(self.friction_mu) and self.friction_mu >= 0):
            raise PlantInputError(f"friction_mu must be a finite number >= 0, got {self.friction_mu}")
        for name in DRIVE_TRAIN_FIELDS:
            value = getattr(self, name)
            try:  # values checked here, joint names when a plant resolves them for its robot
                joint_values(value, tuple(value) if isinstance(value, dict) else (), name)
            except ModelError as exc:
                raise PlantInputError(str(exc)) from exc
        if self.record_every_n_steps < 0:
            raise PlantInputError(f"record_every_n_steps must be >= 0 (0 disables), got {self.record_every_n_steps}")


@dataclass
class Recording:
    """Time stamps and configurations (pinocchio layout) sampled during a run, for replays and plots."""

    time_s: list[float] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)

    def append(self, time_s: float, q: np.ndarray) -> None:
        self.time_s.append(float(time_s))
        self.q.append(np.array(q, dtype=float))

    def clear(self) -> None:
        self.time_s.clear()
        self.q.clear()

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(time_s of shape (N,), q of shape (N, nq))."""
        q = np.array(self.q) if self.q else np.zeros((0, 0))
        return np.array(self.time_s), q

    def __len__(self) -> int:
        return len(self.time_s)


@runtime_checkable
class Plant(Protocol):
    """A simulated (or real) robot stepped with joint torques; states in pinocchio layout."""

    robot: RobotModel
    config: PlantConfig
    recording: Recording

    @property
    def time_s(self) -> float: ...

    @property
    def dt_s(self) -> float: ...

    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        """Set the state (default: `robot.q_nominal`, zero velocity), time to 0, clear the recording."""

    def step(self, tau_joints: np.ndarray) -> np.ndarray:
        """Apply joint torques (N m, `robot.joint_names` order) for one step of `config.dt_s`.

        Torques are clamped to +-`robot.tau_max`; the applied torques are returned.
        """

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) in pinocchio layout (copies)."""

    def apply_base_velocity_kick(self, dv_world_m_s: np.ndarray) -> None:
        """Add a world-frame velocity change to the base (a push)."""

    def contact_forces(self) -> np.ndarray:
        """World-frame force (N) on each foot from the environment during the last step, shape (n_feet, 3)."""


def specialised_config(config: PlantConfig | None, cls: type[C]) -> C:
    """`config` as the plant's own config class: defaults if None, shared fields kept if a base `PlantConfig`."""
    if config is None:
        return cls()
    if isinstance(config, cls):
        return config
    if type(config) is PlantConfig:
        return cls(**{name: getattr(config, name) for name in PlantConfig.__dataclass_fields__})
    raise PlantInputError(f"{cls.__name__[:-6]} needs a {cls.__name__} or PlantConfig, got {type(config).__name__}")


# ---------------------------------------------------------------------------- input checks
def checked_torques(robot: RobotModel, tau_joints: np.ndarray) -> np.ndarray:
    """Validate a joint torque vector and clamp it to +-tau_max."""
    tau = np.asarray(tau_joints, dtype=float)
    if tau.shape != (robot.n_joints,):
        raise PlantInputError(
            f"tau_joints has shape {tau.shape}, expected ({robot.n_joints},): one torque per joint in "
            f"robot.joint_names order ({', '.join(robot.joint_names)})"
        )
    bad = ~np.isfinite(tau)
    if bad.any():
        names = [robot.joint_names[i] for i in np.flatnonzero(bad)]
        raise PlantInputError(f"tau_joints contains NaN/inf for joints {names}")
    return np.clip(tau, -robot.tau_max, robot.tau_max)


def checked_state(robot: RobotModel, q: np.ndarray | None, v: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Validate (q, v) in pinocchio layout; defaults are `q_nominal` and zero velocity.

    The base quaternion is renormalised; a quaternion far from unit length is rejected.
    """
    q = np.array(robot.q_nominal if q is None else q, dtype=float)
    v = np.zeros(robot.nv) if v is None else np.array(v, dtype=float)
    for label, vec, size in (("q", q, robot.nq), ("v", v, robot.nv)):
        if vec.shape != (size,):
            raise PlantInputError(f"{label} has shape {vec.shape}, expected ({size},) (pinocchio layout)")
        if not np.all(np.isfinite(vec)):
            raise PlantInputError(f"{label} contains NaN/inf at indices {np.flatnonzero(~np.isfinite(vec)).tolist()}")
    norm = np.linalg.norm(q[3:7])
    if abs(norm - 1.0) > 1e-3:
        raise PlantInputError(f"base quaternion q[3:7] (xyzw) must have unit norm, got norm {norm:.6f}")
    q[3:7] /= norm
    return q, v


def checked_vector3(name: str, value: np.ndarray) -> np.ndarray:
    """A finite 3-vector or a PlantInputError naming the argument."""
    vec = np.asarray(value, dtype=float)
    if vec.shape != (3,) or not np.all(np.isfinite(vec)):
        raise PlantInputError(f"{name} must be a finite 3-vector, got {value!r}")
    return vec


def quat_xyzw_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion given as (x, y, z, w)."""
    x, y, z, w = quat_xyzw
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
