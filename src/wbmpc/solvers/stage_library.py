"""The OCP's stage functions as one compiled library for the direct Fatrop binding (`fatrop_direct.py`).

Fatrop asks an OCP for per-stage blocks: the transposed dynamics Jacobian BAbt, the Lagrangian Hessian RSQrqt,
the equality and inequality Jacobians Ggt / Ggt_ineq, constraint values, cost gradients and bounds. Each stage
kind's blocks are generated here directly in Fatrop's (u_k, x_k) order (`stage_kind_functions`) and written dense
(`dense_writes`: the structural nonzeros into a cleared column-major buffer), so each block is one generated call
and one BLASFEO pack; the Hessian and Jacobian also on 4 stages of a kind at once (`stage_vectors`). The generated C and a table of the stage kinds
(`csrc/wbmpc_stages.h`: their functions and work sizes) compile into one library per set of stage kinds (the
horizon's length does not enter: 10 or 40 nodes of one formulation share it); the shim that answers Fatrop
(`fatrop_shim.py`) is compiled once per machine and gets the stages' layout (kinds, sizes, offsets) from Python.
Stage parameters are rows of a (N+1, n_p) array (`p_index` maps them into the NLP's p).

The library lands in the cache directory of `codegen.py` as `<formulation>_stages_<key>.so`, the key hashing the
generated C, the table's header, compiler and flags.
"""

from __future__ import annotations

import ctypes
import os
import re
import time
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np

from wbmpc.cache import default_cache_dir
from wbmpc.errors import ConfigError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers.codegen import (
    DYNAMICS_HESSIANS,
    CodegenConfig,
    CompileError,
    CompileReport,
    _compile,
    cache_key,
    for_source,
)
from wbmpc.solvers.native import source_dir, source_text
from wbmpc.solvers.stage_covers import Cover, find_covers
from wbmpc.solvers.stage_covers import wrappers as cover_wrappers
from wbmpc.solvers.stage_vectors import LANES, vectorize

FUNCTION_KINDS = ("hess", "jac", "val", "grad", "cost")  # the order of wbmpc_stages.h's WB_HESS, ...
KINDS_VERSION = 3  # WB_KINDS_VERSION of csrc/wbmpc_stages.h


DYNAMICS_TAGS = ("dynamics", "implied_torque")  # the path rows that are RNEA rows (eq. 5) on wb_inverse


def stage_kind_functions(function: ca.Function, tag: str, row_tags: list[tuple[str, int]] | None = None,
                         dynamics_hessian: str = "exact", dense: bool = False) -> list[ca.Function]:
    """The five C functions of one stage kind, inputs (u_k, x_k, p_k) in Fatrop's order; outputs sparse (the shim
    gets them dense all the same: `dense_writes`) or, with `dense`, densified.

    hess: Hessian in (u, x) of sigma l + lam_dyn' f + lam_rows' r (Fatrop's stage Lagrangian, the
    x_{k+1} term of the dynamics being linear); jac: d f/d(u, x) transposed and d r/d(u, x) transposed;
    val: f and r; grad: d l/d(u, x); cost: l. `dynamics_hessian` (with the rows' `row_tags`, as
    `OcpProblem.stage_function` gives them) approximates the curvature of the dynamics rows (`DYNAMICS_TAGS`):
    see `lagrangian_hessian`.
    """
    n_x, n_u, n_p = function.size1_in(0), function.size1_in(1), function.size1_in(2)
    u, x, p = ca.SX.sym("u", n_u), ca.SX.sym("x", n_x), ca.SX.sym("p", n_p)
    z = ca.vertcat(u, x)
    next_state, rows, cost = function(x, u, p)
    sigma = ca.SX.sym("sigma")
    lam_dyn, lam_rows = ca.SX.sym("lam_dyn", next_state.shape[0]), ca.SX.sym("lam_rows", rows.shape[0])
    dynamics = _tagged_rows(row_tags or [], DYNAMICS_TAGS)
    hessian = lagrangian_hessian(u, x, sigma * cost + ca.dot(lam_dyn, next_state), rows, lam_rows, dynamics,
                                 dynamics_hessian)
    dense = ca.densify if dense else (lambda expr: expr)
    return [
        ca.Function(f"{tag}_hess", [u, x, p, sigma, lam_dyn, lam_rows], [dense(hessian)]),
        ca.Function(f"{tag}_jac", [u, x, p], [dense(ca.jacobian(next_state, z).T), dense(ca.jacobian(rows, z).T)]),
        ca.Function(f"{tag}_val", [u, x, p], [dense(next_state), dense(rows)]),
        ca.Function(f"{tag}_grad", [u, x, p], [dense(ca.gradient(cost, z))]),
        ca.Function(f"{tag}_cost", [u, x, p], [dense(cost)]),
    ]


