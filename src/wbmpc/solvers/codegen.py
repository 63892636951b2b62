"""C code generation of the NLP, compiled once into a shared library and cached by content hash.

Generating C for the expanded NLP (what `nlpsol.generate_dependencies` does) writes every node's
derivatives separately: ~40 MB of C for 15 nodes. Here the oracle functions the solver calls
(`nlp_f`, `nlp_g`, `nlp_grad_f`, `nlp_jac_g`, `nlp_hess_l`, `nlp_grad`) are assembled in MX from
per-stage SX derivatives — value, gradient, Jacobian and Lagrangian Hessian of each stage kind —
so each kind's code exists once. The Hessian is block diagonal in (x_k, u_k) because the gap rows
x_{k+1} - f(x_k, u_k) are linear in x_{k+1}. All task data stay runtime inputs (p and bounds).

The library lands in the user cache directory (`$WBMPC_CACHE_DIR`, else `$XDG_CACHE_HOME/wbmpc`,
else `~/.cache/wbmpc`) under the hash of its C source and compiler command: a second run with the
same problem structure loads it without compiling.
"""

from __future__ import annotations

import hashlib
import os
import resource
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import casadi as ca

from wbmpc.cache import default_cache_dir
from wbmpc.errors import ConfigError, WbmpcError
from wbmpc.ocp.problem import OcpProblem

# how fatrop-direct's stage library treats the curvature of the RNEA rows (stage_library.lagrangian_hessian)
DYNAMICS_HESSIANS = ("exact", "cross", "gauss-newton")


class CompileError(WbmpcError, RuntimeError):
    """Code generation or compilation failed (no compiler, time or memory limit, compiler error)."""


@dataclass(frozen=True)
class CodegenConfig:
    compiler: str = "gcc"
    # -O1 compiles wb_inverse in about a minute; -march=native (FMA, AVX2) halves the stage Hessian's
    # evaluation time at the same compile time (measured on the stage functions); the cache key names the CPU
    flags: tuple[str, ...] = ("-O1", "-march=native")
    timeout_s: float = 1800.0  # a loaded machine can take 15 min for what a quiet one compiles in 2
    memory_limit_mb: float | None = 8000.0  # address-space limit of the compiler process
    cache_dir: Path | None = None  # None: default_cache_dir()
    # generated C larger than this (MB) compiles at `large_source_optimization` instead of the flags' -O level:
    # gcc's -O1 passes grow faster than linearly with a function's length and the stage Hessians of a large robot
    # are single functions of ~200k lines. TALOS (1936 variables, 23.6 MB of C): -O1 did not finish in 30 min on
    # a loaded machine, -O0 took 64 s, and its Jacobian / Lagrangian Hessian then evaluate in 1.2 / 3.2 ms against
    # 4.5 / 11.0 ms in CasADi's virtual machine (the uncompiled solvers). g1 (17.5 MB) and smaller keep -O1
    large_source_mb: float | None = 20.0
    large_source_optimization: str = "-O0"
    # the same limit for fatrop-direct's stage library, whose C is denser (solvers/stage_library.dense_writes: no
    # stored zeros; one kind's derivatives shared, stage_covers): TALOS's is 13.9 MB now for the same Hessian bodies
    # as its 25.3 MB before (at -O0), g1's 10.6 MB (17.9 before, -O1 in 1-2.5 min)
    stage_large_source_mb: float | None = 12.0
    # fatrop-direct's stage library (solvers/stage_library.py) compiles at -O2 instead of -O1 up to this size (MB of
    # C), by default none: with the lane functions of stage_vectors, b1_z1's 4.4 MB compiled at -O2 in 340 s (load
    # 4.5; 132 s before them) against 48 s at -O1 (load 3.3), for 3.7 % of its thread CPU per Fatrop iteration
    # (1.056 -> 1.095 ms, 40 recorded trot states in one process; its functions 0.43 -> 0.48 ms); g1's 10.6 MB at -O2
    # took 1095 s / 4.1 GB for 2.4 % (2.57 -> 2.50 ms). 10 brings b1_z1's -O2 back (a one-off, cached compile)
    stage_o2_max_source_mb: float = 0.0
    # fatrop-direct's stage Hessian: the RNEA rows' curvature "exact", "cross" (only its blocks with an input:
    # d^2/du dx, d^2/du^2) or "gauss-newton" (none); see stage_library.lagrangian_hessian. Inexact ones cost g1
    # twice the iterations; "cross" keeps b1_z1's at -8 % CPU a solve (docs/design/realtime-loop.md)
    dynamics_hessian: str = "exact"

    def __post_init__(self):
        if self.dynamics_hessian not in DYNAMICS_HESSIANS:
            raise ConfigError(f"unknown dynamics_hessian '{self.dynamics_hessian}'; choose from "
                              f"{', '.join(DYNAMICS_HESSIANS)}")


