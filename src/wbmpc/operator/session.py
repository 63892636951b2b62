"""`OperatorSession`: sources -> board -> shaper, the command source of a run or of deploy's MPC phase.

Called once per MPC step (`session(t, q, v) -> Commands`, the loop's `CommandSource`), it moves the board's
clock, polls the sources that the loop drives (a script, the remote's LowState bytes), reads the newest command
and shapes it. Threaded sources (keyboard, gamepad, DDS topics) post whenever they have something; the step
after a post uses it, so the latency from the source's timestamp to the MPC's references is at most one MPC
period. Each step's use of the board is recorded (`steps`) for the latency and the per-segment metrics.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from wbmpc.control.commands import Commands
from wbmpc.operator.board import CommandBoard, Posted
from wbmpc.operator.command import OperatorCommand, OperatorLimits
from wbmpc.operator.shaper import CommandShaper, RampLimits
from wbmpc.robots import RobotModel


class OperatorSession:
    def __init__(self, robot: RobotModel, limits: OperatorLimits, sources: list, initial: OperatorCommand,
                 base_commands: Callable[[float, np.ndarray, np.ndarray], Commands] | None = None,
                 ramp: RampLimits = RampLimits(), gait_mirror=None, passthrough_motion: bool = False):
        """`base_commands`: the scenario's own commands (the hand's, forces) that the operator's fields
        override; `gait_mirror`: a `GaitClock` that must follow the stand/walk switches of an MPC solving
        elsewhere (the real-time solver process), e.g. the one the state estimator reads; `passthrough_motion`:
        the scenario keeps the base's motion (a viewer without command sources: only a dragged hand target
        changes the commands)."""
        self.passthrough_motion = passthrough_motion
        self.robot = robot
        self.board = CommandBoard(initial, limits)
        self.shaper = CommandShaper(robot, initial, ramp)
        self.sources = list(sources)
        self.base = base_commands or (lambda t, q, v: Commands())
        self.gait_mirror = gait_mirror
        self.steps: list[tuple[float, int]] = []  # (MPC step time, board entry used)
        self.hand_targets: list[tuple[float, np.ndarray]] = []  # (step time, world target) while one is set
        self.latencies: list[tuple[int, float]] = []  # (board entry, s from its stamp to the step that used it)
        self._reached = 0
        self.started = False

    @property
    def limits(self) -> OperatorLimits:
        return self.board.limits

    def start(self) -> None:
        for source in self.sources:
            source.start(self.board)
        self.started = True

    def close(self) -> None:
        for source in self.sources:
            source.close()

    def __enter__(self) -> "OperatorSession":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def poll(self, t: float) -> None:
        """The loop's clock and the polled sources (scripts), without a step (deploy polls every tick)."""
        self.board.set_time(t)
        for source in self.sources:
            poll = getattr(source, "poll", None)
            if poll is not None:
                poll(t, self.board)

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray) -> Commands:
        self.poll(t)
        posted = self.board.latest()
        base = self.base(t, q, v)
        commands = self.shaper(t, q, v, posted.command, base)
        if self.passthrough_motion:
            commands = replace(commands, base_velocity_m_s=base.base_velocity_m_s,
                               base_yaw_rate_rad_s=base.base_yaw_rate_rad_s, base_height_m=base.base_height_m,
                               walking=base.walking)
        if self.gait_mirror is not None:
            self.gait_mirror.follow(t, commands.walking)
        self.steps.append((float(t), posted.seq))
        if posted.seq > self._reached:
            for entry in self.board.history[self._reached + 1 : posted.seq + 1]:
                if entry.stamp_s >= 0:  # deploy: posts before the MPC phase (stamped -1) waited for it to start
                    self.latencies.append((entry.seq, float(t) - entry.stamp_s))
            self._reached = posted.seq
        if posted.command.hand_offset_m is not None:
            target = self.shaper.hand_target_world(q)
            if target is not None:
                self.hand_targets.append((float(t), target))
        return commands

    @property
    def lie_down_requested(self) -> bool:
        return self.board.latest().command.lie_down

    def posts(self) -> list[Posted]:
        return list(self.board.history)
