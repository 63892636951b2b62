"""The `--out` directory of a run: checked before the run, written whole or not at all, no stale files.

Before a run, `check_output_dir` only checks that the directory can be created or written (a run
that fails its input checks leaves nothing behind). After it, `write_output_files` writes every
file into a staging folder inside the directory, then removes what the previous wbmpc run there
wrote (listed in `.wbmpc-outputs.json`, so files of other origins are never touched) and moves
the new files in. If writing fails the staging folder goes, and so does the directory if this
call created it.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable

from wbmpc.errors import ConfigError

MANIFEST = ".wbmpc-outputs.json"
# written by wbmpc before the manifest existed: removed from a reused directory as well
LEGACY_NAMES = ("metrics.json", "replay.html", "sweep.json")


def check_output_dir(out_dir: Path) -> Path:
    """Raise `ConfigError` (naming --out) unless `out_dir` is, or can be created as, a writable directory.

    Probes by creating what is missing and a temporary file, then removes them again: nothing is left."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError.for_field("out", f"{out_dir} is a file, not a directory; choose another")
    missing = []
    path = out_dir
    while not path.exists():
        missing.append(path)
        path = path.parent
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out_dir, prefix=".wbmpc-probe-"):
            pass
    except OSError as exc:
        raise ConfigError(f"cannot write to output directory {out_dir}: {exc.strerror}; choose another --out",
                          field="out", detail=f"directory {out_dir} cannot be created or written ({exc.strerror}); "
                          "choose another") from None
    finally:
        for path in missing:  # deepest first
            try:
                path.rmdir()
            except OSError:
                pass
    return out_dir


def previous_outputs(out_dir: Path) -> list[Path]:
    """Files an earlier wbmpc run wrote into `out_dir` (from its manifest, plus the legacy names)."""
    names = set(LEGACY_NAMES)
    manifest = out_dir / MANIFEST
    if manifest.is_file():
        try:
            names |= {str(n) for n in json.loads(manifest.read_text()).get("files", [])}
        except (ValueError, AttributeError):
            pass
    return [out_dir / n for n in sorted(names) if "/" not in n and n not in ("", ".", "..") and (out_dir / n).is_file()]


def remove_previous_outputs(out_dir: Path) -> None:
    for path in previous_outputs(out_dir):
        path.unlink()
    (out_dir / MANIFEST).unlink(missing_ok=True)


def write_output_files(out_dir: Path, write: Callable[[Path], list[Path]]) -> list[Path]:
    """Call `write(staging_dir)` (returns the files it wrote there) and publish them in `out_dir`."""
    out_dir = check_output_dir(out_dir)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".wbmpc-staging-", dir=out_dir))
    try:
        written = [Path(p) for p in write(staging)]
        remove_previous_outputs(out_dir)
        published = []
        for path in written:
            target = out_dir / path.name
            os.replace(path, target)
            published.append(target)
        (out_dir / MANIFEST).write_text(json.dumps({"files": [p.name for p in published]}, indent=1))
        return published
    except BaseException:
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def replace_file(path: Path, text: str) -> None:
    """Write `path` atomically (a reader never sees half a file)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