@dataclass
class CompileReport:
    library: Path
    cached: bool
    source_mb: float
    compile_s: float = 0.0  # 0 when loaded from the cache
    peak_memory_mb: float = 0.0
    generate_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"library": str(self.library), "cached": self.cached, "source_mb": round(self.source_mb, 2),
                "compile_s": round(self.compile_s, 2), "peak_memory_mb": round(self.peak_memory_mb, 1),
                "generate_s": round(self.generate_s, 2)}


def cache_key(code: str, config: CodegenConfig) -> str:
    """Hash of everything the library depends on: casadi, compiler, flags, the C code, and the CPU when
    the flags tune for it (-march=native code may not run on another CPU)."""
    native = any(flag.startswith(("-march=native", "-mtune=native", "-mcpu=native")) for flag in config.flags)
    parts = [ca.__version__, config.compiler, *config.flags, *([cpu_identity()] if native else []), code]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def for_source(config: CodegenConfig, source_mb: float) -> CodegenConfig:
    """The settings a generated source of this size compiles with: above `large_source_mb` the flags' -O level
    is replaced by `large_source_optimization` (the cache key follows the flags used)."""
    if config.large_source_mb is None or source_mb <= config.large_source_mb:
        return config
    flags = (*[flag for flag in config.flags if not flag.startswith("-O")], config.large_source_optimization)
    return replace(config, flags=flags)


