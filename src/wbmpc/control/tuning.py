"""Per-robot control tuning: cost weights, joint PD gains, swing height and gait period.

`CostWeights()` and `PdGains()` are tuned on the paper's 61 kg B1 + Z1. A robot a quarter of that
mass tracks the same posture weights four times faster (same cost, a quarter of the inertia) and
runs its light legs into their torque limits with the same damping gain, so presets may carry
their own settings here; a robot without an entry gets the defaults. The scenario runner applies
them; explicit options (e.g. `--kp/--kd`) still win.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from wbmpc.control.interpolator import PdGains
from wbmpc.control.mpc import CostWeights
from wbmpc.gait import SwingProfile
from wbmpc.robots import RobotModel


@dataclass(frozen=True)
class RobotTuning:
    """Control settings for one robot (units in the names); `note` says what was checked."""

    weights: CostWeights = field(default_factory=CostWeights)
    gains: PdGains = field(default_factory=PdGains)
    swing: SwingProfile = field(default_factory=SwingProfile)
    gait_period_s: float | None = None  # None: the gait's default
    note: str = ""


def scaled_weights(scale: float, base: CostWeights | None = None) -> CostWeights:
    """Tracking weights (posture and velocities) times `scale`; the a/F/tau regularisation kept.

    With scale = robot mass / B1-Z1 mass the tracking cost keeps its ratio to the robot's inertia.
    """
    base = base or CostWeights()
    return CostWeights(
        base_position=tuple(scale * w for w in base.base_position),
        base_orientation=tuple(scale * w for w in base.base_orientation),
        leg_joint_position=scale * base.leg_joint_position,
        arm_joint_position=scale * base.arm_joint_position,
        base_linear_velocity=scale * base.base_linear_velocity,
        base_angular_velocity=scale * base.base_angular_velocity,
        joint_velocity=scale * base.joint_velocity,
        acceleration=base.acceleration,
        contact_force=base.contact_force,
        joint_torque=base.joint_torque,
    )


TUNINGS: dict[str, RobotTuning] = {}


def tuning_for(robot: RobotModel) -> RobotTuning:
    """The tuning of a preset (by robot name), or the defaults."""
    return TUNINGS.get(robot.name, RobotTuning())
