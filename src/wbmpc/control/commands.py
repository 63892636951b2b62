"""`Commands`: what the robot is asked to do at one MPC step (section V-B)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wbmpc.errors import ConfigError, check_number
from wbmpc.ocp.objects import ObjectCommand


@dataclass
class Commands:
    """Tracking commands (section V-B): base velocity in the heading frame, arm velocity/force in world.

    `ee_velocity_m_s=None` (default) moves the end-effector with the commanded base velocity, so
    the arm is carried along when the robot walks; an array makes it a world-frame command (eq. 7).
    `ee_force_n` is the force the end-effector applies on the environment; the robot feels its
    opposite (the contact force F_arm of eq. 2).
    """

    base_velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_yaw_rate_rad_s: float = 0.0
    ee_velocity_m_s: np.ndarray | None = None
    ee_force_n: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_height_m: float | None = None
    # with an object model in the OCP (OcpConfig.object_model): the object's measured state and its path; the
    # arm force is then the OCP's (ee_force_n and ee_velocity_m_s are not used)
    object_command: ObjectCommand | None = None
    # walk in the MPC's gait (True) or stand on every foot (False), switched where the feet allow it
    # (`GaitClock.follow`); None: the gait as scheduled
    walking: bool | None = None

    def __post_init__(self):
        """Refuse NaN/inf and wrong shapes here: a NaN command would give NaN torques."""
        for name in ("base_velocity_m_s", "ee_velocity_m_s", "ee_force_n"):
            value = getattr(self, name)
            if value is None and name == "ee_velocity_m_s":
                continue
            array = np.asarray(value, dtype=float)
            if array.shape != (3,) or not np.all(np.isfinite(array)):
                raise ConfigError.for_field(name, f"must be 3 finite numbers, got {value!r}")
            setattr(self, name, array)
        check_number("base_yaw_rate_rad_s", self.base_yaw_rate_rad_s, unit="rad/s")
        check_number("base_height_m", self.base_height_m, low=0.0, low_open=True, unit="m", allow_none=True)


def object_reference(model, command: ObjectCommand | None, times_s: np.ndarray) -> np.ndarray:
    """The object's commanded path at `times_s` ((n, n_states)) for an MPC that plans with `model` (an
    `wbmpc.ocp.objects.ObjectModel`) inside its OCP; refuses a missing command, a state or a path of the wrong
    size, a non-finite path."""
    if command is None:
        raise ConfigError(f"this MPC plans with the {model.name} inside the OCP: each step's commands need its "
                          "measured state and path (Commands.object_command)")
    if command.state.size != model.n_states:
        raise ConfigError(f"the {model.name}'s state has {model.n_states} values ({', '.join(model.state_names)}), "
                          f"got {command.state.size}")
    reference = np.asarray(command.reference(times_s), dtype=float)
    if reference.shape != (len(times_s), model.n_states) or not np.all(np.isfinite(reference)):
        raise ConfigError(f"the {model.name}'s path must give {model.n_states} finite values per node time, got "
                          f"shape {reference.shape}")
    return reference
