"""`OperatorConfig`: which sources drive a run (`--commands`, `--keyboard`, `--gamepad`), the live viewer
(`--viewer`) and the ramps (`--max-accel`, `--max-yaw-accel`), each declared once (`wbmpc.options`)."""

from __future__ import annotations

import os
from dataclasses import dataclass

from wbmpc.errors import ConfigError
from wbmpc.options import check_fields, option


@dataclass
class OperatorConfig:
    commands_file: str | None = option(None, flag="--commands", metavar="FILE.yaml", help="drive the run from a "
                                       "command script: timed base velocity, yaw rate, height, walk/stand, hand "
                                       "target, stop (see examples/session.yaml); its 'duration' is the run's unless "
                                       "--duration says otherwise")
    keyboard: bool = option(False, flag="--keyboard", help="drive the run from the keyboard in this terminal (w/s "
                            "a/d q/e move, g walk/stand, space stop, ? lists the keys)")
    gamepad: str | None = option(None, flag="--gamepad", metavar="DEVICE", const="auto", help="drive the run from a "
                                 "gamepad (Linux evdev device; without DEVICE the first gamepad found), laid out as "
                                 "Unitree's remote: left stick moves, right stick turns, start walk/stand, B stop")
    viewer: bool = option(False, flag="--viewer", help="watch the run live in MuJoCo's viewer with the MPC's plan "
                          "drawn (base, feet and hand paths, contact forces); push the robot or drag the hand's "
                          "target with the mouse (Ctrl + right/left drag), each push logged as an event. Needs a "
                          "display; the replay (replay.html) works without")
    max_accel_m_s2: float = option(1.0, flag="--max-accel", help="the base velocity reference follows operator "
                                   "commands within this acceleration", low=0.0, high=10.0, low_open=True, unit="m/s^2")
    max_yaw_accel_rad_s2: float = option(2.0, flag="--max-yaw-accel", help="... and the yaw rate within this",
                                         low=0.0, high=20.0, low_open=True, unit="rad/s^2")

    def __post_init__(self):
        check_fields(self)
        if self.commands_file is not None and not os.path.isfile(self.commands_file):
            raise ConfigError(f"--commands: no command script at '{self.commands_file}' (a YAML file of timed "
                              "commands; see examples/session.yaml)")

    @property
    def sources_given(self) -> bool:
        """Whether an operator source replaces the scenario's fixed references."""
        return bool(self.commands_file or self.keyboard or self.gamepad)

    @property
    def active(self) -> bool:
        return self.sources_given or self.viewer
