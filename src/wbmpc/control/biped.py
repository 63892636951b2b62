"""MPC settings of two-legged robots, in one place (to be joined with the robot-derived tuning).

A quadruped's trot keeps its CoM over the diagonal support line; a biped must move its CoM towards
the foot it will stand on during double support, and its hands, pinned in the world, fight the
pelvis' sway. So on two feet:
- `support_sway`: the base xy targets lean 60 % of the way from the centre of the feet to the centre of
  the feet in stance one double-support phase later (`MPC._sway_towards_support`): the plan shifts the
  weight during double support. The OCP's nodes are dense at its start and its cost is not weighted
  by the steps, so a target that leans only once a foot is in the air came too late: g1's plans kept
  the CoM between the feet until lift-off and fell at 0.6 s;
- the force regularisation towards equal shares (eq. 3's F term) 1e-5 instead of 1e-3: at 1e-3 a
  100 N shift costs 10 per node, ten times the base position error it corrects, and g1's plans kept
  both feet equally loaded until lift-off (then fell at 0.6 s); leg posture weight 2 (the soles and the
  pelvis fix a biped's stance legs; the posture cost held the pelvis centred) and base velocity weight 5;
- `free_ee_without_command`: a hand with no velocity command swings free (its pinned velocity rows
  drove g1's arm into its limits and stalled Fatrop in single support).
The gait itself (period from leg length, double-support share) is `wbmpc.gait.biped_walk_timing`.
"""

from __future__ import annotations

import dataclasses

from wbmpc.control.mpc import CostWeights
from wbmpc.gait import biped_walk_timing
from wbmpc.robots import RobotModel

BIPED_SUPPORT_SWAY = 0.6
BIPED_BASE_LINEAR_VELOCITY_WEIGHT = 5.0
BIPED_LEG_JOINT_WEIGHT = 2.0
BIPED_CONTACT_FORCE_WEIGHT = 1e-5


def biped_mpc_settings(robot: RobotModel, weights: CostWeights) -> dict:
    """MpcConfig fields for a two-legged robot (weights derived from `weights`); {} for other robots."""
    if len(robot.feet) != 2:
        return {}
    period_s, double_support_share = biped_walk_timing(float(robot.q_nominal[2]))
    return {
        "weights": dataclasses.replace(weights, base_linear_velocity=BIPED_BASE_LINEAR_VELOCITY_WEIGHT,
                                      leg_joint_position=BIPED_LEG_JOINT_WEIGHT, contact_force=BIPED_CONTACT_FORCE_WEIGHT),
        "support_sway": BIPED_SUPPORT_SWAY,
        "support_lead_s": 0.5 * period_s * double_support_share,
        "free_ee_without_command": True,
    }
