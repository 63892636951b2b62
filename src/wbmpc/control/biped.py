"""Settings of two-legged robots: the rules `control/tuning.derive` applies on top of the size-derived
settings when the robot stands on two feet (their source reads "derived: biped" in `wbmpc info`).

A quadruped's trot keeps its CoM over the diagonal support line; a biped must move its CoM towards
the foot it will stand on during double support, and its hands, pinned in the world, fight the
pelvis' sway. So on two feet:
- the walk's period by Froude similarity from the leg length with 40 % double support
  (`wbmpc.gait.biped_walk_timing`), instead of the trot's 0.8 s scaled;
- feet lifted 7.5 % of the leg length (4.9 cm on g1), not the trot's 16 %: g1's first walking OCPs took
  28 Fatrop iterations with 10 cm steps, 15 with 5 cm;
- `support_sway`: the base xy targets lean 30 % of the way from the centre of the feet to the centre of
  the feet in stance one double-support phase later (`MPC._sway_towards_support`): the plan shifts the
  weight during double support. The OCP's nodes are dense at its start and its cost is not weighted
  by the steps, so a target that leans only once a foot is in the air came too late: g1's plans kept
  the CoM between the feet until lift-off and fell at 0.6 s. With the rotor inertias and the anchor below,
  60 % over-leant (6 s in place: 11 failed steps, 17 iterations; 30 %: 0 and 14.7);
- the force regularisation towards equal shares (eq. 3's F term) 1e-5 instead of 1e-3: at 1e-3 a
  100 N shift costs 10 per node, ten times the base position error it corrects, and g1's plans kept
  both feet equally loaded until lift-off (then fell at 0.6 s); leg posture weight 2 (the soles and the
  pelvis fix a biped's stance legs; the posture cost held the pelvis centred) and base velocity weight 5
  (g1's table raises it to 1000 while its hands are free, `control/tuning.py`: TALOS at 1000 fell walking forward);
- `free_ee_without_command`: a hand with no velocity command swings free (its pinned velocity rows
  drove g1's arm into its limits and stalled Fatrop in single support). Then no hand rows hold the trunk
  in place, so the base xy position weight gets the anchor of a robot without an arm
  (`tuning.ANCHOR_WITHOUT_ARM`, set in `tuning.derive`): g1 walking in place drifted forward into its
  ankle torque limits and fell at 1.6 s with the paper's weight, 2.5 s with 0 failed steps with 10x;
- `swing_placement`: the swing feet's horizontal velocity rows carry each foot to a landing point
  (`control/foot_placement.SwingPlacement`: under the hip at touch-down, half a stance of commanded motion
  ahead, capture-point feedback), where a quadruped's leave them free. With the light posture weight above
  nothing else makes a biped step: walking forward at 0.3 m/s g1 kept each swing foot within 3 cm of its
  lift-off while the CoM ran 9 cm past both soles, its ankles saturated and it fell at 1.1 s (79 % of
  the steps failed); with the placement it walks (10 s: 0 failed steps of 800, the mean speed of each
  gait cycle within 0.004 m/s RMS of the command).
"""

from __future__ import annotations

import dataclasses

from wbmpc.gait import biped_walk_timing

BIPED_SOURCE = "derived: biped"
BIPED_SUPPORT_SWAY = 0.3
BIPED_APEX_PER_LEG = 0.075  # swing apex / leg length: 4.9 cm on g1 (the trot's scaled 10 cm: 28 -> 15 iterations)
BIPED_BASE_LINEAR_VELOCITY_WEIGHT = 5.0
BIPED_LEG_JOINT_WEIGHT = 2.0
BIPED_CONTACT_FORCE_WEIGHT = 1e-5
# off the flat floor the walk's period (and the lean's lead) this much longer: a step up onto a tread's safe band
# lands a foot 22 cm or more ahead of the other (the band's gap and a sole's length), and the CoM must cross to
# it before the trailing foot lifts; in the 0.2 s of g1's double support it stayed 1-6 cm behind that heel
BIPED_TERRAIN_PERIOD_SCALE = 1.4


def biped_overrides(leg_length_m: float) -> dict:
    """{setting: value} (names of `RobotTuning.report`) of a two-legged robot with this leg length."""
    period_s, double_support_share = biped_walk_timing(leg_length_m)
    return {
        "gait_period_s": period_s,
        "swing.apex_height_m": BIPED_APEX_PER_LEG * leg_length_m,
        "weights.base_linear_velocity": BIPED_BASE_LINEAR_VELOCITY_WEIGHT,
        "weights.leg_joint_position": BIPED_LEG_JOINT_WEIGHT,
        "weights.contact_force": BIPED_CONTACT_FORCE_WEIGHT,
        "support_sway": BIPED_SUPPORT_SWAY,
        "support_lead_s": 0.5 * period_s * double_support_share,
        "free_ee_without_command": True,
        "swing_placement": True,
    }


def biped_on_terrain(gait_period_s: float, references):
    """(gait period, `ReferenceConfig`) of a biped walking on a terrain: both slower by BIPED_TERRAIN_PERIOD_SCALE."""
    return (gait_period_s * BIPED_TERRAIN_PERIOD_SCALE,
            dataclasses.replace(references, support_lead_s=references.support_lead_s * BIPED_TERRAIN_PERIOD_SCALE))
