"""`CampaignSpec`: which runs a robustness campaign makes (scenario x grid / random samples x seeds).

A spec comes from a YAML, JSON or TOML file and/or command-line grid flags::

    name: push-map
    scenario: push
    duration_s: 4.0
    seeds: [0]
    fixed: {push_time_s: 1.0}
    grid:                      # full factorial product
      push_direction_deg: [0, 45, 90, 135, 180, 225, 270, 315]
      push_speed_m_s: [0.2, 0.4, 0.6, 0.8, 1.0, 1.2]
      gait_phase: [0, 0.25, 0.5, 0.75]
    random:                    # optional: N uniform samples per grid point
      samples: 0
      ranges: {ee_payload_kg: [0, 3]}
    randomize: false           # true: the reality-gap draw (campaign/reality_gap.py) as `random`'s defaults

Axis names are listed in `wbmpc.campaign.cases.AXES` (scenario options, model errors, sensor
noise, delay, robot); unknown names are rejected with the list of known ones.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path

import tomllib

from wbmpc.errors import ConfigError


@dataclass
class RandomSamples:
    """`samples` draws per grid point, each axis uniform in its [low, high] range (seeded)."""

    samples: int = 0
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    seed: int = 0

    def __post_init__(self):
        if self.samples < 0:
            raise ConfigError(f"random.samples must be >= 0, got {self.samples}")
        clean = {}
        for name, bounds in self.ranges.items():
            try:
                low, high = (float(b) for b in bounds)
            except (TypeError, ValueError):
                raise ConfigError(f"random.ranges.{name} must be [low, high], got {bounds!r}") from None
            if not low <= high:
                raise ConfigError(f"random.ranges.{name}: low {low} is above high {high}")
            clean[name] = (low, high)
        self.ranges = clean


@dataclass
class CampaignSpec:
    """Everything that defines the set of cases (the output directory and the cluster do not)."""

    name: str = "campaign"
    scenario: str = "push"
    robot: str = "b1_z1"
    duration_s: float = 4.0
    nodes: int = 15
    compiled: bool = False
    formulation: str = "wb_inverse"
    seeds: list[int] = field(default_factory=lambda: [0])
    fixed: dict[str, float | str] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)
    random: RandomSamples = field(default_factory=RandomSamples)
    # "realtime": every case beside a solver process at wall-clock speed (one case at a time, in this process:
    # the two cores are the solver's and the simulation's); a number: a fixed delay in ms (the delay_ms axis
    # overrides it); "none": the simulation waits
    delay: str = "none"
    solver: str | None = None  # None: fatrop, or with delay realtime the run's default (--solver auto)
    # the reality-gap draw (`wbmpc.campaign.reality_gap`): random plants around the robot's model, `random.samples`
    # of them (default 100) per grid point, the spec's own ranges and fixed values over the draw's defaults
    randomize: bool = False

    def __post_init__(self):
        from wbmpc.control.delay import delay_from_text

        delay_from_text(self.delay)
        if isinstance(self.random, dict):
            self.random = RandomSamples(**self.random)
        if self.random.samples and not self.random.ranges and not self.randomize:
            raise ConfigError("random.samples > 0 needs random.ranges: {axis: [low, high], ...} (or randomize: true)")
        if not self.duration_s > 0:
            raise ConfigError(f"duration_s must be positive, got {self.duration_s}")
        if self.nodes < 2:
            raise ConfigError(f"nodes must be >= 2, got {self.nodes}")
        if not self.seeds:
            raise ConfigError("seeds must list at least one seed")
        self.seeds = [int(s) for s in self.seeds]
        for name, values in self.grid.items():
            if not isinstance(values, (list, tuple)) or not values:
                raise ConfigError(f"grid.{name} must be a non-empty list of values, got {values!r}")
            self.grid[name] = list(values)
        from wbmpc.campaign.cases import check_axes  # axis names and value ranges

        check_axes(self)


def load_spec(path: str | Path | None = None, **overrides) -> CampaignSpec:
    """A spec from a .yaml/.yml/.json/.toml file (or defaults), with `overrides` (None = keep) on top.

    `grid` overrides are merged axis by axis into the file's grid.
    """
    data: dict = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"campaign spec {path} does not exist; pass a .yaml, .json or .toml file")
        text = path.read_text()
        suffix = path.suffix.lower()
        try:
            if suffix in (".yaml", ".yml"):
                import yaml

                data = yaml.safe_load(text) or {}
            elif suffix == ".json":
                data = json.loads(text)
            elif suffix == ".toml":
                data = tomllib.loads(text)
            else:
                raise ConfigError(f"campaign spec {path}: unknown format '{suffix}'; use .yaml, .json or .toml")
        except (ValueError, tomllib.TOMLDecodeError) as exc:
            raise ConfigError(f"campaign spec {path} is not valid {suffix[1:]}: {exc}") from None
        except ImportError:
            raise ConfigError("YAML specs need PyYAML (pip install pyyaml); or use .json / .toml") from None
        if not isinstance(data, dict):
            raise ConfigError(f"campaign spec {path} must be a mapping of settings, got {type(data).__name__}")
    known = {f.name for f in fields(CampaignSpec)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"campaign spec: unknown keys {unknown}; known keys: {', '.join(sorted(known))}")
    grid = dict(data.get("grid") or {})
    grid.update(overrides.pop("grid", None) or {})
    fixed = dict(data.get("fixed") or {})
    fixed.update(overrides.pop("fixed", None) or {})
    data.update({k: v for k, v in overrides.items() if v is not None})
    data["grid"], data["fixed"] = grid, fixed
    try:
        return CampaignSpec(**data)
    except TypeError as exc:
        raise ConfigError(f"campaign spec: {exc}") from None


def parse_grid_flag(text: str) -> tuple[str, list]:
    """`axis=v1,v2,...` or `axis=start:stop:step` (stop included) -> (axis, values)."""
    if "=" not in text:
        raise ConfigError(f"--grid expects AXIS=V1,V2,... or AXIS=START:STOP:STEP, got {text!r}")
    name, values = (part.strip() for part in text.split("=", 1))
    if ":" in values:
        try:
            start, stop, step = (float(v) for v in values.split(":"))
        except ValueError:
            raise ConfigError(f"--grid {name}: START:STOP:STEP must be three numbers, got {values!r}") from None
        if not step > 0 or stop < start:
            raise ConfigError(f"--grid {name}: need STEP > 0 and STOP >= START, got {values!r}")
        count = int(round((stop - start) / step)) + 1
        return name, [round(start + i * step, 10) for i in range(count)]
    items = [v.strip() for v in values.split(",") if v.strip()]
    if not items:
        raise ConfigError(f"--grid {name}: no values given")
    parsed = []
    for item in items:
        try:
            parsed.append(float(item))
        except ValueError:
            parsed.append(item)
    return name, parsed
