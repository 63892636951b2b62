"""The Unitree remote (the robot's own wireless controller): its bytes, and its sticks and keys as commands.

Layout, as Unitree documents it (`xRockerBtnDataStruct`, 40 bytes in LowState's `wireless_remote`; the same
keys and sticks on the `rt/wirelesscontroller` topic as `WirelessController_{lx, ly, rx, ry, keys}`):

| bytes | content |
|---|---|
| 0-1 | head |
| 2-3 | keys, a little-endian uint16: bit 0 R1, 1 L1, 2 start, 3 select, 4 R2, 5 L2, 6 F1, 7 F2, 8 A, 9 B, 10 X, 11 Y, 12 up, 13 right, 14 down, 15 left |
| 4-7, 8-11, 12-15 | lx, rx, ry: float32 little-endian, [-1, 1] (x: right positive, y: up/forward positive) |
| 16-19 | L2: float32, the analog trigger |
| 20-23 | ly: float32 |
| 24-39 | idle |

Mapping (`RemoteMapping`, the gamepad's too): left stick forward/lateral, right stick x yaw rate (pushed right:
turn right), `start` walk <-> stand, `B` stop (zero velocity, stand), `up`/`down` body height +-2 cm, `R1` held:
the sticks move the hand's target instead (left stick x/y, right stick y: up/down), `Y` hand back to its
standing place, `L2`+`A` lie down. A key acts when pressed (an edge), once per `KEY_REPEAT_S` whichever channel
(LowState bytes or the topic) brought it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from wbmpc.errors import WbmpcError
from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import OperatorLimits

REMOTE_BYTES = 40
KEY_BITS = {"R1": 0, "L1": 1, "start": 2, "select": 3, "R2": 4, "L2": 5, "F1": 6, "F2": 7, "A": 8, "B": 9, "X": 10,
            "Y": 11, "up": 12, "right": 13, "down": 14, "left": 15}
STICK_OFFSETS = {"lx": 4, "rx": 8, "ry": 12, "l2": 16, "ly": 20}
DEADZONE = 0.08  # stick travel read as zero (a released stick rests within a few percent of centre)
KEY_REPEAT_S = 0.3
HEIGHT_STEP_M = 0.02
HAND_RATE_M_S = 0.1  # the hand's target moves this fast with a stick fully pushed (R1 held)


class RemoteError(WbmpcError, ValueError):
    """Remote bytes that are not a remote's: wrong length, non-finite or out-of-range sticks."""


@dataclass(frozen=True)
class RemoteState:
    """Sticks in [-1, 1] and the pressed keys (a bit mask, `KEY_BITS`)."""

    lx: float = 0.0
    ly: float = 0.0
    rx: float = 0.0
    ry: float = 0.0
    l2: float = 0.0
    keys: int = 0

    def pressed(self, name: str) -> bool:
        return bool(self.keys >> KEY_BITS[name] & 1)

    @property
    def key_names(self) -> tuple[str, ...]:
        return tuple(name for name in KEY_BITS if self.pressed(name))

    @classmethod
    def with_keys(cls, *names: str, **sticks) -> "RemoteState":
        return cls(keys=keys_mask(names), **sticks)


def keys_mask(names) -> int:
    unknown = [n for n in names if n not in KEY_BITS]
    if unknown:
        raise RemoteError(f"unknown remote key {', '.join(unknown)}; the remote has {', '.join(KEY_BITS)}")
    return sum(1 << KEY_BITS[n] for n in names)


def _stick(name: str, value: float) -> float:
    if not math.isfinite(value) or abs(value) > 1.5:
        raise RemoteError(f"remote stick {name} reads {value!r}: not a stick position in [-1, 1]")
    return float(np.clip(value, -1.0, 1.0))


def decode_remote(data) -> RemoteState:
    """LowState's `wireless_remote` (40 bytes or ints) -> `RemoteState`; RemoteError on a malformed block."""
    raw = bytes(bytearray(int(b) & 0xFF for b in data))
    if len(raw) != REMOTE_BYTES:
        raise RemoteError(f"the remote's block has {len(raw)} bytes, not {REMOTE_BYTES}")
    keys = struct.unpack_from("<H", raw, 2)[0]
    values = {name: struct.unpack_from("<f", raw, offset)[0] for name, offset in STICK_OFFSETS.items()}
    return RemoteState(**{name: _stick(name, value) for name, value in values.items()}, keys=int(keys))


def encode_remote(state: RemoteState) -> list[int]:
    """`RemoteState` -> the 40 bytes of LowState's `wireless_remote` (as ints; head and idle bytes zero)."""
    raw = bytearray(REMOTE_BYTES)
    struct.pack_into("<H", raw, 2, state.keys & 0xFFFF)
    for name, offset in STICK_OFFSETS.items():
        struct.pack_into("<f", raw, offset, float(getattr(state, name)))
    return list(raw)


