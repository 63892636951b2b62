"""Command scripts (`--commands FILE.yaml`): timed operator commands for reproducible sessions and tests.

```yaml
duration: 60                     # optional: the run's length when --duration is not given
commands:
  - {at: 0, label: stand}                        # times in seconds from the start, increasing
  - {at: 2, label: walk, walk: true, forward: 0.4}
  - {at: 10, label: turn, forward: 0.0, yaw_rate: 0.6}
  - {at: 24, label: stop, stop: true}            # zero velocity and stand
  - {at: 28, label: hand, hand: [0.2, 0.0, 0.0]} # hand target offset, base heading frame (null: free)
```

Each entry changes the fields it names (`forward`, `lateral` m/s, `yaw_rate` rad/s, `height` m from the standing
height, `walk` true/false, `hand` [x, y, z] m, `stop`, `lie_down`); the others keep their values. Every entry is
checked when the file is read, against the robot's ranges (`OperatorLimits`): an unknown command, a value of the
wrong type or beyond the robot's range is an error naming the file, the line and the fix, before anything runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from wbmpc.errors import ConfigError
from wbmpc.operator.board import CommandBoard
from wbmpc.operator.command import FIELDS, OperatorCommand, OperatorLimits

ENTRY_KEYS = ("at", "label", *FIELDS, "stop")
NUMBER_KEYS = ("forward", "lateral", "yaw_rate", "height")
MAX_SCRIPT_S = 3600.0


@dataclass(frozen=True)
class ScriptEntry:
    at_s: float
    label: str
    changes: dict  # the fields this entry sets (`OperatorCommand.with_changes` names); {"stop": True} for a stop
    command: OperatorCommand  # the whole command once this entry applied (the script alone)
    line: int


@dataclass(frozen=True)
class CommandScript:
    path: str
    entries: tuple[ScriptEntry, ...]
    duration_s: float | None
    ignored: tuple[str, ...] = ()  # fields the robot cannot follow (a hand target on a robot without an arm)

    def segments(self, end_s: float) -> list[tuple[float, float, ScriptEntry]]:
        """(start, end, entry) of each entry until the next one (or `end_s`)."""
        times = [e.at_s for e in self.entries] + [end_s]
        return [(times[i], min(times[i + 1], end_s), e) for i, e in enumerate(self.entries) if times[i] < end_s]


class _LineLoader(yaml.SafeLoader):
    """A safe loader that keeps each mapping's line (`__line__`) for the error messages."""


def _mapping_with_line(loader, node):
    mapping = loader.construct_mapping(node, deep=True)
    mapping["__line__"] = node.start_mark.line + 1
    return mapping


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_with_line)


def read_script(path: str | Path, limits: OperatorLimits, initial: OperatorCommand = OperatorCommand()) -> CommandScript:
    """Parse and check a command script (see the module docstring); ConfigError on any defect."""
    path = Path(path)
    duration, items = _load(path)
    entries, command, last_t = [], initial, -math.inf
    ignored: set[str] = set()
    for index, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"--commands {path}, entry {index + 1}: each command is a mapping like {{at: 2.0, walk: "
                              f"true, forward: 0.4}}, got {item!r}")
        line = item.pop("__line__", 0)
        where = f"--commands {path}:{line}"
        at = _entry_time(item, where, last_t, duration)
        last_t = at
        changes = _changes(item, where, limits, ignored)
        stop = changes.pop("stop", False)
        if stop:
            command = command.stopped()
        command = command.with_changes(**changes)
        problems = limits.violations(command)
        if problems:
            raise ConfigError(f"{where}: {'; '.join(problems)}: lower it (the robot's ranges: "
                              f"{_ranges_text(limits)})")
        if stop:
            changes = {"stop": True, **changes}
        label = str(item.get("label") or _auto_label(changes))
        entries.append(ScriptEntry(at, label, changes, command, line))
    return CommandScript(str(path), tuple(entries), None if duration is None else float(duration), tuple(sorted(ignored)))


