"""A gamepad on the machine running wbmpc (`--gamepad [DEVICE]`), read through the Linux input subsystem.

Library: python-evdev (`pip install evdev`, the `operator` extra): the maintained binding of Linux's evdev
interface, which every gamepad driver (xpad, hid-playstation, hid-nintendo, generic HID) reports through with
the kernel's standard gamepad codes (Documentation/input/gamepad.rst), per-event kernel timestamps, and the
axis ranges to normalise sticks; no display or event loop needed (pygame/SDL need a window's event pump, the
old joystick API /dev/input/js* has no per-axis ranges and is deprecated in favour of evdev). A removed device
raises ENODEV on read, which is how a vanished gamepad is noticed.

The pad is laid out as Unitree's remote (`remote.RemoteState`: the same sticks and keys by position) and
mapped by `remote.RemoteMapping`, so it drives a run as the robot's own remote drives deploy, and `robot-sim
--remote-gamepad` can publish it as the remote's bytes. When the device disappears mid-run the robot holds a
stand (zero velocity) and the run says so.
"""

from __future__ import annotations

import errno
import select
import threading
import time

from wbmpc.errors import ConfigError
from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import OperatorLimits
from wbmpc.operator.remote import KEY_BITS, RemoteMapping, RemoteState

INSTALL_HINT = 'pip install evdev (or pip install "wbmpc[operator]")'


def _ecodes():
    try:
        from evdev import ecodes
    except ImportError:
        raise ConfigError(f"--gamepad reads Linux input devices through python-evdev, which is not installed: "
                          f"{INSTALL_HINT}") from None
    return ecodes


def _layout():
    """(axes: evdev code -> (stick, sign)), (buttons: evdev code -> remote key), trigger axes -> key."""
    e = _ecodes()
    axes = {e.ABS_X: ("lx", 1.0), e.ABS_Y: ("ly", -1.0), e.ABS_RX: ("rx", 1.0), e.ABS_RY: ("ry", -1.0)}
    buttons = {e.BTN_SOUTH: "A", e.BTN_EAST: "B", e.BTN_WEST: "X", e.BTN_NORTH: "Y", e.BTN_TL: "L1", e.BTN_TR: "R1",
               e.BTN_TL2: "L2", e.BTN_TR2: "R2", e.BTN_START: "start", e.BTN_SELECT: "select", e.BTN_MODE: "F1",
               e.BTN_DPAD_UP: "up", e.BTN_DPAD_DOWN: "down", e.BTN_DPAD_LEFT: "left", e.BTN_DPAD_RIGHT: "right"}
    triggers = {e.ABS_Z: "L2", e.ABS_RZ: "R2", e.ABS_BRAKE: "L2", e.ABS_GAS: "R2"}
    return axes, buttons, triggers


def find_gamepad(path: str | None = None):
    """The evdev device at `path`, or the first one that looks like a gamepad (sticks and a south button)."""
    e = _ecodes()  # a ConfigError with the install hint without python-evdev
    from evdev import InputDevice, list_devices

    if path:
        try:
            return InputDevice(path)
        except (FileNotFoundError, PermissionError, OSError) as exc:
            raise ConfigError(f"--gamepad {path}: cannot open it ({exc.strerror or exc}); list input devices with "
                              "`python -m evdev.evtest`, or check the permissions (the 'input' group)") from None
    devices = list_devices()
    for candidate in devices:
        try:
            device = InputDevice(candidate)
        except OSError:
            continue
        caps = device.capabilities()
        if e.ABS_X in [c if isinstance(c, int) else c[0] for c in caps.get(e.EV_ABS, [])] and \
                (e.BTN_SOUTH in caps.get(e.EV_KEY, []) or e.BTN_GAMEPAD in caps.get(e.EV_KEY, [])):
            return device
        device.close()
    where = "no readable /dev/input/event* devices" if not devices else f"{len(devices)} input devices, none a gamepad"
    raise ConfigError(f"--gamepad: no gamepad found ({where}); plug one in, name it (--gamepad /dev/input/eventN), "
                      "or drive the run with --keyboard or --commands FILE.yaml")