def _tagged_rows(row_tags: list[tuple[str, int]], wanted: tuple[str, ...]) -> list[int]:
    """Indices of the path rows whose tag is in `wanted`."""
    out, start = [], 0
    for name, size in row_tags:
        if name in wanted:
            out += range(start, start + size)
        start += size
    return out


def lagrangian_hessian(u: ca.SX, x: ca.SX, rest: ca.SX, rows: ca.SX, lam_rows: ca.SX, dynamics: list[int],
                       mode: str = "exact") -> ca.SX:
    """Hessian in z = (u, x) of rest + lam_rows' rows, the curvature of the rows `dynamics` (the RNEA rows)
    as `mode` says:

    - "exact": all of it.
    - "cross": their blocks with an input only, (u, u) and (u, x); their (x, x) block dropped. RNEA is linear in
      a and F (eq. 5), so what stays is exact d^2/(d x d u) (M(q)'s and J_c(q)'s derivatives in lam's direction)
      and what goes is the curvature of gravity, the contacts, Coriolis and the inertia in (q, v) (g1's plain stage
      Hessian 139.6k -> 52.7k CasADi instructions).
    - "gauss-newton": none of it (the rows' curvature dropped; the cost's and the other rows' kept: 38.9k).

    An inexact Hessian keeps the KKT point (same constraints and stationarity) but can cost iterations: on b1_z1's
    trot "cross" keeps them (-8 % CPU a solve), on g1's walk both double them (6.4 -> 13.8 / 18.3 on recorded
    states), hence "exact" by default (docs/design/realtime-loop.md)."""
    if mode not in DYNAMICS_HESSIANS:
        raise ConfigError(f"unknown dynamics_hessian '{mode}'; choose from {', '.join(DYNAMICS_HESSIANS)}")
    z = ca.vertcat(u, x)
    if mode == "exact" or not dynamics:
        return ca.hessian(rest + ca.dot(lam_rows, rows), z)[0]
    others = [i for i in range(rows.shape[0]) if i not in set(dynamics)]
    hessian = ca.hessian(rest + ca.dot(lam_rows[others], rows[others]), z)[0]
    if mode == "gauss-newton":
        return hessian
    n_u, n_x = u.shape[0], x.shape[0]
    with_input = ca.jacobian(ca.gradient(ca.dot(lam_rows[dynamics], rows[dynamics]), u), z)  # (u, z) rows
    return hessian + ca.vertcat(with_input, ca.horzcat(with_input[:, n_u:].T, ca.SX(n_x, n_x)))


LAYOUT_ROWS = ("kind", "nx", "nu", "nr", "x_offset", "row_offset", "gap_offset")  # wbmpc_stages.h's WB_L_*