def _load(path: Path) -> tuple[float | None, list]:
    """The script's `duration` (None without one) and its list of commands, each mapping with its `__line__`."""
    if not path.is_file():
        raise ConfigError(f"--commands: no command script at '{path}' (a YAML file of timed commands; see "
                          "examples/session.yaml)")
    try:
        data = yaml.load(path.read_text(), Loader=_LineLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"--commands {path}: not valid YAML ({exc})") from None
    duration = None
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"duration", "commands", "__line__"})
        if unknown:
            raise ConfigError(f"--commands {path}: unknown top-level key {', '.join(map(repr, unknown))}; a script "
                              "holds 'duration' (optional) and 'commands' (a list)")
        duration = data.get("duration")
        if duration is not None and (isinstance(duration, bool) or not isinstance(duration, (int, float))
                                     or not 0 < duration <= MAX_SCRIPT_S):
            raise ConfigError(f"--commands {path}: duration must be a number of seconds in (0, {MAX_SCRIPT_S:g}], "
                              f"got {duration!r}")
        data = data.get("commands")
    if not isinstance(data, list) or not data:
        raise ConfigError(f"--commands {path}: expected a list of commands (or 'commands:' holding one), each "
                          "{at: SECONDS, ...}")
    return duration, data


def _entry_time(item: dict, where: str, last_t: float, duration: float | None) -> float:
    """The entry's `at`, checked: known keys, a time >= 0 after the previous one and before the duration."""
    unknown = sorted(set(item) - set(ENTRY_KEYS))
    if unknown:
        raise ConfigError(f"{where}: unknown command {', '.join(map(repr, unknown))}; known: {', '.join(ENTRY_KEYS)}")
    at = item.get("at")
    if isinstance(at, bool) or not isinstance(at, (int, float)) or not math.isfinite(at) or at < 0:
        raise ConfigError(f"{where}: 'at' must be a time in seconds >= 0, got {at!r}")
    if at <= last_t:
        raise ConfigError(f"{where}: times must increase; {at:g} s comes after {last_t:g} s")
    if duration is not None and at >= duration:
        raise ConfigError(f"{where}: at {at:g} s is not before the script's duration ({duration:g} s)")
    return float(at)


def _changes(item: dict, where: str, limits: OperatorLimits, ignored: set[str]) -> dict:
    """The fields an entry sets, each value checked for its type ("hand" on a robot without an arm: `ignored`)."""
    changes = {}
    for key, value in item.items():
        if key in NUMBER_KEYS:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{where}: {key} must be a number in {FIELDS[key]}, got {value!r}")
            changes[key] = float(value)
        elif key in ("walk", "stop", "lie_down"):
            if not isinstance(value, bool):
                raise ConfigError(f"{where}: {key} must be true or false, got {value!r}")
            if key == "walk" or value:
                changes[key] = value
        elif key == "hand":
            if value is not None and (not isinstance(value, list) or len(value) != 3 or not all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
                raise ConfigError(f"{where}: hand must be [x, y, z] in metres (base heading frame, from its "
                                  f"standing place) or null, got {value!r}")
            if not limits.has_arm:
                ignored.add("hand")
                continue
            changes["hand"] = None if value is None else [float(x) for x in value]
    return changes


def script_duration(path: str | Path | None) -> float | None:
    """A script's own `duration` (None without one or without a script), read without checking the rest."""
    if not path:
        return None
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError):
        return None
    value = data.get("duration") if isinstance(data, dict) else None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _ranges_text(limits: OperatorLimits) -> str:
    low, high = limits.height_range_m
    return (f"forward +-{limits.max_forward_m_s:g} m/s, lateral +-{limits.max_lateral_m_s:g} m/s, yaw rate "
            f"+-{limits.max_yaw_rate_rad_s:g} rad/s, height {low:+g} to {high:+g} m, hand {limits.max_hand_offset_m:g} m")


def _auto_label(changes: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in changes.items()) or "hold"


class ScriptSource:
    """Posts each entry of a script when the loop's clock reaches its time (stamped with that time)."""

    name = "script"

    def __init__(self, script: CommandScript):
        self.script = script
        self._next = 0

    def start(self, board: CommandBoard) -> None:
        pass

    def poll(self, t_s: float, board: CommandBoard) -> None:
        entries = self.script.entries
        while self._next < len(entries) and entries[self._next].at_s <= t_s + 1e-9:
            entry = entries[self._next]
            changes = dict(entry.changes)
            if changes.pop("stop", False):
                board.post(self.name, command=board.latest().command.stopped(), stamp_s=entry.at_s,
                           note=f"script: {entry.label}")
            if changes or not entry.changes:
                board.post(self.name, changes, stamp_s=entry.at_s, note=f"script: {entry.label}")
            self._next += 1

    def close(self) -> None:
        pass