def cpu_identity() -> str:
    """Model name and feature flags of this CPU: code built with -march=native is cached per CPU."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        import platform

        return platform.processor() or platform.machine()
    wanted = ("model name", "flags", "Features", "CPU implementer", "CPU part")
    return "\n".join(sorted({line.strip() for line in lines if line.split(":")[0].strip() in wanted}))


def _stage_derivatives(function: ca.Function) -> dict[str, ca.Function]:
    """Value, cost gradient, Jacobian and Lagrangian (gradient, Hessian) of one stage kind in z = [x_k; u_k]."""
    n_x, n_u, n_p = function.size1_in(0), function.size1_in(1), function.size1_in(2)
    z, p = ca.SX.sym("z", n_x + n_u), ca.SX.sym("p", n_p)
    next_state, rows, cost = function(z[:n_x], z[n_x:], p)
    sigma = ca.SX.sym("sigma")
    lam_gap, lam_rows = ca.SX.sym("lam_gap", next_state.shape[0]), ca.SX.sym("lam_rows", rows.shape[0])
    lagrangian = sigma * cost - ca.dot(lam_gap, next_state) + ca.dot(lam_rows, rows)  # gap rows: x_{k+1} - f
    hessian, gradient = ca.hessian(lagrangian, z)
    name = function.name()
    return {
        "value": ca.Function(f"{name}_value", [z, p], [next_state, rows]),
        "cost": ca.Function(f"{name}_cost", [z, p], [cost]),  # nlp_f alone: no dynamics evaluated
        "cost_gradient": ca.Function(f"{name}_cost_gradient", [z, p], [cost, ca.gradient(cost, z)]),
        "jacobian": ca.Function(f"{name}_jacobian", [z, p], [ca.jacobian(next_state, z), ca.jacobian(rows, z)]),
        "lagrangian": ca.Function(f"{name}_lagrangian", [z, p, sigma, lam_gap, lam_rows], [gradient, hessian]),
    }


def _stage_parts(problem: OcpProblem, x: ca.MX, p: ca.MX, lam_f: ca.MX, lam_g: ca.MX) -> dict:
    """The NLP's pieces from each node's stage derivatives (one set per stage kind): cost, rows of g, cost
    gradient blocks, Jacobian rows, Lagrangian gradient and Hessian blocks."""
    N, nx, n = problem.N, problem.nx, problem.n_variables
    derivatives: dict[str, dict[str, ca.Function]] = {}
    out = {"cost": 0, "rows": [], "cost_gradient": [], "jacobian_rows": [], "lagrangian_gradient": [], "hessian": []}
    row, previous_lam_gap = 0, None
    for k in range(N + 1):
        function, _ = problem.stage_function(k)
        d = derivatives.setdefault(function.name(), _stage_derivatives(function))
        state, inputs = problem.stage_slices[k]
        z = x[state.start : inputs.stop]
        n_z, before, after = inputs.stop - state.start, state.start, n - inputs.stop
        p_k = problem.stage_parameters(p, k)
        next_state, path = d["value"](z, p_k)
        stage_cost = d["cost"](z, p_k)  # (the calls in this order: the generated code, its cache key, unchanged)
        n_gap, n_path = (nx if k < N else 0), path.shape[0]
        lam_gap, lam_path = lam_g[row : row + n_gap], lam_g[row + n_gap : row + n_gap + n_path]
        gradient, hessian = d["lagrangian"](z, p_k, lam_f, lam_gap, lam_path)
        if previous_lam_gap is not None:  # x_k enters the previous gap rows with coefficient +1
            gradient = gradient + ca.vertcat(previous_lam_gap, ca.MX(n_z - nx, 1))
        jac_next, jac_path = d["jacobian"](z, p_k)
        if k < N:
            out["rows"].append(x[problem.stage_slices[k + 1][0]] - next_state)
            out["jacobian_rows"].append(ca.horzcat(ca.MX(nx, before), -jac_next, ca.MX.eye(nx), ca.MX(nx, after - nx)))
        out["rows"].append(path)
        out["jacobian_rows"].append(ca.horzcat(ca.MX(n_path, before), jac_path, ca.MX(n_path, after)))
        out["cost"] += stage_cost
        out["cost_gradient"].append(d["cost_gradient"](z, p_k)[1])
        out["lagrangian_gradient"].append(gradient)
        out["hessian"].append(hessian)
        previous_lam_gap = lam_gap
        row += n_gap + n_path
    return out


def nlp_functions(problem: OcpProblem, solver: str = "fatrop") -> list[ca.Function]:
    """The oracle functions casadi's `nlpsol` loads from a library, built from stage derivatives.

    Signatures follow the solver plugin: Fatrop takes the full Hessian and `nlp_hess_l` also returns
    the Lagrangian gradient; IPOPT takes its upper triangle and `nlp_grad_f` also returns f.
    """
    n = problem.n_variables
    x, p = ca.MX.sym("x", n), ca.MX.sym("p", problem.params.size)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", problem.n_constraints)
    parts = _stage_parts(problem, x, p, lam_f, lam_g)
    cost, rows, cost_gradient, jacobian_rows, lagrangian_gradient, hessian_blocks = (
        parts[name] for name in ("cost", "rows", "cost_gradient", "jacobian_rows", "lagrangian_gradient", "hessian"))
    g = ca.vertcat(*rows)
    gamma = lam_f * cost + ca.dot(lam_g, g)
    hessian = ca.diagcat(*hessian_blocks)
    grad_f = ca.vertcat(*cost_gradient)
    xp, xpl = ["x", "p"], ["x", "p", "lam_f", "lam_g"]
    if solver == "fatrop":
        grad_f_fn = ca.Function("nlp_grad_f", [x, p], [grad_f], xp, ["grad_f_x"])
        hess_fn = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.vertcat(*lagrangian_gradient), hessian], xpl,
                              ["grad_gamma_x", "hess_gamma_x_x"])
    else:
        grad_f_fn = ca.Function("nlp_grad_f", [x, p], [cost, grad_f], xp, ["f", "grad_f_x"])
        hess_fn = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.triu(hessian)], xpl, ["triu_hess_gamma_x_x"])
    return [
        ca.Function("nlp", [x, p], [cost, g], xp, ["f", "g"]),
        ca.Function("nlp_f", [x, p], [cost], xp, ["f"]),
        ca.Function("nlp_g", [x, p], [g], xp, ["g"]),
        grad_f_fn,
        ca.Function("nlp_jac_g", [x, p], [g, ca.vertcat(*jacobian_rows)], xp, ["g", "jac_g_x"]),
        hess_fn,
        # called once per solve for the parameter multipliers: plain MX reverse mode is enough
        ca.Function("nlp_grad", [x, p, lam_f, lam_g], [cost, g, ca.gradient(gamma, x), ca.gradient(gamma, p)], xpl,
                    ["f", "g", "grad_gamma_x", "grad_gamma_p"]),
    ]


def _compile(source: Path | list[Path], library: Path, config: CodegenConfig,
             link: tuple[str, ...] = ()) -> tuple[float, float]:
    """Run the compiler on one or more sources (C or C++, by extension) with a time and memory limit, then `link`
    (libraries after the sources); (seconds, peak resident MB)."""
    compiler = shutil.which(config.compiler)
    if compiler is None:
        raise CompileError(f"no C compiler '{config.compiler}' on PATH: install gcc (e.g. apt install gcc) "
                           "or run without --compiled")
    partial = library.with_suffix(f".{os.getpid()}.tmp")
    sources = [str(s) for s in (source if isinstance(source, (list, tuple)) else [source])]
    command = [compiler, *config.flags, "-shared", "-fPIC", *sources, "-o", str(partial), *link, "-lm"]
    limit = None if config.memory_limit_mb is None else int(config.memory_limit_mb * 2**20)

    def limit_memory():  # runs in the child before exec
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    start = time.perf_counter()
    log = tempfile.TemporaryFile()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=log, preexec_fn=limit_memory)
    deadline = start + config.timeout_s
    while True:  # wait4 gives this compiler's own peak memory (getrusage would give all children's)
        pid, status, usage = os.wait4(process.pid, os.WNOHANG)
        if pid:
            break
        if time.perf_counter() > deadline:
            process.kill()
            os.wait4(process.pid, 0)
            partial.unlink(missing_ok=True)
            raise CompileError(f"compiling {Path(sources[0]).name} took over {config.timeout_s:.0f} s; raise "
                               "CodegenConfig.timeout_s or use the non-compiled solver")
        time.sleep(0.05)
    elapsed = time.perf_counter() - start
    exit_code = process.returncode = os.waitstatus_to_exitcode(status)  # reaped by wait4: tell Popen
    log.seek(0)
    stderr = log.read()
    log.close()
    peak_mb = usage.ru_maxrss / 1024
    if exit_code != 0:
        partial.unlink(missing_ok=True)
        message = stderr.decode(errors="replace").strip().splitlines()[-3:]
        memory_hint = " (out of memory? raise CodegenConfig.memory_limit_mb)" if "memory" in " ".join(message).lower() else ""
        names = ", ".join(Path(name).name for name in sources)
        raise CompileError(f"{config.compiler} failed on {names}{memory_hint}: {' | '.join(message)}")
    os.replace(partial, library)
    return elapsed, peak_mb


def compile_nlp(problem: OcpProblem, solver: str = "fatrop", config: CodegenConfig = CodegenConfig()) -> CompileReport:
    """Generate the NLP's C code, compile it unless the cache has it, and return where it is."""
    start = time.perf_counter()
    functions = nlp_functions(problem, solver)
    generator = ca.CodeGenerator("wbmpc_nlp.c", {"with_header": False})
    for function in functions:
        generator.add(function)
    return _build(generator.dump(), f"{problem.config.formulation}_{solver}", config, time.perf_counter() - start)


