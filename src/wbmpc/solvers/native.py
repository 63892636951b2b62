"""The C and C++ sources shipped with wbmpc (`solvers/csrc/`, package data) and their compilation into cached
libraries.

A library built from shipped sources only is the same for every problem: it is compiled once per machine and
cached in `wbmpc.cache.default_cache_dir()` under the hash of its sources, compiler, flags (and the CPU, with
-march=native) and anything else the caller names in `key_extra` (e.g. the directory of the headers it builds
against). Parallel builds of one key (campaign and test workers) compile to per-process files and rename.
"""

from __future__ import annotations

from dataclasses import replace
from importlib import resources
from pathlib import Path

from wbmpc.cache import default_cache_dir
from wbmpc.solvers.codegen import CodegenConfig, CompileError, CompileReport, _compile, cache_key


def source_dir() -> Path:
    """The directory of the shipped sources (`include` it for their headers)."""
    return Path(str(resources.files("wbmpc.solvers") / "csrc"))


def source_text(name: str) -> str:
    path = source_dir() / name
    try:
        return path.read_text()
    except OSError as exc:
        raise CompileError(f"wbmpc's C source {path} is missing ({exc.strerror}): reinstall wbmpc "
                           "(`pip install --force-reinstall wbmpc`); the package data csrc/ holds it") from exc


def build_native(stem: str, sources: tuple[str, ...], config: CodegenConfig, flags: tuple[str, ...],
                 link: tuple[str, ...] = (), key_extra: str = "", headers: tuple[str, ...] = ()) -> CompileReport:
    """Compile the shipped `sources` (and the `headers` they include, hashed with them) into
    `<cache>/<stem>_<key>.so` unless the cache has it. `flags` are the compiler's, `link` the libraries after
    the sources."""
    texts = [f"// {name}\n{source_text(name)}" for name in (*sources, *headers)]
    key = cache_key("\n".join([*texts, key_extra, *link]), replace(config, flags=flags))
    cache = Path(config.cache_dir or default_cache_dir())
    library = cache / f"{stem}_{key}.so"
    if library.exists():
        return CompileReport(library, cached=True, source_mb=sum(map(len, texts)) / 1e6)
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CompileError(f"cannot create the cache directory {cache}: {exc.strerror}; set WBMPC_CACHE_DIR") from exc
    paths = [source_dir() / name for name in sources]
    compile_s, peak_mb = _compile(paths, library, replace(config, flags=(*flags, f"-I{source_dir()}")), link)
    return CompileReport(library, cached=False, source_mb=sum(map(len, texts)) / 1e6, compile_s=compile_s,
                         peak_memory_mb=peak_mb)