def _stage_kinds(problem: OcpProblem, dynamics_hessian: str = "exact", dense: bool = False
                 ) -> tuple[list[ca.Function], np.ndarray, int, dict[int, Cover]]:
    """The generated functions of the stage kinds (in order of first appearance; a covered kind's Hessian and
    Jacobian left out: `stage_covers`), the stages' layout (LAYOUT_ROWS x (N+1) ints), the number of kinds and
    their covers."""
    N, nx = problem.N, problem.nx
    kinds: dict[str, int] = {}
    stages: list[tuple[ca.Function, list[tuple[str, int]]]] = []
    layout = np.zeros((len(LAYOUT_ROWS), N + 1), dtype=np.int32)
    for k in range(N + 1):
        function, row_tags = problem.stage_function(k)
        if function.name() not in kinds:
            kinds[function.name()] = len(kinds)
            stages.append((function, row_tags))
        state, inputs = problem.stage_slices[k]
        gap = int(problem.stage_row_starts[k])
        layout[:, k] = (kinds[function.name()], nx, inputs.stop - inputs.start, function.size1_out(1), state.start,
                        gap + (nx if k < N else 0), gap if k < N else -1)
    covers = find_covers(stages)
    functions: list[ca.Function] = []
    for kind, (function, row_tags) in enumerate(stages):
        generated = stage_kind_functions(function, f"wbk{kind}", row_tags, dynamics_hessian, dense)
        functions += generated[2:] if kind in covers else generated
    return functions, layout, len(stages), covers


_BODY_SIGNATURE = "(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem)"


def code_sections(code: str, names: list[str]) -> tuple[str, list[str]]:
    """The generated C with each named function's body (CasADi's static `casadi_f<i>` its export calls) in a
    section of its own (not inlined into its export), and the C expressions of each body's first and past-the-end
    byte (the linker's __start_/__stop_ symbols of the section, weak: 0 if a section is missing; "0" where CasADi's
    text is not as expected): the shim prefetches a kind's code before its first call (`csrc/stage_tasks.c`).
    Placement only: the body's instructions are the same."""
    ranges = []
    for name in names:
        found = re.search(re.escape(f"int {name}{_BODY_SIGNATURE}") + r"\{\s*return (casadi_f\d+)\(", code)
        definition = f"static int {found.group(1)}{_BODY_SIGNATURE} {{" if found else None
        if definition is None or code.count(definition) != 1:
            ranges += ["0", "0"]
            continue
        section = f"wbmpc_code_{name}"
        code = code.replace(definition, f'__attribute__((noinline, section("{section}"))) {definition}')
        ranges += [f"__start_{section}", f"__stop_{section}"]
    return code, ranges


_OUTPUT_WRITE = re.compile(r"if \(res\[(\d+)\]!=0\) res\[\1\]\[(\d+)\]=")


def dense_writes(code: str, functions: list[ca.Function]) -> str | None:
    """The generated C of `functions` (sparse outputs) rewritten to write each output's nonzeros straight into the
    dense column-major buffer the shim passes, after one memset of that buffer; None where CasADi's text is not as
    expected (then the caller generates densified outputs). CasADi's densified outputs store every structural zero
    one by one, each behind a null check of its buffer (the shim passes every output): g1's plain stage Hessian
    stores 10404 values of which 2404 are nonzero, its Jacobian 10506 of 1217. The arithmetic is the same
    instructions in the same order, so the values are bit for bit those of the dense outputs; only less machine
    code streams through the core per call (g1's plain stage Hessian 1.51 -> 1.28 MB)."""
    for function in functions:
        found = re.search(re.escape(f"int {function.name()}{_BODY_SIGNATURE}") + r"\{\s*return (casadi_f\d+)\(", code)
        head = f"static int {found.group(1)}{_BODY_SIGNATURE} {{\n" if found else None
        if head is None or code.count(head) != 1:
            return None
        start = code.index(head) + len(head)
        end = code.find("\n  return 0;\n}\n", start)
        if end < 0:
            return None
        outputs = [function.sparsity_out(i) for i in range(function.n_out())]
        positions = [np.array(sparsity.row(), dtype=int) + sparsity.size1() * np.array(sparsity.get_col(), dtype=int)
                     for sparsity in outputs]  # column-major place of each nonzero
        written = []

        def dense(found: re.Match) -> str:
            i, k = int(found.group(1)), int(found.group(2))
            written.append((i, k))
            return f"res[{i}][{positions[i][k]}]="

        body = _OUTPUT_WRITE.sub(dense, code[start:end])
        if sorted(written) != [(i, k) for i, sparsity in enumerate(outputs) for k in range(sparsity.nnz())]:
            return None
        zeros = "".join(f"  memset(res[{i}], 0, sizeof(casadi_real) * {sparsity.numel()});\n"
                        for i, sparsity in enumerate(outputs) if sparsity.nnz() < sparsity.numel())
        code = code[:start] + zeros + body + code[end:]
    return "#include <string.h>\n" + code


