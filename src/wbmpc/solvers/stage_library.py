"""The OCP's stage functions as one compiled library for the direct Fatrop binding (`fatrop_direct.py`).

Fatrop asks an OCP for per-stage blocks: the transposed dynamics Jacobian BAbt, the Lagrangian Hessian RSQrqt,
the equality and inequality Jacobians Ggt / Ggt_ineq, constraint values, cost gradients and bounds. Each stage
kind's blocks are generated here directly in Fatrop's (u_k, x_k) order and dense (`stage_kind_functions`), so each
block is one generated call and one BLASFEO pack. The generated C and a table describing the problem
(`csrc/wbmpc_stages.h`: sizes, offsets, stage kinds and the functions) compile into one library per problem
structure; the shim that answers Fatrop (`fatrop_shim.py`) is compiled once per machine and reads the problem only
through that table. Stage parameters are rows of a (N+1, n_p) array (`p_index` maps them into the NLP's p).

The library lands in the cache directory of `codegen.py` as `<formulation>_stages_<key>.so`, the key hashing the
generated C, the table header, compiler and flags.
"""

from __future__ import annotations

import ctypes
import os
import time
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np

from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers.codegen import (
    CodegenConfig,
    CompileError,
    CompileReport,
    _compile,
    cache_key,
    default_cache_dir,
    for_source,
)
from wbmpc.solvers.native import source_dir, source_text

FUNCTION_KINDS = ("hess", "jac", "val", "grad", "cost")  # the order of wbmpc_stages.h's WB_HESS, ...
STAGES_VERSION = 1  # WB_STAGES_VERSION of csrc/wbmpc_stages.h
O2_MAX_SOURCE_MB = 10.0  # generated C up to this size compiles at -O2 instead of CodegenConfig's -O1 (see build)


def stage_kind_functions(function: ca.Function, tag: str) -> list[ca.Function]:
    """The five C functions of one stage kind, inputs (u_k, x_k, p_k) in Fatrop's order, dense outputs.

    hess: Hessian in (u, x) of sigma l + lam_dyn' f + lam_rows' r (Fatrop's stage Lagrangian, the
    x_{k+1} term of the dynamics being linear); jac: d f/d(u, x) transposed and d r/d(u, x) transposed;
    val: f and r; grad: d l/d(u, x); cost: l.
    """
    n_x, n_u, n_p = function.size1_in(0), function.size1_in(1), function.size1_in(2)
    u, x, p = ca.SX.sym("u", n_u), ca.SX.sym("x", n_x), ca.SX.sym("p", n_p)
    z = ca.vertcat(u, x)
    next_state, rows, cost = function(x, u, p)
    sigma = ca.SX.sym("sigma")
    lam_dyn, lam_rows = ca.SX.sym("lam_dyn", next_state.shape[0]), ca.SX.sym("lam_rows", rows.shape[0])
    lagrangian = sigma * cost + ca.dot(lam_dyn, next_state) + ca.dot(lam_rows, rows)
    hessian = ca.hessian(lagrangian, z)[0]
    dense = ca.densify
    return [
        ca.Function(f"{tag}_hess", [u, x, p, sigma, lam_dyn, lam_rows], [dense(hessian)]),
        ca.Function(f"{tag}_jac", [u, x, p], [dense(ca.jacobian(next_state, z).T), dense(ca.jacobian(rows, z).T)]),
        ca.Function(f"{tag}_val", [u, x, p], [dense(next_state), dense(rows)]),
        ca.Function(f"{tag}_grad", [u, x, p], [dense(ca.gradient(cost, z))]),
        ca.Function(f"{tag}_cost", [u, x, p], [dense(cost)]),
    ]


def _c_array(name: str, values) -> str:
    return f"static const int {name}[] = {{{', '.join(str(int(v)) for v in values)}}};\n"


def _stage_kinds(problem: OcpProblem) -> tuple[list[ca.Function], dict]:
    """The generated functions of each stage kind and the per-stage table columns."""
    N, nx = problem.N, problem.nx
    kinds: dict[str, int] = {}
    functions: list[ca.Function] = []
    columns = {name: [] for name in ("kind", "nx", "nu", "nr", "x_offset", "row_offset", "gap_offset")}
    for k in range(N + 1):
        function, _ = problem.stage_function(k)
        if function.name() not in kinds:
            kinds[function.name()] = len(kinds)
            functions += stage_kind_functions(function, f"wbk{kinds[function.name()]}")
        state, inputs = problem.stage_slices[k]
        gap = int(problem.stage_row_starts[k])
        for name, value in (("kind", kinds[function.name()]), ("nx", nx), ("nu", inputs.stop - inputs.start),
                            ("nr", function.size1_out(1)), ("x_offset", state.start),
                            ("gap_offset", gap if k < N else -1), ("row_offset", gap + (nx if k < N else 0))):
            columns[name].append(value)
    return functions, columns


