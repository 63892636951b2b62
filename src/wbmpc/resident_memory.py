"""Resident memory of this process (MB), to show that a long run's memory stays flat."""

from __future__ import annotations

import os
import resource
import sys

_PAGE_BYTES = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_mb() -> float:
    """The process's resident set size now (Linux: /proc/self/statm); elsewhere its peak so far
    (`getrusage`, which cannot shrink, so growth still shows)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * _PAGE_BYTES / 1e6
    except (OSError, IndexError, ValueError):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux, bytes on macOS
        return peak / 1e6 if sys.platform == "darwin" else peak / 1e3