def _kinds_table(functions: list[ca.Function], code_ranges: list[str], n_kinds: int, covers: dict[int, Cover],
                 lane_functions: list[str]) -> str:
    """The C table of the stage kinds (`wb_kinds`) and the covered kinds' wrappers, compiled beside the generated
    functions; a covered kind's Hessian and Jacobian have its cover's code range (the code they run); the functions
    named in `lane_functions` have a `<name>_lanes` version of LANES stages (stage_vectors.py)."""
    by_name = {f.name(): f for f in functions}
    ranges = dict(zip([f.name() for f in functions], zip(code_ranges[::2], code_ranges[1::2])))
    sizes = np.array([[f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()] for f in functions]).max(axis=0)
    wrappers = []
    for kind, cover in sorted(covers.items()):
        jac_work = by_name[f"wbk{cover.cover}_jac"].sz_w()
        sizes[3] = max(sizes[3], jac_work + cover.n_z * cover.cover_rows)
        wrappers.append(cover_wrappers(cover, jac_work))
        for name in ("hess", "jac"):
            ranges[f"wbk{kind}_{name}"] = ranges[f"wbk{cover.cover}_{name}"]
    names = [f"wbk{i}_{kind}" for i in range(n_kinds) for kind in FUNCTION_KINDS]
    code = [bound for name in names for bound in ranges[name]]
    lanes = [f"wbk{i}_{kind}_lanes" if f"wbk{i}_{kind}" in lane_functions else "0"
             for i in range(n_kinds) for kind in ("hess", "jac")]
    cover_table = [f"{{{c.cover}, {c.cover_rows}, wbk{k}_cover_lam, wbk{k}_cover_rows}}" if (c := covers.get(k))
                   else "{-1, 0, 0, 0}" for k in range(n_kinds)]
    fields = [KINDS_VERSION, n_kinds, "wb_functions", *sizes, "wb_code", LANES, "wb_lane_functions", "wb_covers"]
    bounds = sorted({name for name in code if name != "0"})
    return "".join([
        *(["\n#include <string.h>\n", *wrappers] if wrappers else []),
        '\n/* ---- wbmpc: the table of the stage kinds (wbmpc_stages.h) ---- */\n#include "wbmpc_stages.h"\n',
        "".join(f"extern const char {name}[] __attribute__((weak, visibility(\"hidden\")));\n" for name in bounds),
        f"static const wb_fn wb_functions[] = {{{', '.join(names)}}};\n",
        f"static const char* const wb_code[] = {{{', '.join(code)}}};\n",
        f"static const wb_lane_fn wb_lane_functions[] = {{{', '.join(lanes)}}};\n",
        f"static const wb_cover wb_covers[] = {{{', '.join(cover_table)}}};\n",
        f"static const wb_kinds wb_stage_kinds = {{{', '.join(str(f) for f in fields)}}};\n",
        "const wb_kinds* wbmpc_stage_kinds(void) { return &wb_stage_kinds; }\n",
    ])