def _table(problem: OcpProblem, functions: list[ca.Function], columns: dict, n_p: int) -> str:
    """The C table (`wb_stages`) of the problem, compiled beside the generated functions."""
    sizes = np.array([[f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()] for f in functions]).max(axis=0)
    n_kinds = len(functions) // len(FUNCTION_KINDS)
    pointers = ", ".join(f"wbk{i}_{kind}" for i in range(n_kinds) for kind in FUNCTION_KINDS)
    max_n = max(a + b for a, b in zip(columns["nx"], columns["nu"]))
    fields = [STAGES_VERSION, problem.N + 1, n_p, problem.n_variables, problem.n_constraints, n_kinds,
              *[f"wb_{name}" for name in ("kind", "nx", "nu", "nr", "x_offset", "row_offset", "gap_offset")],
              "wb_functions", *sizes, max_n, max(columns["nx"]), max(max(columns["nr"]), 1)]
    return "".join([
        '\n/* ---- wbmpc: the problem table (wbmpc_stages.h) ---- */\n#include "wbmpc_stages.h"\n',
        *[_c_array(f"wb_{name}", values) for name, values in columns.items()],
        f"static const wb_fn wb_functions[] = {{{pointers}}};\n",
        f"static const wb_stages wb_problem = {{{', '.join(str(f) for f in fields)}}};\n",
        "const wb_stages* wbmpc_stages(void) { return &wb_problem; }\n",
    ])


def generate_source(problem: OcpProblem) -> tuple[str, np.ndarray]:
    """The C source of the stage library for `problem` and the (N+1, n_p) index map of the stage parameters into p."""
    functions, columns = _stage_kinds(problem)
    n_p = functions[0].size1_in(2)
    p_index = np.array([np.asarray(ca.evalf(problem.stage_parameters(ca.DM(np.arange(problem.params.size)), k)))
                        .ravel() for k in range(problem.N + 1)]).round().astype(np.int64)
    assert p_index.shape == (problem.N + 1, n_p)
    generator = ca.CodeGenerator("wbmpc_stages.c", {"with_header": False})
    for function in functions:
        generator.add(function)
    return generator.dump() + _table(problem, functions, columns, n_p), p_index


def compile_flags(config: CodegenConfig, source_mb: float) -> tuple[CodegenConfig, tuple[str, ...]]:
    """The settings a stage library of this size compiles with. CodegenConfig's default -O1 (chosen for the
    whole-NLP library's compile time) becomes -O2 up to O2_MAX_SOURCE_MB: b1_z1's stage functions evaluate 2.63 ->
    1.60 ms per closed-loop step for one longer, cached compile (7.6 MB of C, load ~4: 80 s and 0.86 GB at -O1,
    254 s and 0.96 GB at -O2); larger sources follow `codegen.for_source` (TALOS-sized at -O0)."""
    config = for_source(config, source_mb)
    optimize = source_mb <= O2_MAX_SOURCE_MB
    return config, tuple("-O2" if flag == "-O1" and optimize else flag for flag in config.flags)


def build(problem: OcpProblem, config: CodegenConfig = CodegenConfig()) -> tuple[CompileReport, np.ndarray]:
    """Generate, compile (unless cached) and return the stage library and the stage parameter map."""
    start = time.perf_counter()
    code, p_index = generate_source(problem)
    generate_s = time.perf_counter() - start
    source_mb = len(code) / 1e6
    config, flags = compile_flags(config, source_mb)
    key = cache_key(code + source_text("wbmpc_stages.h"), replace(config, flags=flags))
    cache = Path(config.cache_dir or default_cache_dir())
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CompileError(f"cannot create the cache directory {cache}: {exc.strerror}; set WBMPC_CACHE_DIR") from exc
    library = cache / f"{problem.config.formulation}_stages_{key}.so"
    if library.exists():
        return CompileReport(library, cached=True, source_mb=source_mb, generate_s=generate_s), p_index
    source = cache / f"{library.stem}.{os.getpid()}.c"  # per process: parallel builds of one key never share a file
    source.write_text(code)
    try:
        compile_s, peak_mb = _compile(source, library, replace(config, flags=(*flags, f"-I{source_dir()}")))
    finally:
        source.unlink(missing_ok=True)
    return CompileReport(library, cached=False, source_mb=source_mb, compile_s=compile_s, peak_memory_mb=peak_mb,
                         generate_s=generate_s), p_index


class StageLibrary:
    """A compiled stage library loaded with ctypes; `table` is its `wb_stages*` for the shim."""

    def __init__(self, report: CompileReport, p_index: np.ndarray):
        self.report, self.p_index = report, p_index
        self.lib = ctypes.CDLL(str(report.library))
        self.lib.wbmpc_stages.restype = ctypes.c_void_p
        self.table = ctypes.c_void_p(self.lib.wbmpc_stages())
