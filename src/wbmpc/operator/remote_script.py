"""What an operator does on the robot's remote, scripted for `wbmpc robot-sim --remote-script FILE.yaml`, and the
publisher that puts it (or a gamepad on this machine, `--remote-gamepad`) into robot-sim's messages: the 40 bytes
of every LowState's `wireless_remote` (CRC included) and `rt/wirelesscontroller` at 50 Hz, as a robot does.

```yaml
remote:                                   # times in seconds after robot-sim's first LowCmd
  - {at: 4.0, press: start}               # a key pressed for 0.2 s (walk)
  - {at: 5.0, ly: 0.5}                    # sticks in [-1, 1] keep their position until changed
  - {at: 9.0, ly: 0.0, rx: -0.5}          # turn right
  - {at: 13.0, rx: 0.0, press: B}         # stop
  - {at: 16.0, press: [L2, A]}            # lie down
```
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import yaml

from wbmpc.errors import ConfigError
from wbmpc.operator.remote import KEY_BITS, RemoteState, encode_remote, keys_mask

PRESS_S = 0.2
TOPIC_PERIOD_S = 0.02
STICKS = ("lx", "ly", "rx", "ry")


@dataclass(frozen=True)
class RemoteStep:
    at_s: float
    sticks: dict
    press: int  # keys pressed for PRESS_S
    hold: int | None  # keys held from here on (None: unchanged)


def read_remote_script(path: str | Path) -> list[RemoteStep]:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--remote-script: no file at '{path}' (YAML: remote: [{{at: SECONDS, ly: 0.5}}, ...])")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"--remote-script {path}: not valid YAML ({exc})") from None
    if isinstance(data, dict):
        data = data.get("remote")
    if not isinstance(data, list) or not data:
        raise ConfigError(f"--remote-script {path}: expected a list 'remote:' of {{at: SECONDS, ...}}")
    steps, last = [], -math.inf
    for index, item in enumerate(data):
        where = f"--remote-script {path}, entry {index + 1}"
        if not isinstance(item, dict):
            raise ConfigError(f"{where}: expected a mapping such as {{at: 2.0, ly: 0.5}}, got {item!r}")
        unknown = sorted(set(item) - {"at", "press", "hold", *STICKS})
        if unknown:
            raise ConfigError(f"{where}: unknown field {', '.join(unknown)}; known: at, press, hold, {', '.join(STICKS)}")
        at = item.get("at")
        if isinstance(at, bool) or not isinstance(at, (int, float)) or not at >= 0 or at <= last:
            raise ConfigError(f"{where}: 'at' must be increasing seconds >= 0, got {at!r}")
        last = float(at)
        sticks = {}
        for name in STICKS:
            if name in item:
                value = item[name]
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not -1.0 <= value <= 1.0:
                    raise ConfigError(f"{where}: {name} is a stick position in [-1, 1], got {value!r}")
                sticks[name] = float(value)
        keys = {}
        for field in ("press", "hold"):
            value = item.get(field)
            names = [value] if isinstance(value, str) else list(value or [])
            try:
                keys[field] = keys_mask(names)
            except ValueError as exc:
                raise ConfigError(f"{where}: {exc}") from None
        steps.append(RemoteStep(last, sticks, keys["press"], keys["hold"] if "hold" in item else None))
    return steps


class ScriptedRemote:
    """The remote's state at a time of the script (sticks held, presses 0.2 s long)."""

    def __init__(self, steps: list[RemoteStep]):
        self.steps = steps

    def state_at(self, t_s: float | None) -> RemoteState:
        state, held = RemoteState(), 0
        if t_s is None:
            return state
        keys = 0
        for step in self.steps:
            if step.at_s > t_s + 1e-9:
                break
            state = replace(state, **step.sticks)
            if step.hold is not None:
                held = step.hold
            keys = step.press if t_s < step.at_s + PRESS_S else 0
        keys |= held
        return replace(state, keys=keys, l2=1.0 if keys >> KEY_BITS["L2"] & 1 else 0.0)


class GamepadRemote:
    """A gamepad on this machine as the robot's remote (robot-sim --remote-gamepad)."""

    def __init__(self, path: str | None = None):
        from wbmpc.operator.gamepad import GamepadReader, find_gamepad

        self.reader = GamepadReader(find_gamepad(path))

    def state_at(self, t_s: float | None) -> RemoteState:
        from wbmpc.operator.gamepad import wait_for_state

        return wait_for_state(self.reader, 0.0)


class RemotePublisher:
    """Writes the remote's state into robot-sim's LowState (`write`, before it is sent) and on
    `rt/wirelesscontroller` every TOPIC_PERIOD_S."""

    def __init__(self, remote, topic: bool = True):
        """`topic`: also publish `rt/wirelesscontroller` (needs DDS opened); False: the LowState bytes only."""
        self.remote = remote
        self.topic = topic
        self._publisher = None
        self._message = None
        self._last_topic_t = -math.inf
        self.published = 0

    def write(self, low_state, t_s: float | None) -> RemoteState:
        from wbmpc.hardware.crc import low_state_crc

        state = self.remote.state_at(t_s)
        low_state.wireless_remote = encode_remote(state)
        low_state.crc = low_state_crc(low_state)
        now = t_s if t_s is not None else 0.0
        if self.topic and now - self._last_topic_t >= TOPIC_PERIOD_S - 1e-9:
            self._publish(state)
            self._last_topic_t = now
        return state

    def _publish(self, state: RemoteState) -> None:
        if self._publisher is None:
            from wbmpc.hardware.sdk import load_sdk
            from wbmpc.operator.remote_source import WIRELESS_CONTROLLER_TOPIC, wireless_controller_type

            sdk = load_sdk()
            kind = wireless_controller_type()
            self._publisher = sdk.ChannelPublisher(WIRELESS_CONTROLLER_TOPIC, kind)
            self._publisher.Init()
            self._message = kind(0.0, 0.0, 0.0, 0.0, 0)
        message = self._message
        message.lx, message.ly, message.rx, message.ry = state.lx, state.ly, state.rx, state.ry
        message.keys = state.keys
        self._publisher.Write(message)
        self.published += 1

    def close(self) -> None:
        if self._publisher is not None:
            self._publisher.Close()
            self._publisher = None
