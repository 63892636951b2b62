"""Exceptions with messages that name the problem and the fix."""

from __future__ import annotations

from typing import Iterable


class WbmpcError(Exception):
    """Base class of every error wbmpc raises on purpose."""


class ModelError(WbmpcError):
    """A robot description is missing, malformed or names things that do not exist."""


class ConfigError(WbmpcError):
    """A configuration or command is out of range or inconsistent."""


def unknown_name(kind: str, name: str, known: Iterable[str]) -> str:
    """Message for an unknown frame/joint/gait/... that lists what exists."""
    known = sorted(known)
    shown = ", ".join(known[:60]) + (" ..." if len(known) > 60 else "")
    return f"unknown {kind} '{name}'; available {kind}s: {shown}"
