"""What an operator asks of the robot (`OperatorCommand`) and the ranges a robot accepts (`OperatorLimits`).

One command interface for every source (the robot's remote, a gamepad, the keyboard, a command script, the
scenario's fixed references): base velocity forward and lateral (heading frame, m/s), yaw rate (rad/s), body
height (offset from the robot's standing height, m), walk or stand, the hand's target (offset from its place in
the standing pose, base heading frame, m; None: the scenario's hand command or a free hand) and lie-down (deploy:
lie down and end; run: end the run). A stop is "zero velocity, stand". The MPC never sees these targets directly:
`shaper.CommandShaper` ramps them within acceleration limits into the MPC's `Commands`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from wbmpc.errors import ConfigError, check_number
from wbmpc.robots import GRAVITY_M_S2, RobotModel

# the fields a source may set, with their units (scripts, keyboard help, errors)
FIELDS = {"forward": "m/s", "lateral": "m/s", "yaw_rate": "rad/s", "height": "m", "walk": "true/false",
          "hand": "[x, y, z] m", "lie_down": "true"}


@dataclass(frozen=True)
class OperatorCommand:
    """The operator's targets (see the module docstring)."""

    forward_m_s: float = 0.0
    lateral_m_s: float = 0.0
    yaw_rate_rad_s: float = 0.0
    height_offset_m: float = 0.0
    walking: bool = False
    hand_offset_m: tuple[float, float, float] | None = None
    lie_down: bool = False

    def with_changes(self, **changes) -> "OperatorCommand":
        """A copy with the given fields (names as in `FIELDS` or the dataclass's own)."""
        names = {"forward": "forward_m_s", "lateral": "lateral_m_s", "yaw_rate": "yaw_rate_rad_s",
                 "height": "height_offset_m", "walk": "walking", "hand": "hand_offset_m"}
        values = {names.get(key, key): value for key, value in changes.items()}
        if values.get("hand_offset_m") is not None:
            values["hand_offset_m"] = tuple(float(x) for x in values["hand_offset_m"])
        return replace(self, **values)

    def stopped(self) -> "OperatorCommand":
        """Zero velocity and stand (the hold/stop of every source); height and hand stay."""
        return replace(self, forward_m_s=0.0, lateral_m_s=0.0, yaw_rate_rad_s=0.0, walking=False)

    @property
    def moving(self) -> bool:
        return bool(self.forward_m_s or self.lateral_m_s or self.yaw_rate_rad_s)

    def as_dict(self) -> dict:
        return {"forward_m_s": self.forward_m_s, "lateral_m_s": self.lateral_m_s, "yaw_rate_rad_s": self.yaw_rate_rad_s,
                "height_offset_m": self.height_offset_m, "walking": self.walking,
                "hand_offset_m": None if self.hand_offset_m is None else list(self.hand_offset_m),
                "lie_down": self.lie_down}

    def describe(self) -> str:
        """Short human text: "walk 0.40 m/s fwd, 0.60 rad/s" / "stand, hand +0.20 0.00 0.00 m"."""
        parts = ["walk" if self.walking else "stand"]
        if self.forward_m_s or self.lateral_m_s:
            parts.append(f"{self.forward_m_s:+.2f} fwd {self.lateral_m_s:+.2f} lat m/s")
        if self.yaw_rate_rad_s:
            parts.append(f"yaw {self.yaw_rate_rad_s:+.2f} rad/s")
        if self.height_offset_m:
            parts.append(f"height {100 * self.height_offset_m:+.0f} cm")
        if self.hand_offset_m is not None:
            parts.append("hand " + " ".join(f"{x:+.2f}" for x in self.hand_offset_m) + " m")
        if self.lie_down:
            parts.append("lie down")
        return ", ".join(parts)


# speed ceilings by dynamic similarity: Froude number v^2 / (g L) of a brisk trot for four legs (0.25), of a
# slow walk for two (0.1, 0.9 m/s for g1); sideways half of that; yaw rate the forward ceiling over the leg
# length, at most the MPC's own limit. Body height -20 % / +5 % of the standing height, the hand 30 cm.
QUADRUPED_FROUDE, BIPED_FROUDE = 0.25, 0.1