def decode_wireless_controller(msg) -> RemoteState:
    """A `rt/wirelesscontroller` message (WirelessController_: lx, ly, rx, ry, keys) -> `RemoteState`."""
    keys = int(msg.keys) & 0xFFFF
    return RemoteState(lx=_stick("lx", float(msg.lx)), ly=_stick("ly", float(msg.ly)), rx=_stick("rx", float(msg.rx)),
                       ry=_stick("ry", float(msg.ry)), l2=1.0 if keys >> KEY_BITS["L2"] & 1 else 0.0, keys=keys)


def _shaped(value: float) -> float:
    """Stick travel past the dead zone, rescaled to [-1, 1]."""
    magnitude = max(abs(value) - DEADZONE, 0.0) / (1.0 - DEADZONE)
    return math.copysign(magnitude, value) if magnitude else 0.0


class RemoteMapping:
    """Turns successive `RemoteState`s into posts on a `CommandBoard` (see the module docstring)."""

    def __init__(self, limits: OperatorLimits, source: str = "remote"):
        self.limits, self.source = limits, source
        self._previous_keys: dict[str, int] = {}  # per channel
        self._last_press: dict[str, float] = {}
        self._sticks: tuple[float, float, float] | None = None
        self._arm_sticks: np.ndarray | None = None
        self._last_stamp: float | None = None

    def update(self, state: RemoteState, stamp_s: float, board: CommandBoard, channel: str = "lowstate") -> None:
        previous = self._previous_keys.get(channel, 0)
        self._previous_keys[channel] = state.keys
        pressed = [name for name, bit in KEY_BITS.items() if state.keys >> bit & 1 and not previous >> bit & 1]
        dt = 0.0 if self._last_stamp is None else max(0.0, stamp_s - self._last_stamp)
        self._last_stamp = stamp_s
        for name in pressed:
            if stamp_s - self._last_press.get(name, -math.inf) < KEY_REPEAT_S:
                continue  # the same press through the other channel
            self._last_press[name] = stamp_s
            self._key(name, state, stamp_s, board)
        lx, ly, rx, ry = (_shaped(getattr(state, s)) for s in ("lx", "ly", "rx", "ry"))
        latest = board.latest().command
        arm = self._arm_sticks  # the hand moves as the sticks were held since the last update
        self._arm_sticks = np.array([ly, -lx, ry]) if state.pressed("R1") else None
        if state.pressed("R1"):  # arm mode: the sticks move the hand's target, the base holds still
            if self.limits.has_arm and arm is not None and np.any(arm) and dt > 0:
                hand = np.asarray(latest.hand_offset_m or (0.0, 0.0, 0.0)) + HAND_RATE_M_S * dt * arm
                board.post(self.source, {"hand": hand}, stamp_s=stamp_s, note=f"{self.source}: R1 + sticks, hand")
            sticks = (0.0, 0.0, 0.0)
        else:
            sticks = (ly * self.limits.max_forward_m_s, -lx * self.limits.max_lateral_m_s,
                      -rx * self.limits.max_yaw_rate_rad_s)
        if self._sticks is None or max(abs(a - b) for a, b in zip(sticks, self._sticks)) > 1e-3:
            if self._sticks is not None or any(sticks):  # an idle remote does not override other sources
                board.post(self.source, {"forward": sticks[0], "lateral": sticks[1], "yaw_rate": sticks[2]},
                           stamp_s=stamp_s, note=f"{self.source}: sticks")
            self._sticks = sticks

    def _key(self, name: str, state: RemoteState, stamp_s: float, board: CommandBoard) -> None:
        latest = board.latest().command
        post = lambda changes, note, **kw: board.post(self.source, changes, stamp_s=stamp_s,  # noqa: E731
                                                      note=f"{self.source}: {note}", **kw)
        if name == "A" and state.pressed("L2"):
            post(None, "L2+A, lie down", command=latest.stopped().with_changes(lie_down=True))
        elif name == "start":
            post({"walk": not latest.walking}, "start, " + ("stand" if latest.walking else "walk"))
        elif name == "B":
            post(None, "B, stop", command=latest.stopped())
        elif name in ("up", "down"):
            step = HEIGHT_STEP_M if name == "up" else -HEIGHT_STEP_M
            post({"height": latest.height_offset_m + step}, f"{name}, height")
        elif name == "Y" and self.limits.has_arm:
            post({"hand": (0.0, 0.0, 0.0)}, "Y, hand home")
