"""The motor law of eq. (10) under a zero-order hold: the damping a joint loop of a given rate can carry.

A command (eq. 9's references with Kp, Kd) reaches the motors at the joint loop's rate; where the law is
evaluated once per command with the joint readings of that moment and its torque held until the next
(unitree_mujoco's LowCmd callback; `LoopConfig.motor_law = "held"`), the damper is an explicit, sampled one.
For a joint-space mode of inertia I (an eigenvalue of the joint-space inertia matrix, base fixed, as a
swinging leg sees it) held over T seconds, with a = Kp T^2 / I and b = Kd T / I, the exact discretisation is

    q+ = (1 - a/2) q + T (1 - b/2) v,   v+ = -(a / T) q + (1 - b) v,   characteristic z^2 - (2 - a/2 - b) z + 1 - b + a/2,

stable iff 0 < b - a/2 and b < 2 (Jury). With Kp = 0 (the paper's legs) the velocity error of the mode
shrinks by (1 - b) per hold: b = 1 removes it in one hold (dead-beat), b > 1 overshoots, b >= 2 grows.
The legs' lightest mode is the calf swinging with the thigh (Go2 0.0030 kg m^2 at its standing pose, its
calf's diagonal 0.0050): Go2's Kd 2.57 held 2 ms is b = 1.7, held 5 ms (200 Hz) b = 4.3, and the swing
legs shook until the MPC failed (trot forward 0.3 m/s fell 1.2 s in at 200 Hz; 0 failed steps when the same
commands are re-evaluated every 1 ms physics step, `motor_law = "continuous"`).

`held_gains` therefore caps each Kd at `DAMPER_BOUND` I_min / T for the longest hold T the plant can
apply (one joint-loop period plus its jitter, at least one physics step), and leaves gains below the bound
alone: the robot's tuned Kd is what it would run with a motor driver's kHz loop.

The bound, 1.75, was chosen by measurement. 1 (dead-beat: no overshoot, twice the hold to instability) capped
Go2's Kd at the paper's 500 Hz too (2.57 -> 1.51), with equal nominal tracking (trot forward 0.3 m/s: 0.032 m/s
either way) but less robustness: of the first stress-campaign plants (delays of 13-26 ms, joint damping and dry
friction 3-6x, sensor noise 3x), two fell 1.6 and 4.0 s in at Kd 1.51 and stayed up at 2.57. At 1.75 no
quadruped preset's Kd changes at 500 Hz but go2_z1's (2.96 -> 2.65) and the Solos'; Go2 at 200 Hz gets 1.06.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from wbmpc.control.interpolator import PdGains
from wbmpc.robots import RobotModel

# largest Kd T / I of the lightest joint-space mode (module docstring): 2 is the instability, 1 dead-beat
DAMPER_BOUND = 1.75


def hold_s(joint_loop_hz: float, jitter_ms: float = 0.0, motor_law: str = "held", physics_dt_s: float = 1e-3) -> float:
    """The longest time a motor torque is held: one joint-loop period plus its jitter (at least one physics
    step) where the law is evaluated once per command; one physics step where it runs continuously."""
    if motor_law == "continuous":
        return physics_dt_s
    period = 1.0 / joint_loop_hz + jitter_ms / 1e3
    return max(physics_dt_s * np.ceil(period / physics_dt_s - 1e-9), physics_dt_s)


def joint_mode_inertia(robot: RobotModel, joints: np.ndarray, q: np.ndarray | None = None) -> float | None:
    """Smallest eigenvalue (kg m^2) of the joint-space inertia matrix of `joints` (a boolean mask over
    `robot.joint_names`), base fixed, with the model's armature, at `q` (default the nominal pose); None when
    the mask is empty."""
    joints = np.asarray(joints, dtype=bool)
    if not joints.any():
        return None
    model = robot.model
    data = model.createData()
    mass = pin.crba(model, data, robot.q_nominal if q is None else q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    joint_space = mass[6:, 6:] + np.diag(np.broadcast_to(np.asarray(robot.armature_kg_m2, dtype=float), (robot.n_joints,)))
    return float(np.linalg.eigvalsh(joint_space[np.ix_(joints, joints)])[0])


def damper_ratio(kd: float, inertia_kg_m2: float | None, hold: float) -> float:
    """b = Kd T / I of the lightest mode (0 without one)."""
    return 0.0 if inertia_kg_m2 is None else kd * hold / inertia_kg_m2


def held_gains(gains: PdGains, leg_inertia_kg_m2: float | None, arm_inertia_kg_m2: float | None,
               hold: float) -> PdGains:
    """`gains` with each Kd at most `DAMPER_BOUND` I / T (module docstring); Kp unchanged (b - a/2 > 0 holds
    for every Kp below 2 Kd / T: 1000 N m/rad at Kd 2.5 and 5 ms)."""
    kd_leg, kd_arm = gains.kd_leg, gains.kd_arm
    if leg_inertia_kg_m2 is not None:
        kd_leg = min(kd_leg, DAMPER_BOUND * leg_inertia_kg_m2 / hold)
    if arm_inertia_kg_m2 is not None:
        kd_arm = min(kd_arm, DAMPER_BOUND * arm_inertia_kg_m2 / hold)
    if (kd_leg, kd_arm) == (gains.kd_leg, gains.kd_arm):
        return gains
    return dataclasses.replace(gains, kd_leg=kd_leg, kd_arm=kd_arm)


def unstable_gains(gains: PdGains, leg_inertia_kg_m2: float | None, arm_inertia_kg_m2: float | None,
                   hold: float) -> list[str]:
    """The gains whose held damper is unstable (b >= 2 or b <= a / 2), named with their ratio."""
    out = []
    for part, kp, kd, inertia in (("leg", gains.kp_leg, gains.kd_leg, leg_inertia_kg_m2),
                                  ("arm", gains.kp_arm, gains.kd_arm, arm_inertia_kg_m2)):
        if inertia is None:
            continue
        b, a = kd * hold / inertia, kp * hold**2 / inertia
        if b >= 2.0 or (kp > 0 and b <= a / 2):
            out.append(f"kd_{part} {kd:.3g} N m s/rad held {1e3 * hold:.3g} ms on a {inertia:.2g} kg m^2 joint mode: "
                       f"Kd T / I = {b:.2f} (stable below 2; the tuned gains are capped at {DAMPER_BOUND:g})")
    return out
