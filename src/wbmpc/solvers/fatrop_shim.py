"""The C shim between Fatrop's OCP C interface and a problem's compiled stage functions (`stage_library.py`).

Fatrop (the casadi wheel ships `libfatrop` and its headers, `casadi/include/fatrop/ocp/OCPCInterface.h`) asks an
OCP for per-stage blocks. casadi's nlpsol plugin answers from whole-NLP functions (`nlp_jac_g`, `nlp_hess_l`)
and copies each block out of the sparse results; the shim (`csrc/fatrop_callbacks.c`) answers Fatrop's
whole-horizon callbacks by evaluating every stage's generated function and packing its block, the stages spread
over a small thread pool (`csrc/stage_pool.c`, `csrc/stage_tasks.c`): the 15 stages' functions are independent,
and each task writes only its stage's outputs, so any thread count gives the same blocks bit for bit.

The row split follows casadi's plugin, so both paths solve the same problem the same way: a row or variable with
lb == ub is an equality, one with a finite bound an inequality (with a slack), one with both bounds infinite is
left out; in each stage the constraint rows come first, then the variables, each in NLP order. One difference
(`csrc/stage_layout.c`): inputs with lb == ub (swing feet's zero forces, the arm's commanded force) are eliminated
instead of being equality rows, so Fatrop's per-stage elimination and Riccati recursion work on fewer inputs and
rows (the same iterates up to rounding; their multipliers follow from the Lagrangian's stationarity). Fatrop's
dynamics multipliers are those of f(x_k, u_k) - x_{k+1} = 0, the negative of casadi's (our gap rows are x_{k+1} - f).

Fatrop itself is driven by a small C++ driver (`csrc/fatrop_driver.cpp`) built from the same exported pieces as
Fatrop's own `fatrop_ocp_c_create`, adding a primal-dual warm start and a time limit, and faster kernels for its
equality elimination (`csrc/fatrop_kernels.cpp`, see `fatrop_kernels.py`).

`ShimLibrary` loads the shim with ctypes beside a problem's stage library; the solve's call (`wb_solve`) checks its
inputs itself (finite p and initial guess, bounds in order), gathers the stages' parameters from the NLP's p, and
unpacks the solution into the caller's preallocated outputs, so the Python around it is a few lines.

The shim does not depend on the problem: it is compiled once per machine from the shipped sources
(`native.build_native`, cached as `fatrop_shim_<key>.so`, the key hashing the sources, compiler, flags and the
directory of Fatrop's headers) and reads a problem only through its stage library's table. Until wbmpc 0.1 both
were one generated library per problem (`<formulation>_fatrop_direct_<key>.so`, a changed shim recompiled every
problem's stage functions); those cached files are no longer used.
"""

from __future__ import annotations

import ctypes
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca

from wbmpc.errors import WbmpcError
from wbmpc.solvers import blasfeo
from wbmpc.solvers.codegen import CodegenConfig, CompileReport
from wbmpc.solvers.native import build_native

if TYPE_CHECKING:
    from wbmpc.solvers.stage_library import StageLibrary

SOURCES = ("fatrop_shim.c", "fatrop_callbacks.c", "stage_layout.c", "stage_tasks.c", "stage_pool.c",
           "fatrop_driver.cpp", "fatrop_kernels.cpp", "fatrop_sparse.cpp")
HEADERS = ("fatrop_shim.h", "stage_pool.h", "wbmpc_stages.h")
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class FatropUnavailable(WbmpcError, RuntimeError):
    """Fatrop's C interface cannot be built here (no headers or library in the casadi wheel, no compiler)."""


def casadi_paths() -> tuple[Path, Path]:
    """(include directory with fatrop/ocp/OCPCInterface.h and blasfeo.h, directory of libfatrop)."""
    directory = Path(ca.__file__).parent
    include = directory / "include"
    header = include / "fatrop" / "ocp" / "OCPCInterface.h"
    if not header.exists() or not (include / "blasfeo.h").exists():
        raise FatropUnavailable(f"Fatrop's C headers are missing ({header}): this casadi build has no Fatrop "
                                "C interface; use the solver 'fatrop' (casadi's nlpsol)")
    if not list(directory.glob("libfatrop.so*")) or not list(directory.glob("libblasfeo.so*")):
        raise FatropUnavailable(f"libfatrop or libblasfeo is missing in {directory}; use the solver 'fatrop'")
    return include, directory