def compile_functions(functions: list[ca.Function], stem: str, config: CodegenConfig = CodegenConfig()
                      ) -> CompileReport:
    """Other functions evaluated every MPC step (not the NLP's: e.g. the MPC's plan unpacking) compiled into one
    cached library named `stem`_<key>.so, as `compile_nlp` does; load them with `casadi.external(name, library)`."""
    start = time.perf_counter()
    generator = ca.CodeGenerator(f"{stem}.c", {"with_header": False})
    for function in functions:
        generator.add(function)
    return _build(generator.dump(), stem, config, time.perf_counter() - start)


def _build(code: str, stem: str, config: CodegenConfig, generate_s: float) -> CompileReport:
    """The library of this generated C from the cache, compiled into it first where it is not there yet."""
    source_mb = len(code) / 1e6
    config = for_source(config, source_mb)
    key = cache_key(code, config)
    cache = Path(config.cache_dir or default_cache_dir())
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CompileError(f"cannot create the cache directory {cache}: {exc.strerror}; set WBMPC_CACHE_DIR") from exc
    stem = f"{stem}_{key}"
    library = cache / f"{stem}.so"
    if library.exists():
        return CompileReport(library, cached=True, source_mb=source_mb, generate_s=generate_s)
    source = cache / f"{stem}.{os.getpid()}.c"  # per process: parallel builds of one key never share a file
    source.write_text(code)
    try:
        compile_s, peak_mb = _compile(source, library, config)
    finally:
        source.unlink(missing_ok=True)
    return CompileReport(library, cached=False, source_mb=source_mb, compile_s=compile_s, peak_memory_mb=peak_mb,
                         generate_s=generate_s)
