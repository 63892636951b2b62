"""The robot link: which LowStates the controller accepts, and the clock it reads them on.

- `robot` (the default, strict): a Unitree robot fills every field: header (unitree_go), CRC, a `tick`
  in ms that advances, motor temperatures (a motor is present when it reports one). A LowState missing
  any of them is rejected and counted by reason; time comes from `tick`.
- `sim`: Unitree's own simulator (unitree_mujoco's `simulate_python`) leaves header, CRC, tick and
  temperatures at 0. Those unset fields are accepted and counted (a header or CRC that is set must still
  be right); the model's motors are taken as present; time comes from the receive clock wherever the
  tick does not advance (from the first such message on). Such a simulator's messages carry no time:
  if it falls behind the wall clock (a loaded machine), the controller's clock runs ahead of the
  robot's. `clock_rate` measures it: the robot's seconds per receive-clock second, from the joints'
  motion (position change against reported velocity, sum over the moving joints of
  dq dq_reported / sum |dq_reported|^2 dt).

When LowStates arrive and all are rejected, `all_rejected_message` counts them and names why, and
points a strict link that hears a simulator to `--robot-link sim`.
"""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.estimation.sensors import SensorReadings
from wbmpc.hardware.mapping import MotorMap
from wbmpc.hardware.messages import UNSET, MessageError, decode_low_state, low_state_defects

LINKS = ("robot", "sim")
TICK_CLOCK, RECEIVE_CLOCK = "tick", "receive clock"
MOVING_RAD_S = 0.5  # joints faster than this tell the clock rate (slower ones: encoder noise dominates)
MIN_RATE_EVIDENCE_RAD2 = 1.0  # sum of |dq_reported|^2 dt before a clock rate is reported


def check_link(link: str) -> str:
    if link not in LINKS:
        raise ConfigError(f"--robot-link must be robot (a Unitree robot, strict) or sim (Unitree's simulator, "
                          f"unitree_mujoco), got {link!r}")
    return link


class LowStateLink:
    """Checks LowStates for `link` and stamps their time; counts what it received, rejected and accepted."""

    def __init__(self, motors: MotorMap, link: str = "robot"):
        self.motors, self.link = motors, check_link(link)
        self.received = 0
        self.rejected: Counter = Counter()  # reason -> messages
        self.accepted_unset: Counter = Counter()  # unset field -> accepted messages (sim link)
        self.time_source = TICK_CLOCK
        self.mode_machine: int | None = None  # unitree_hg: the robot's, from its last accepted LowState
        self._last_tick: int | None = None
        self._last_time_s: float | None = None
        self._receive_offset_s = 0.0
        self._last_joints: tuple[np.ndarray, np.ndarray] | None = None
        self._rate_num = self._rate_den = 0.0

    @property
    def last_time_s(self) -> float | None:
        """Robot time of the last accepted LowState."""
        return self._last_time_s

    def reading(self, msg, received_s: float) -> SensorReadings:
        """Checked `SensorReadings` of `msg` (received at `received_s`, a monotonic clock); MessageError if rejected."""
        self.received += 1
        defects = low_state_defects(msg)
        accept = UNSET if self.link == "sim" else ()
        try:
            reading = decode_low_state(msg, self.motors, accept=accept, defects=defects)
            advancing = msg.tick != 0 and (self._last_tick is None or msg.tick > self._last_tick)
            if self.link == "robot" and not advancing:
                raise MessageError(f"LowState tick {msg.tick} does not advance (last {self._last_tick})",
                                   ("tick not advancing",))
        except MessageError as exc:
            self.rejected.update(exc.reasons)
            raise
        for field in defects:
            self.accepted_unset[field] += 1
        if not advancing and self.time_source == TICK_CLOCK:  # sim link: from here on, the receive clock
            self.time_source = RECEIVE_CLOCK
            last = self._last_time_s  # the robot time goes on from the last tick (or starts at 0)
            self._receive_offset_s = (last + 1e-3 if last is not None else 0.0) - received_s
        t = msg.tick / 1e3 if self.time_source == TICK_CLOCK else received_s + self._receive_offset_s
        if self._last_time_s is not None and t <= self._last_time_s:
            t = self._last_time_s + 1e-6  # the receive clock is monotonic; two messages in one clock step
        self._measure_clock_rate(reading.joint_position_rad, reading.joint_velocity_rad_s, t)
        self._last_tick, self._last_time_s = msg.tick, t
        if self.motors.family == "unitree_hg":
            self.mode_machine = int(msg.mode_machine)
        return dataclasses.replace(reading, time_s=t)

    def _measure_clock_rate(self, q: np.ndarray, dq: np.ndarray, t: float) -> None:
        last, self._last_joints = self._last_joints, (q, dq)
        if last is None or self._last_time_s is None:
            return
        dt = t - self._last_time_s
        mean_dq = 0.5 * (dq + last[1])
        moving = np.abs(mean_dq) > MOVING_RAD_S
        if 0 < dt < 0.1 and np.any(moving):
            self._rate_num += float((q - last[0])[moving] @ mean_dq[moving])
            self._rate_den += float(mean_dq[moving] @ mean_dq[moving]) * dt

    @property
    def clock_rate(self) -> float | None:
        """Robot seconds per second of this link's clock, from the joints' motion (None: too little motion)."""
        return self._rate_num / self._rate_den if self._rate_den >= MIN_RATE_EVIDENCE_RAD2 else None

    def all_rejected_message(self, topic: str, within_s: float) -> str:
        """Every LowState so far was rejected: how many, why, and (strict link, unset fields) what to do."""
        reasons = ", ".join(f"{reason} ({count})" for reason, count in self.rejected.most_common())
        text = f"{self.received} LowStates received on '{topic}' within {within_s:.1f} s, all rejected: {reasons}"
        if self.link == "robot" and set(self.rejected) & set(UNSET):
            text += ("; is this a simulator? Unitree's (unitree_mujoco) leaves the header, CRC, tick and motor "
                     "temperatures at 0: run with --robot-link sim")
        return text

    def summary(self) -> dict:
        return {"robot_link": self.link, "time_source": self.time_source, "accepted_unset": dict(self.accepted_unset),
                "mode_machine": self.mode_machine, "clock_rate": self.clock_rate}
