"""wbmpc's cache directory: compiled solvers, composed robots, replay meshes, BLASFEO builds.

`WBMPC_CACHE_DIR` if set, else `$XDG_CACHE_HOME/wbmpc` (`~/.cache/wbmpc`). Nothing here goes into git.
"""

from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """The cache directory (module docstring); not created here."""
    if os.environ.get("WBMPC_CACHE_DIR"):
        return Path(os.environ["WBMPC_CACHE_DIR"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "wbmpc"
