"""MPC settings of two-legged robots, in one place (to be joined with the robot-derived tuning).

A quadruped's trot keeps its CoM over the diagonal support line; a biped must move its CoM towards
the foot it will stand on during double support, and its hands, pinned in the world, fight the
pelvis' sway. So on two feet:
- `support_sway`: the base xy targets lean halfway from the centre of the feet to the centre of each
  node's stance feet (`MPC._sway_towards_support`);
- base linear velocity weight 5 instead of 50: at 50 it costs more than the position error it corrects,
  and g1's plans kept the CoM between the feet until lift-off (then fell at 0.7 s);
- `free_ee_without_command`: a hand with no velocity command swings free (its pinned velocity rows
  drove g1's arm into its limits and stalled Fatrop in single support).
The gait itself (period from leg length, double-support share) is `wbmpc.gait.biped_walk_timing`.
"""

from __future__ import annotations

import dataclasses

from wbmpc.control.mpc import CostWeights
from wbmpc.robots import RobotModel

BIPED_SUPPORT_SWAY = 0.5
BIPED_BASE_LINEAR_VELOCITY_WEIGHT = 5.0


def biped_mpc_settings(robot: RobotModel, weights: CostWeights) -> dict:
    """MpcConfig fields for a two-legged robot (weights derived from `weights`); {} for other robots."""
    if len(robot.feet) != 2:
        return {}
    return {
        "weights": dataclasses.replace(weights, base_linear_velocity=BIPED_BASE_LINEAR_VELOCITY_WEIGHT),
        "support_sway": BIPED_SUPPORT_SWAY,
        "free_ee_without_command": True,
    }
