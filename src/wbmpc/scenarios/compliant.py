"""`compliant` (section VI-C): arm PD gains lowered, end-effector force target zero and velocity target zero
plus a slow return to the nominal place (`--compliant-return 0` for the paper's pure zero); a scripted hand moves
the end-effector back, left and down through a capped spring.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from wbmpc.control.commands import Commands
from wbmpc.control.interpolator import PdGains
from wbmpc.control.loop import Event
from wbmpc.scenarios.arm_statics import nominal_ee_position
from wbmpc.scenarios.base import Scenario, ScenarioOptions
from wbmpc.scenarios.feedback import EeState, yaw_rotation
from wbmpc.scenarios.signals import arm_torque_metrics
from wbmpc.sim.objects import ExternalHand, HandPush, Scene


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
        ee = EeState(robot)
        offset = yaw_rotation(robot.q_nominal).T @ (nominal_ee_position(robot) - robot.q_nominal[:3])
        gain = self.options.compliant_return_gain_1_s

        def command(t_s, q, v):
            velocity = np.zeros(3)
            if gain > 0:
                velocity = gain * (q[:3] + yaw_rotation(q) @ offset - ee.position(q))
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
        out.update(arm_torque_metrics(robot, log))
        return out
