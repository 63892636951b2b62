"""Exceptions with messages that name the problem and the fix, and range checks for config dataclasses.

Config dataclasses validate themselves in `__post_init__` with `check_number`, so the Python API
refuses bad values as the CLI does. A `ConfigError` raised for one field carries `field` (the
dataclass field, e.g. `uniform_dt_ms`) and `detail` (the message without the name): the CLI
re-words it with the flag the user typed (`--uniform-dt must be ...`).
"""

from __future__ import annotations

import math
import numbers
from typing import Iterable


class WbmpcError(Exception):
    """Base class of every error wbmpc raises on purpose."""


class ModelError(WbmpcError):
    """A robot description is missing, malformed or names things that do not exist."""


class RunError(WbmpcError, RuntimeError):
    """A run that was set up correctly failed while running: the first MPC solve failed, a worker
    process (real-time MPC, DDS echo) did not start. The CLI exits 1 (the run failed), not 2 (bad input).
    """


class ConfigError(WbmpcError):
    """A configuration or command is out of range or inconsistent.

    `ConfigError.for_field(field, detail)` reads "`field` `detail`"; `field` and `detail` stay on the
    exception so that a front end can name its own option instead of the dataclass field.
    """

    def __init__(self, message: str, *, field: str | None = None, detail: str | None = None):
        super().__init__(message)
        self.field = field
        self.detail = detail

    @classmethod
    def for_field(cls, field: str, detail: str) -> "ConfigError":
        return cls(f"{field} {detail}", field=field, detail=detail)

    def worded(self, names: dict[str, str]) -> str:
        """The message with the field replaced by its name in `names` (e.g. a CLI flag), if listed."""
        if self.field is not None and self.detail is not None and self.field in names:
            return f"{names[self.field]} {self.detail}"
        return str(self)


def check_number(field: str, value, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False, unit: str = "", allow_none: bool = False) -> None:
    """Raise `ConfigError.for_field` unless `value` is a finite real in [low, high] ((low, high] if low_open)."""
    if value is None and allow_none:
        return
    suffix = f" {unit}" if unit else ""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ConfigError.for_field(field, f"must be a finite number{f' (in {unit})' if unit else ''}, got {value!r}")
    if low is not None and (value <= low if low_open else value < low):
        bound = f"> {low:g}" if low_open else f">= {low:g}"
        raise ConfigError.for_field(field, f"must be {bound}{suffix}, got {value:g}")
    if high is not None and value > high:
        raise ConfigError.for_field(field, f"must be <= {high:g}{suffix}, got {value:g}")


def unknown_name(kind: str, name: str, known: Iterable[str]) -> str:
    """Message for an unknown frame/joint/gait/... that lists what exists."""
    known = sorted(known)
    shown = ", ".join(known[:60]) + (" ..." if len(known) > 60 else "")
    plural = kind[:-2] + "es" if kind.endswith("is") else kind + "s"  # axis -> axes
    return f"unknown {kind} '{name}'; available {plural}: {shown}"
