"""The keyboard in the terminal as a command source (`--keyboard`).

The terminal is put in cbreak mode (keys arrive as typed, without Enter; Ctrl-C still interrupts) and restored
at the end. A thread reads the keys and posts on the board. Velocity keys also start walking (a standing robot
told to move forward walks); `space` stops (zero velocity, stand).
"""

from __future__ import annotations

import os
import select
import sys
import threading

import numpy as np

from wbmpc.errors import ConfigError
from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import OperatorLimits

SPEED_STEP_M_S = 0.1
YAW_STEP_RAD_S = 0.2
HEIGHT_STEP_M = 0.01
HAND_STEP_M = 0.02
ARROWS = {b"\x1b[A": "up", b"\x1b[B": "down", b"\x1b[C": "right", b"\x1b[D": "left"}
# key -> (field, step) for increments; the help lists them in this order
INCREMENTS = {"w": ("forward", SPEED_STEP_M_S), "up": ("forward", SPEED_STEP_M_S),
              "s": ("forward", -SPEED_STEP_M_S), "down": ("forward", -SPEED_STEP_M_S),
              "a": ("lateral", SPEED_STEP_M_S), "d": ("lateral", -SPEED_STEP_M_S),
              "q": ("yaw_rate", YAW_STEP_RAD_S), "left": ("yaw_rate", YAW_STEP_RAD_S),
              "e": ("yaw_rate", -YAW_STEP_RAD_S), "right": ("yaw_rate", -YAW_STEP_RAD_S),
              "r": ("height", HEIGHT_STEP_M), "f": ("height", -HEIGHT_STEP_M)}
HAND_KEYS = {"i": (0, HAND_STEP_M), "k": (0, -HAND_STEP_M), "j": (1, HAND_STEP_M), "l": (1, -HAND_STEP_M),
             "u": (2, HAND_STEP_M), "o": (2, -HAND_STEP_M)}
HELP = ("keys: w/s or up/down forward -+0.1 m/s, a/d left/right 0.1 m/s, q/e or left/right turn 0.2 rad/s, r/f "
        "height +-1 cm, space stop, g walk/stand, i/k j/l u/o hand x/y/z +-2 cm, h hand home, n hand free, x lie "
        "down (ends a run), ? this help; Ctrl-C stops")


def split_keys(data: bytes) -> list[str]:
    """Bytes read from the terminal -> key names (arrows from their escape sequences, others as characters)."""
    keys, i = [], 0
    while i < len(data):
        chunk = data[i : i + 3]
        if chunk in ARROWS:
            keys.append(ARROWS[chunk])
            i += 3
            continue
        keys.append(chr(data[i]) if data[i] < 128 else "?")
        i += 1
    return keys


class KeyboardSource:
    """Reads the keys of the terminal on `fd` (stdin by default) in a thread and posts them."""

    name = "keyboard"

    def __init__(self, limits: OperatorLimits, fd: int | None = None, echo=None):
        self.limits = limits
        self.fd = sys.stdin.fileno() if fd is None else fd
        self.echo = echo if echo is not None else sys.stderr
        if not os.isatty(self.fd):
            raise ConfigError("--keyboard reads keys from the terminal, but standard input is not one (a pipe or a "
                              "file): run wbmpc in a terminal, or script the session with --commands FILE.yaml")
        self._saved = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, board: CommandBoard) -> None:
        import termios
        import tty

        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd)
        print(f"wbmpc: {HELP}", file=self.echo, flush=True)
        self._thread = threading.Thread(target=self._read, args=(board,), name="wbmpc-keyboard", daemon=True)
        self._thread.start()

    def _read(self, board: CommandBoard) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.fd, 64)
            except OSError:
                board.notice("the keyboard's terminal closed: holding a stand")
                board.post(self.name, command=board.latest().command.stopped(), note="keyboard: terminal closed")
                return
            if not data:
                return
            for key in split_keys(data):
                self.press(key, board)

    def press(self, key: str, board: CommandBoard) -> None:
        """One key's command (also what the tests call)."""
        latest = board.latest().command
        note = f"keyboard: {key}"
        if key in INCREMENTS:
            name, step = INCREMENTS[key]
            current = {"forward": latest.forward_m_s, "lateral": latest.lateral_m_s, "yaw_rate": latest.yaw_rate_rad_s,
                       "height": latest.height_offset_m}[name]
            changes = {name: round(current + step, 6)}
            if name != "height":
                changes["walk"] = True
            board.post(self.name, changes, note=note)
        elif key == " ":
            board.post(self.name, command=latest.stopped(), note=note + " (stop)")
        elif key in ("g", "\n", "\r"):
            board.post(self.name, {"walk": not latest.walking}, note=note + (" (stand)" if latest.walking else " (walk)"))
        elif key in HAND_KEYS or key in ("h", "n"):
            if not self.limits.has_arm:
                board.notice(f"keyboard: '{key}' moves the hand; this robot has no arm")
                return
            if key == "n":
                board.post(self.name, {"hand": None}, note=note + " (hand free)")
                return
            hand = np.zeros(3) if key == "h" else np.asarray(latest.hand_offset_m or (0.0, 0.0, 0.0), dtype=float)
            if key in HAND_KEYS:
                axis, step = HAND_KEYS[key]
                hand[axis] += step
            board.post(self.name, {"hand": hand}, note=note)
        elif key == "x":
            board.post(self.name, command=latest.stopped().with_changes(lie_down=True), note=note + " (lie down)")
        elif key == "?":
            print(f"wbmpc: {HELP}", file=self.echo, flush=True)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None