class GamepadReader:
    """evdev events -> `RemoteState` (sticks normalised with the device's axis ranges, D-pad hats as keys)."""

    def __init__(self, device):
        self.device = device
        self._axes, self._buttons, self._triggers = _layout()
        e = _ecodes()
        self._hat_x, self._hat_y = e.ABS_HAT0X, e.ABS_HAT0Y
        self._ev_abs, self._ev_key = e.EV_ABS, e.EV_KEY
        self._ranges = {}
        for code in (*self._axes, *self._triggers):
            try:
                info = device.absinfo(code)
            except (OSError, KeyError, TypeError):
                continue
            if info is not None and info.max > info.min:
                self._ranges[code] = (info.min, info.max)
        self.state = RemoteState()

    def _normalised(self, code: int, value: int) -> float:
        low, high = self._ranges.get(code, (-32768, 32767))
        return max(-1.0, min(1.0, 2.0 * (value - low) / (high - low) - 1.0))

    def apply(self, event) -> bool:
        """Fold one evdev event into `state`; True when it changed."""
        state, keys = self.state, self.state.keys
        values = {"lx": state.lx, "ly": state.ly, "rx": state.rx, "ry": state.ry, "l2": state.l2}
        if event.type == self._ev_abs:
            if event.code in self._axes:
                stick, sign = self._axes[event.code]
                values[stick] = sign * self._normalised(event.code, event.value)
            elif event.code in self._triggers:
                low, high = self._ranges.get(event.code, (0, 255))
                pull = (event.value - low) / max(high - low, 1)
                keys = _set_key(keys, self._triggers[event.code], pull > 0.5)
                if self._triggers[event.code] == "L2":
                    values["l2"] = float(pull)
            elif event.code == self._hat_x:
                keys = _set_key(_set_key(keys, "left", event.value < 0), "right", event.value > 0)
            elif event.code == self._hat_y:
                keys = _set_key(_set_key(keys, "up", event.value < 0), "down", event.value > 0)
            else:
                return False
        elif event.type == self._ev_key and event.code in self._buttons:
            keys = _set_key(keys, self._buttons[event.code], event.value != 0)
        else:
            return False
        self.state = RemoteState(**values, keys=keys)
        return True


def _set_key(keys: int, name: str, down: bool) -> int:
    bit = 1 << KEY_BITS[name]
    return keys | bit if down else keys & ~bit


class GamepadSource:
    """Reads the pad in a thread; each change goes through `RemoteMapping` to the board. A vanished device:
    a stand is posted (the last safe command) with a notice."""

    name = "gamepad"

    def __init__(self, limits: OperatorLimits, device=None, path: str | None = None):
        self.device = device if device is not None else find_gamepad(path)
        self.reader = GamepadReader(self.device)
        self.mapping = RemoteMapping(limits, source=self.name)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.lost_at_s: float | None = None

    @property
    def description(self) -> str:
        return f"{getattr(self.device, 'name', 'gamepad')} ({getattr(self.device, 'path', '?')})"

    def start(self, board: CommandBoard) -> None:
        self._thread = threading.Thread(target=self._read, args=(board,), name="wbmpc-gamepad", daemon=True)
        self._thread.start()

    def _read(self, board: CommandBoard) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.device.fd], [], [], 0.05)
                if not ready:
                    continue
                events = list(self.device.read())
            except BlockingIOError:
                continue
            except (OSError, ValueError) as exc:  # ENODEV: unplugged; EBADF/ValueError: its fd went away
                if isinstance(exc, OSError) and exc.errno not in (errno.ENODEV, errno.EBADF, errno.EIO, None):
                    raise
                self.lost_at_s = board.now_s
                board.post(self.name, command=board.latest().command.stopped(),
                           note=f"gamepad {self.description} disconnected: holding a stand")
                board.notice(f"the gamepad {self.description} disconnected at {board.now_s:.2f} s: the robot holds "
                             "a stand (zero velocity) until the run ends")
                return
            for event in events:  # each change on its own: a press and its release may come in one read
                if self.reader.apply(event):
                    self.mapping.update(self.reader.state, board.now_s, board, channel="gamepad")

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        try:
            self.device.close()
        except Exception:  # noqa: BLE001  (already gone)
            pass


def wait_for_state(reader: GamepadReader, timeout_s: float) -> RemoteState:
    """Read pending events for up to `timeout_s` (robot-sim's publisher)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        ready, _, _ = select.select([reader.device.fd], [], [], max(0.0, end - time.monotonic()))
        if not ready:
            break
        for event in reader.device.read():
            reader.apply(event)
    return reader.state