@dataclass(frozen=True)
class OperatorLimits:
    """The command ranges of a robot: what a script may ask (beyond: an error before anything runs) and
    where live sources (sticks, keys) are clamped."""

    max_forward_m_s: float = 1.0
    max_lateral_m_s: float = 0.5
    max_yaw_rate_rad_s: float = 1.0
    height_range_m: tuple[float, float] = (-0.1, 0.03)
    max_hand_offset_m: float = 0.3
    has_arm: bool = True

    def __post_init__(self):
        for name in ("max_forward_m_s", "max_lateral_m_s", "max_yaw_rate_rad_s", "max_hand_offset_m"):
            check_number(name, getattr(self, name), low=0.0, low_open=True)
        low, high = self.height_range_m
        if not low <= 0 <= high:
            raise ConfigError(f"height_range_m must hold 0, got {self.height_range_m}")

    @classmethod
    def for_robot(cls, robot: RobotModel, max_base_speed_m_s: float = 1.5, max_yaw_rate_rad_s: float = 1.5):
        """Ceilings from the robot's size (Froude similarity on its standing height), capped by the MPC's limits."""
        height = float(robot.q_nominal[2])
        froude = BIPED_FROUDE if len(robot.feet) == 2 else QUADRUPED_FROUDE
        forward = min(math.sqrt(froude * GRAVITY_M_S2 * height), max_base_speed_m_s)
        return cls(max_forward_m_s=round(forward, 2), max_lateral_m_s=round(0.5 * forward, 2),
                   max_yaw_rate_rad_s=round(min(forward / height, max_yaw_rate_rad_s), 2),
                   height_range_m=(round(-0.2 * height, 3), round(0.05 * height, 3)),
                   has_arm=robot.arm_ee is not None)

    def violations(self, command: OperatorCommand) -> list[str]:
        """Why `command` is out of range (empty when it is not): each names the value, the limit and its unit."""
        out = []
        for name, value, limit, unit in (("forward", command.forward_m_s, self.max_forward_m_s, "m/s"),
                                         ("lateral", command.lateral_m_s, self.max_lateral_m_s, "m/s"),
                                         ("yaw_rate", command.yaw_rate_rad_s, self.max_yaw_rate_rad_s, "rad/s")):
            if not math.isfinite(value) or abs(value) > limit + 1e-12:
                out.append(f"{name} {value:g} {unit} is beyond this robot's range of +-{limit:g} {unit}")
        low, high = self.height_range_m
        if not math.isfinite(command.height_offset_m) or not low - 1e-12 <= command.height_offset_m <= high + 1e-12:
            out.append(f"height {command.height_offset_m:+g} m is outside this robot's {low:+g} to {high:+g} m "
                       "(offset from its standing height)")
        if command.hand_offset_m is not None:
            hand = np.asarray(command.hand_offset_m, dtype=float)
            if hand.shape != (3,) or not np.all(np.isfinite(hand)):
                out.append(f"hand must be three numbers [x, y, z] in metres, got {command.hand_offset_m}")
            elif np.linalg.norm(hand) > self.max_hand_offset_m + 1e-12:
                out.append(f"hand offset {np.linalg.norm(hand):.3g} m is beyond {self.max_hand_offset_m:g} m from "
                           "its standing place")
        return out

    def clamp(self, command: OperatorCommand) -> OperatorCommand:
        """`command` moved into range (live sources: a stick pushed past its scale, a key held)."""
        low, high = self.height_range_m
        hand = command.hand_offset_m
        if hand is not None:
            vector = np.asarray(hand, dtype=float)
            norm = float(np.linalg.norm(vector))
            if norm > self.max_hand_offset_m:
                vector = vector * self.max_hand_offset_m / norm
            hand = tuple(float(x) for x in vector)
        return replace(command,
                       forward_m_s=float(np.clip(command.forward_m_s, -self.max_forward_m_s, self.max_forward_m_s)),
                       lateral_m_s=float(np.clip(command.lateral_m_s, -self.max_lateral_m_s, self.max_lateral_m_s)),
                       yaw_rate_rad_s=float(np.clip(command.yaw_rate_rad_s, -self.max_yaw_rate_rad_s,
                                                    self.max_yaw_rate_rad_s)),
                       height_offset_m=float(np.clip(command.height_offset_m, low, high)), hand_offset_m=hand)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}
