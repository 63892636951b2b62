"""The robot link's timing as deploy measures it before the MPC phase: the command period and the motor law's hold.

One LowCmd answers each LowState, so the intervals between LowStates (robot time; the sim link's receive clock)
are the command period. Unitree's simulator (unitree_mujoco) evaluates eq. (10) once per LowCmd and holds its
torque until the next one: the hold is the longest usual interval (95th percentile). A robot's motor drivers
evaluate it at kHz with the last LowCmd's references (`ROBOT_MOTOR_LAW_PERIOD_S`). The MPC phase takes the
tuned gains for that hold (`RobotTuning.gains_at`, `wbmpc.control.joint_loop`) and samples eq. (9) half a
command period ahead, at the middle of the time its command is held.
"""

from __future__ import annotations

import numpy as np

# a robot's motor drivers evaluate eq. (10) at kHz with the last LowCmd's references: the hold its gains must
# stand (`wbmpc.control.joint_loop`); at 1 ms no preset's tuned Kd is capped
ROBOT_MOTOR_LAW_PERIOD_S = 1e-3
MAX_INTERVALS = 5000  # the first 10 s at 500 Hz: stand-up and hold give enough
UNMEASURED_PERIOD_S = 2e-3  # the period taken when fewer than two intervals arrived (a Go2's 500 Hz LowCmd)


class LinkTiming:
    """The intervals of the LowStates noted (`note`) and what they imply: `period_s`, `hold_s`, `reference_lead_s`."""

    def __init__(self, robot_link: str):
        """`robot_link`: "sim" (the law held per command, unitree_mujoco) or "robot" (motor drivers at kHz)."""
        self.robot_link = robot_link
        self._intervals: list[float] = []
        self._last_s: float | None = None

    def note(self, t_s: float) -> None:
        """A LowState's robot time (s)."""
        if self._last_s is not None and len(self._intervals) < MAX_INTERVALS:
            self._intervals.append(t_s - self._last_s)
        self._last_s = t_s

    def _measured(self) -> np.ndarray:
        # the first interval spans the start-up (the MPC built, the sport mode released): left out
        return np.array(self._intervals[1:]) if len(self._intervals) > 1 else np.array([UNMEASURED_PERIOD_S])

    @property
    def period_s(self) -> float:
        """The command period: the median interval."""
        return float(np.median(self._measured()))

    @property
    def hold_s(self) -> float:
        """How long the motor law's torque is held: the 95th percentile interval on the sim link, the motor
        drivers' period on a robot."""
        return float(np.percentile(self._measured(), 95)) if self.robot_link == "sim" else ROBOT_MOTOR_LAW_PERIOD_S

    @property
    def reference_lead_s(self) -> float:
        """Eq. (9) sampled this far ahead: the middle of a command's hold."""
        return 0.5 * self.period_s

    def for_mpc_phase(self, joint_loop_gains, kp: np.ndarray, kd: np.ndarray, legs: np.ndarray) -> tuple:
        """(kp, kd, eq. 9's lead (s), the report's `joint_loop`) of the MPC phase: `joint_loop_gains(hold_s)`'s
        (a `PdGains`; None: `kp`, `kd` as they are, per joint), the period and hold measured (ms), the legs' gains."""
        if joint_loop_gains is not None:
            kp, kd = joint_loop_gains(self.hold_s).vectors(~legs)
        summary = {"command_period_ms": 1e3 * self.period_s, "hold_ms": 1e3 * self.hold_s,
                   "kd_leg": float(kd[legs][0]) if legs.any() else None,
                   "kp_leg": float(kp[legs][0]) if legs.any() else None}
        return kp, kd, self.reference_lead_s, summary
