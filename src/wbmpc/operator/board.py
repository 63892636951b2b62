"""`CommandBoard`: where every source posts the operator's command and the control loop reads it.

Sources run in their own threads (keyboard, gamepad, DDS callbacks) or are polled by the loop (a script, the
remote bytes of a LowState). Each post makes a new numbered entry with its source, its timestamp on the
loop's clock (the source's own time when it has one, e.g. a script's time or a LowState's tick; else the
loop's time when it arrived) and a note; the loop reads the newest at each MPC step, so a command reaches the
MPC's references at the next step. The loop moves the board's clock (`set_time`) every tick.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from wbmpc.operator.command import OperatorCommand, OperatorLimits


@dataclass(frozen=True)
class Posted:
    """One entry of the board: the whole command after the change, where and when it came from."""

    seq: int
    command: OperatorCommand
    source: str
    stamp_s: float  # loop time of the source's event
    note: str = ""  # "keyboard: w", "script: walk (line 5)", "gamepad lost"


class CommandBoard:
    """Thread-safe newest command plus the history of posts (`history`) and notices (`notices`)."""

    def __init__(self, initial: OperatorCommand, limits: OperatorLimits, source: str = "scenario"):
        self.limits = limits
        self._lock = threading.Lock()
        self._now_s = 0.0
        self._latest = Posted(0, initial, source, 0.0, "initial")
        self.history: list[Posted] = [self._latest]
        self.notices: list[tuple[float, str]] = []  # (loop time, text): a source lost, a key ignored
        self._listeners: list = []

    def set_time(self, t_s: float) -> None:
        self._now_s = float(t_s)

    @property
    def now_s(self) -> float:
        return self._now_s

    def latest(self) -> Posted:
        with self._lock:
            return self._latest

    def post(self, source: str, changes: dict | None = None, *, command: OperatorCommand | None = None,
             stamp_s: float | None = None, note: str = "", clamp: bool = True) -> Posted:
        """A new command from `source`: `changes` applied to the newest one (or a whole `command`); live sources
        are clamped to the robot's ranges (`clamp`), scripts were checked when read."""
        with self._lock:
            current = self._latest.command
            new = command if command is not None else current.with_changes(**(changes or {}))
            if clamp:
                new = self.limits.clamp(new)
            stamp = self._now_s if stamp_s is None else float(stamp_s)
            self._latest = Posted(self._latest.seq + 1, new, source, stamp, note)
            self.history.append(self._latest)
            posted = self._latest
        for listener in self._listeners:
            listener(posted)
        return posted

    def notice(self, text: str) -> None:
        """Something the run reports (stderr and metrics): a lost gamepad, a command the robot cannot follow."""
        with self._lock:
            self.notices.append((self._now_s, text))
        for listener in self._listeners:
            listener(text)

    def add_listener(self, listener) -> None:
        """`listener(Posted | str)` after each post or notice (the CLI prints them)."""
        self._listeners.append(listener)