def build_shim(config: CodegenConfig = CodegenConfig()) -> CompileReport:
    """The compiled shim (built on first use) with the config's flags (-O1 as -O2: a few hundred lines compile in
    seconds; -march=native: the AVX2 kernels where the CPU has them), -fexceptions (a deadline unwinds through the
    C frames) and the pool's threads."""
    include, lib_dir = casadi_paths()
    flags = (*["-O2" if flag == "-O1" else flag for flag in config.flags], "-fexceptions", "-pthread", f"-I{include}")
    # libraries after the sources and not --as-needed: the shim must record libfatrop as a dependency
    link = ("-Wl,--no-as-needed", f"-L{lib_dir}", "-lfatrop", "-lblasfeo", "-lstdc++", "-lpthread",
            f"-Wl,-rpath,{lib_dir}")
    return build_native("fatrop_shim", SOURCES, config, flags, link, key_extra=str(include), headers=HEADERS)


class ShimLibrary:
    """The compiled shim and the problem's stage library, loaded with ctypes, shared by every solver on the problem."""

    def __init__(self, shim: CompileReport, stages: StageLibrary):
        self.report, self.shim_report, self.stages = stages.report, shim, stages
        self.p_index = stages.p_index
        blasfeo.activate()  # before libfatrop (and its BLASFEO) is loaded with the shim
        lib = ctypes.CDLL(str(shim.library))
        lib.wb_ctx_new.restype = ctypes.c_void_p
        lib.wb_ctx_new.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)] + [ctypes.c_int] * 5
        lib.wb_ctx_free.argtypes = [ctypes.c_void_p]
        lib.wb_ctx_threads.argtypes = [ctypes.c_void_p]
        lib.wb_sizes.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)]
        lib.wb_solver_new.restype = ctypes.c_void_p
        lib.wb_solver_new.argtypes = [ctypes.c_void_p] + [_DOUBLE_P] * 4 + [ctypes.c_int]
        lib.wb_solver_free.argtypes = [ctypes.c_void_p]
        lib.wb_solver_forget.argtypes = [ctypes.c_void_p]
        for name, kind in (("wb_option_double", ctypes.c_double), ("wb_option_int", ctypes.c_int),
                           ("wb_option_bool", ctypes.c_int)):
            getattr(lib, name).argtypes = [ctypes.c_void_p, ctypes.c_char_p, kind]
        lib.wb_eval_g.argtypes = [ctypes.c_void_p] + [_DOUBLE_P] * 3
        lib.wb_eval_derivatives.argtypes = [ctypes.c_void_p, _DOUBLE_P, _DOUBLE_P, ctypes.c_double, _DOUBLE_P, _DOUBLE_P]
        # (ctx, solver, p, lbx, ubx, lbg, ubg, x0, budget_s, warm, lam_g0, lam_x0, z_floor)
        lib.wb_solve.argtypes = [ctypes.c_void_p] * 2 + [_DOUBLE_P] * 6 + [ctypes.c_double, ctypes.c_int, _DOUBLE_P,
                                                                          _DOUBLE_P, ctypes.c_double]
        lib.wb_ctx_parameters.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        lib.wb_ctx_outputs.argtypes = [ctypes.c_void_p] * 6
        lib.wbd_fatrop_kernels.argtypes = [ctypes.c_int]
        lib.wbd_fatrop_kernels.restype = ctypes.c_int
        lib.wb_warm_up.argtypes = [ctypes.c_void_p]
        lib.wb_ctx_eliminate_fixed.argtypes = [ctypes.c_void_p, ctypes.c_int]
        self.lib = lib
        self.warmed_up: set[int] = set()  # thread counts whose first context ran wb_warm_up

    def context(self, threads: int) -> ctypes.c_void_p:
        """A new context (scratch and thread pool) evaluating on `threads` threads."""
        stages = self.stages
        layout = stages.layout.ctypes.data_as(ctypes.POINTER(ctypes.c_int))
        ctx = ctypes.c_void_p(self.lib.wb_ctx_new(stages.kinds, layout, *stages.sizes, int(threads)))
        if not ctx.value:
            raise RuntimeError("the Fatrop shim could not allocate its context (out of memory, or the stage library "
                               "was built for another shim: clear the cache directory)")
        return ctx

    def sizes(self, ctx) -> tuple[int, int, int, int]:
        sizes = (ctypes.c_int * 4)()
        self.lib.wb_sizes(ctx, sizes)
        return tuple(sizes)