def generate_source(problem: OcpProblem, dynamics_hessian: str = "exact") -> tuple[str, np.ndarray, np.ndarray]:
    """The C source of the stage library for `problem`, the (N+1, n_p) index map of the stage parameters into p and
    the stages' layout for the shim (LAYOUT_ROWS x (N+1)). The source depends on the kinds of stages only: another
    horizon length with the same kinds reuses the library."""
    functions, layout, n_kinds, covers = _stage_kinds(problem, dynamics_hessian)
    code = dense_writes(_generated(functions), functions)
    if code is None:  # CasADi's text not as expected: its own densified outputs
        functions, layout, n_kinds, covers = _stage_kinds(problem, dynamics_hessian, dense=True)
        code = _generated(functions)
    n_p = functions[0].size1_in(2)
    p_index = np.array([np.asarray(ca.evalf(problem.stage_parameters(ca.DM(np.arange(problem.params.size)), k)))
                        .ravel() for k in range(problem.N + 1)]).round().astype(np.int64)
    assert p_index.shape == (problem.N + 1, n_p)
    code, code_ranges = code_sections(code, [function.name() for function in functions])
    derivatives = [f for f in functions if f.name().endswith(("_hess", "_jac"))]
    code, lane_functions = vectorize(code, [f.name() for f in derivatives], {f.name(): f.n_in() for f in derivatives},
                                     {f.name(): f.n_out() for f in derivatives})
    return code + _kinds_table(functions, code_ranges, n_kinds, covers, lane_functions), p_index, layout


def _generated(functions: list[ca.Function]) -> str:
    generator = ca.CodeGenerator("wbmpc_stages.c", {"with_header": False})
    for function in functions:
        generator.add(function)
    return generator.dump()


def compile_flags(config: CodegenConfig, source_mb: float) -> tuple[CodegenConfig, tuple[str, ...]]:
    """The settings a stage library of this size compiles with: CodegenConfig's flags (-O1), -O2 up to
    `stage_o2_max_source_mb` (none by default; b1_z1's 4.4 MB: 340 s against 48 s at -O1 for 3.7 % per Fatrop
    iteration, see CodegenConfig), larger sources following `codegen.for_source` (TALOS-sized at -O0)."""
    config = for_source(replace(config, large_source_mb=config.stage_large_source_mb), source_mb)
    optimize = source_mb <= config.stage_o2_max_source_mb
    return config, tuple("-O2" if flag == "-O1" and optimize else flag for flag in config.flags)


def build(problem: OcpProblem, config: CodegenConfig = CodegenConfig()) -> "StageLibrary":
    """Generate, compile (unless cached) and load the stage library of `problem`."""
    start = time.perf_counter()
    code, p_index, layout = generate_source(problem, config.dynamics_hessian)
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
        report = CompileReport(library, cached=True, source_mb=source_mb, generate_s=generate_s)
        return StageLibrary(report, problem, p_index, layout)
    source = cache / f"{library.stem}.{os.getpid()}.c"  # per process: parallel builds of one key never share a file
    source.write_text(code)
    try:
        compile_s, peak_mb = _compile(source, library, replace(config, flags=(*flags, f"-I{source_dir()}")))
    finally:
        source.unlink(missing_ok=True)
    report = CompileReport(library, cached=False, source_mb=source_mb, compile_s=compile_s, peak_memory_mb=peak_mb,
                           generate_s=generate_s)
    return StageLibrary(report, problem, p_index, layout)


class StageLibrary:
    """A compiled stage library loaded with ctypes and the problem's stage layout: `kinds` is the library's
    `wb_kinds*`, `layout` the stages' table (LAYOUT_ROWS x (N+1) int32) and `sizes` (stages, parameters per
    stage, variables, constraints), what the shim's `wb_ctx_new` takes."""

    def __init__(self, report: CompileReport, problem: OcpProblem, p_index: np.ndarray, layout: np.ndarray):
        self.report, self.p_index = report, p_index
        self.layout = np.ascontiguousarray(layout, dtype=np.int32)
        self.sizes = (problem.N + 1, p_index.shape[1], problem.n_variables, problem.n_constraints)
        self.lib = ctypes.CDLL(str(report.library))
        self.lib.wbmpc_stage_kinds.restype = ctypes.c_void_p
        self.kinds = ctypes.c_void_p(self.lib.wbmpc_stage_kinds())
