"""The structured QP of one SQP iteration (`solvers/qp.py`) on HPIPM's OCP QP interface directly.

casadi's `conic('hpipm')` boxes every variable and keeps every constraint row, infinite bounds replaced by
+-1e8 (dummy inequalities the interior point iterates on), passes equality rows as two inequalities and
allocates HPIPM's memory in each call. `DirectQp` fills HPIPM's stage blocks from the nonzeros of H and
J with index maps computed once, masks infinite bound sides out, declares rows and bounds with lb == ub
equalities, and keeps HPIPM's memory between calls (`csrc/hpipm_shim.c`, compiled once against the HPIPM
and BLASFEO that ship in the casadi wheel, cached beside the generated code). Inputs with lb == ub (swing feet's
forces, the arm's commanded force) and x_0 (fixed by the initial-state rows) are left out of HPIPM's QP
(`csrc/hpipm_reduce.c`, `QpConfig.eliminate_fixed`): the same QP on smaller Riccati blocks, their multipliers
recovered from the stage's stationarity; HPIPM instances are kept per pattern of reduced sizes. Where no inequality is
active (b1_z1's trot: every QP), one Riccati factorisation solves the QP: the inequalities dropped, the equality rows
eliminated (`csrc/hpipm_eqelim.c`, `QpConfig.active_set_guess`), the dropped rows checked, the interior point where one
is violated (docs/design/rti.md). Same QP, same solution
as `StructuredQp` (tests/solvers/test_hpipm_direct.py); `solve` has its interface. Declaring the equalities (idxe) changed
neither the iterations nor the solutions on 60 post-push b1_z1 QPs: off by default (no rebuilds at contact switches).
In HPIPM's absolute mode (speed_abs) the equality multipliers are computed on exit (comp_dual_sol_eq): the SQP's
merit penalty and dual residual need them, and casadi's conic cannot ask for them.

Measured on b1_z1 (60 QPs after a 0.8 m/s push, speed_abs): the same iterations as casadi's conic (11.8 / 10.9
with mu0 100) at ~0.45 ms each (HPIPM's Riccati recursion: the floor of this QP's size), ~0.3 ms less overhead per
QP; with mu0 1e3 (RtiConfig.qp_barrier_init) 11.1. The larger gain is upstream: H, J and the gradient reach it as
NumPy nonzeros of buffered calls, no DMs (RtiSolver).

Stage k of HPIPM holds (u_k, x_k); our variables are (x_0, u_0, x_1, ...) and our rows per stage the gap
rows I x_{k+1} + A_k x_k + B_k u_k = rhs (HPIPM: x_{k+1} = -(A_k x_k + B_k u_k - rhs) / I) then the path
rows; HPIPM's dynamics multipliers pi_k are those of its form, casadi's of the gap rows are -pi_k / I.
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np

from wbmpc.errors import WbmpcError
from wbmpc.ocp.problem import OcpProblem
from wbmpc.solvers import blasfeo
from wbmpc.solvers.codegen import CodegenConfig, CompileError
from wbmpc.solvers.native import build_native
from wbmpc.solvers.qp import HPIPM_MODES, HPIPM_STATUS, QpConfig, QpResult, StructuredQp, stage_dimensions

HPIPM_BINDINGS = ("direct", "casadi")  # RtiConfig.hpipm_binding


class HpipmUnavailable(WbmpcError, RuntimeError):
    """HPIPM's C interface cannot be built here (no headers or library in the casadi wheel, no compiler)."""


def shim_library(config: CodegenConfig = CodegenConfig()) -> Path:
    """The compiled shim (`csrc/hpipm_shim.c`, built on first use, cached under the hash of its source, flags and
    HPIPM's headers' directory)."""
    directory = Path(ca.__file__).parent
    include = directory / "include"
    if not (include / "hpipm_d_ocp_qp_ipm.h").exists() or not list(directory.glob("libhpipm.so*")):
        raise HpipmUnavailable(f"HPIPM's headers or libhpipm are missing in {directory}: use casadi's hpipm conic")
    blasfeo.activate()  # before libhpipm (and its BLASFEO) is loaded
    flags = (*config.flags, "-O2", f"-I{include}")
    link = (f"-L{directory}", "-Wl,--no-as-needed", "-lhpipm", "-lblasfeo", f"-Wl,-rpath,{directory}")
    try:
        return build_native("hpipm_shim", ("hpipm_shim.c", "hpipm_reduce.c", "hpipm_load.c", "hpipm_eqelim.c"), config, flags, link, key_extra=str(include),
                            headers=("hpipm_shim.h",)).library
    except CompileError as exc:
        raise HpipmUnavailable(f"the HPIPM shim did not compile: {exc}") from exc


_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class DirectQp:
    """HPIPM on the stage blocks of (H, J) of an OCP, index maps built once; `solve` as `StructuredQp.solve`."""

    def __init__(self, problem: OcpProblem, hessian: ca.Sparsity, jacobian: ca.Sparsity, config: QpConfig = QpConfig(),
                 declare_equalities: bool = False, codegen: CodegenConfig = CodegenConfig()):
        self.config = config
        self.hessian_sparsity, self.jacobian_sparsity = hessian, jacobian
        self._lib = ctypes.CDLL(str(shim_library(codegen)))
        self._lib.wbqp_new.restype = ctypes.c_void_p
        self._lib.wbqp_new.argtypes = [ctypes.c_int, *[ctypes.POINTER(ctypes.c_int)] * 3, ctypes.c_int, ctypes.c_int,
                                       ctypes.c_double, ctypes.c_double, ctypes.c_int, ctypes.c_double, ctypes.c_int,
                                       ctypes.c_int, ctypes.c_int, *[ctypes.POINTER(ctypes.c_int)] * 2]
        self._lib.wbqp_solve.restype = ctypes.c_int
        self._lib.wbqp_solve.argtypes = [ctypes.c_void_p] + [_DOUBLE_P] * 22
        self._lib.wbqp_iterations.restype = ctypes.c_int
        self._lib.wbqp_iterations.argtypes = [ctypes.c_void_p]
        self._lib.wbqp_free.argtypes = [ctypes.c_void_p]
        self._lib.wbqp_rebuilds.restype = ctypes.c_int
        self._lib.wbqp_rebuilds.argtypes = [ctypes.c_void_p]
        self._lib.wbqp_sizes.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)]
        self._lib.wbqp_nlp_new.restype = ctypes.c_void_p
        self._lib.wbqp_nlp_new.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p, ctypes.c_void_p]
        self._lib.wbqp_nlp_solve.restype = ctypes.c_int
        self._lib.wbqp_nlp_solve.argtypes = [ctypes.c_void_p] * 12
        self._lib.wbqp_nlp_free.argtypes = [ctypes.c_void_p]
        self._lib.wbqp_set_guess.restype = ctypes.c_int
        self._lib.wbqp_set_guess.argtypes = [ctypes.c_void_p, ctypes.c_int]
        self._lib.wbqp_guess_stats.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int)]
        dims = stage_dimensions(problem)
        N, nx, nu, ng = dims["N"], dims["nx"], dims["nu"], dims["ng"]
        self.N = N
        self._maps(problem, nx, nu, ng, hessian, jacobian)
        ints = [(ctypes.c_int * (N + 1))(*values) for values in (nx, nu, ng)]
        x0_rows, x0_cols = self._x0_rows
        self._handle = self._lib.wbqp_new(N, *ints, HPIPM_MODES.index(config.mode), config.max_iterations,
                                          config.barrier_init, config.tolerance, int(config.warm_start),
                                          config.infinity, int(declare_equalities), int(config.eliminate_fixed),
                                          len(x0_rows), (ctypes.c_int * max(len(x0_rows), 1))(*x0_rows),
                                          (ctypes.c_int * max(len(x0_cols), 1))(*x0_cols))
        if not self._handle:
            raise MemoryError("HPIPM's shim could not allocate its QP")
        if config.active_set_guess and not self._lib.wbqp_set_guess(self._handle, 1):
            raise MemoryError("HPIPM's shim could not allocate the active-set guess")

    def __del__(self):
        handle = getattr(self, "_handle", None)
        if handle:
            self._lib.wbqp_free(handle)
            self._handle = None
        if getattr(self, "_nlp_handle", None):
            self._lib.wbqp_nlp_free(self._nlp_handle)
            self._nlp_handle = None

    def _maps(self, problem, nx, nu, ng, hessian: ca.Sparsity, jacobian: ca.Sparsity) -> None:
        """Where each nonzero of J and H, each variable and each row goes in HPIPM's stage-major blocks."""
        N = self.N
        cols = self._column_layout(problem.n_variables, nx, nu)
        rows = self._row_layout(problem.n_constraints, nx, ng)

        def offsets(sizes):
            return np.concatenate([[0], np.cumsum(sizes)]).astype(int)

        size = {"A": [nx[k + 1] * nx[k] for k in range(N)], "B": [nx[k + 1] * nu[k] for k in range(N)],
                "Q": [nx[k] ** 2 for k in range(N + 1)], "S": [nu[k] * nx[k] for k in range(N + 1)],
                "R": [nu[k] ** 2 for k in range(N + 1)], "C": [ng[k] * nx[k] for k in range(N + 1)],
                "D": [ng[k] * nu[k] for k in range(N + 1)]}
        off = {name: offsets(sizes) for name, sizes in size.items()}
        self._jacobian_maps(jacobian, cols, rows, off, nx, nu, ng)
        self._initial_state_rows(problem, jacobian, cols, rows)
        self._hessian_maps(hessian, cols, off, nx, nu)
        self._allocate(off, problem.n_variables, problem.n_constraints)

    @property
    def rebuilds(self) -> int:
        """HPIPM instances built so far: one per pattern of QP sizes (fixed inputs left out) not in the shim's cache."""
        return int(self._lib.wbqp_rebuilds(self._handle))

    @property
    def guess_stats(self) -> dict[str, int]:
        """The active-set guess (`QpConfig.active_set_guess`): QPs it was tried on, QPs it solved, and the last call's
        outcome (-1 not tried, 0 solved, 1 an inequality active, 2 rows it does not handle, 3 numerical failure)."""
        out = (ctypes.c_int * 3)()
        self._lib.wbqp_guess_stats(self._handle, out)
        return {"tries": out[0], "hits": out[1], "last": out[2]}

    @property
    def solved_sizes(self) -> dict[str, list[int]]:
        """nx, nu, ng per stage of the last QP as HPIPM solved it (fixed inputs and x_0 left out); zeros before."""
        sizes = (ctypes.c_int * (3 * (self.N + 1)))()
        self._lib.wbqp_sizes(self._handle, sizes)
        values = list(sizes)
        return {name: values[i * (self.N + 1):(i + 1) * (self.N + 1)] for i, name in enumerate(("nx", "nu", "ng"))}

    def _initial_state_rows(self, problem, jacobian: ca.Sparsity, cols, rows_layout) -> None:
        """Stage 0's initial-state rows (`problem.rows["x0"]`) as (row among stage 0's rows, state component) where each
        has one Jacobian nonzero, on x_0 (the shim then leaves x_0 out of HPIPM's QP); none otherwise."""
        self._x0_rows: tuple[list[int], list[int]] = ([], [])
        rows = np.asarray(problem.rows.get("x0", np.zeros(0)), dtype=int).ravel()
        row_stage, row_kind, row_local = rows_layout
        col_stage, col_part, col_local = cols
        nz_rows, nz_cols = (np.asarray(v) for v in jacobian.get_triplet())
        in_rows = np.isin(nz_rows, rows)
        if rows.size == 0 or np.any((row_stage[rows] != 0) | (row_kind[rows] != 1)) or \
                np.count_nonzero(in_rows) != rows.size or np.unique(nz_rows[in_rows]).size != rows.size:
            return
        on_x0 = (col_stage[nz_cols[in_rows]] == 0) & (col_part[nz_cols[in_rows]] == 0)
        if on_x0.all():
            self._x0_rows = ([int(v) for v in row_local[nz_rows[in_rows]]],
                             [int(v) for v in col_local[nz_cols[in_rows]]])

    def _column_layout(self, n_var: int, nx, nu) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per NLP variable: its stage, part (0: x, 1: u) and position in the part; x_index, u_index."""
        col_stage, col_part, col_local = (np.full(n_var, -1) for _ in range(3))
        x_index, u_index, c = [], [], 0
        for k in range(self.N + 1):
            col_stage[c : c + nx[k] + nu[k]] = k
            col_part[c : c + nx[k]], col_part[c + nx[k] : c + nx[k] + nu[k]] = 0, 1
            col_local[c : c + nx[k]] = np.arange(nx[k])
            col_local[c + nx[k] : c + nx[k] + nu[k]] = np.arange(nu[k])
            x_index.append(np.arange(c, c + nx[k]))
            u_index.append(np.arange(c + nx[k], c + nx[k] + nu[k]))
            c += nx[k] + nu[k]
        if c != n_var:
            raise WbmpcError(f"HPIPM stage sizes cover {c} of {n_var} variables")
        self.x_index, self.u_index = np.concatenate(x_index), np.concatenate(u_index)
        return col_stage, col_part, col_local

    def _row_layout(self, n_row: int, nx, ng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per NLP row: its stage, kind (0: gap, 1: path) and position; gap_index, path_index."""
        N = self.N
        row_stage, row_kind, row_local = (np.full(n_row, -1) for _ in range(3))
        gap_index, path_index, r = [], [], 0
        for k in range(N + 1):
            if k < N:
                row_stage[r : r + nx[k + 1]], row_kind[r : r + nx[k + 1]] = k, 0
                row_local[r : r + nx[k + 1]] = np.arange(nx[k + 1])
                gap_index.append(np.arange(r, r + nx[k + 1]))
                r += nx[k + 1]
            row_stage[r : r + ng[k]], row_kind[r : r + ng[k]], row_local[r : r + ng[k]] = k, 1, np.arange(ng[k])
            path_index.append(np.arange(r, r + ng[k]))
            r += ng[k]
        self.gap_index, self.path_index = np.concatenate(gap_index), np.concatenate(path_index)
        return row_stage, row_kind, row_local

    def _jacobian_maps(self, jacobian: ca.Sparsity, cols, rows_layout, off, nx, nu, ng) -> None:
        """J's nonzeros (CasADi's column-major order) into A, B, C, D; the gap rows' identity; the A/B scales."""
        N = self.N
        col_stage, col_part, col_local = cols
        row_stage, row_kind, row_local = rows_layout
        nx_arr, ng_arr = np.asarray(nx), np.asarray(ng)
        rows = np.asarray(jacobian.row())
        columns = np.repeat(np.arange(jacobian.size2()), np.diff(np.asarray(jacobian.colind())))
        ks, kind, lr = row_stage[rows], row_kind[rows], row_local[rows]
        cs, part, lc = col_stage[columns], col_part[columns], col_local[columns]
        self._j_maps = {}
        for name, mask, dest in (
                ("A", (kind == 0) & (cs == ks) & (part == 0), lambda: off["A"][ks] + lc * nx_arr[np.minimum(ks + 1, N)] + lr),
                ("B", (kind == 0) & (cs == ks) & (part == 1), lambda: off["B"][ks] + lc * nx_arr[np.minimum(ks + 1, N)] + lr),
                ("C", (kind == 1) & (cs == ks) & (part == 0), lambda: off["C"][ks] + lc * ng_arr[ks] + lr),
                ("D", (kind == 1) & (cs == ks) & (part == 1), lambda: off["D"][ks] + lc * ng_arr[ks] + lr)):
            where = np.nonzero(mask)[0]
            self._j_maps[name] = (where, dest()[where])
        eye = (kind == 0) & (cs == ks + 1) & (part == 0)
        if np.any(eye & (lc != lr)):
            raise WbmpcError("the gap rows' x_{k+1} block is not diagonal: HPIPM needs x_{k+1} = A x_k + B u_k + b")
        covered = sum(len(w) for w, _ in self._j_maps.values()) + int(eye.sum())
        if covered != len(rows):
            raise WbmpcError(f"{len(rows) - covered} Jacobian nonzeros fall outside HPIPM's stage blocks")
        self._eye = (np.nonzero(eye)[0], ks[eye] * 0 + self._gap_position(rows[eye]))
        # the scale of each A / B entry: -1 / I of its row
        self._ab_scale_rows = {"A": self._gap_position_of(off, "A", nx, N)[self._j_maps["A"][1]],
                               "B": self._gap_position_of(off, "B", nx, N, nu)[self._j_maps["B"][1]]}

    def _hessian_maps(self, hessian: ca.Sparsity, cols, off, nx, nu) -> None:
        """H's nonzeros into Q, S, R; both triangles written (a symmetric H stored whole writes each entry twice, the
        same value)."""
        col_stage, col_part, col_local = cols
        nx_arr, nu_arr = np.asarray(nx), np.asarray(nu)
        hrows = np.asarray(hessian.row())
        hcols = np.repeat(np.arange(hessian.size2()), np.diff(np.asarray(hessian.colind())))
        self._h_maps = []
        for r_, c_ in ((hrows, hcols), (hcols, hrows)):
            ks_r, ks_c = col_stage[r_], col_stage[c_]
            if np.any(ks_r != ks_c):
                raise WbmpcError("the QP Hessian couples stages: HPIPM needs a block-diagonal H")
            pr, pc, lr_, lc_ = col_part[r_], col_part[c_], col_local[r_], col_local[c_]
            for name, mask, dest in (("Q", (pr == 0) & (pc == 0), off["Q"][ks_r] + lc_ * nx_arr[ks_r] + lr_),
                                     ("S", (pr == 1) & (pc == 0), off["S"][ks_r] + lc_ * nu_arr[ks_r] + lr_),
                                     ("R", (pr == 1) & (pc == 1), off["R"][ks_r] + lc_ * nu_arr[ks_r] + lr_)):
                where = np.nonzero(mask)[0]
                self._h_maps.append((name, where, dest[where]))

    def _allocate(self, off, n_var: int, n_row: int) -> None:
        """The blocks (one store, A first), vectors and results HPIPM reads and writes; the index maps of
        `csrc/hpipm_load.c` (J's and H's nonzeros into the store, the NLP's order into the stages' and back)."""
        n_gap, n_u, n_x, n_path = len(self.gap_index), len(self.u_index), len(self.x_index), len(self.path_index)
        base = dict(zip(off, np.concatenate([[0], np.cumsum([int(off[name][-1]) for name in off])])))
        self._store = np.zeros(sum(int(off[name][-1]) for name in off))
        self._blocks = {name: self._store[base[name]:base[name] + int(off[name][-1])] for name in off}
        vectors = [np.zeros(n) for n in (n_gap, n_x, n_u, n_u, n_u, n_x, n_x, n_path, n_path, n_u, n_x, n_gap, n_u, n_x,
                                         n_path, n_gap)]
        self._b, self._q, self._r, *self._bounds = vectors[:9]
        self._u, self._x, self._pi, self._lam_u, self._lam_x, self._lam_g, self._scale = vectors[9:]
        names = ("A", "B", "C", "D")
        eye_where, eye_position = self._eye
        eye_src = np.full(n_gap, -1)
        eye_src[eye_position] = eye_where
        i32 = [np.ascontiguousarray(v, dtype=np.int32) for v in (
            np.concatenate([self._j_maps[n][0] for n in names]),
            np.concatenate([base[n] + self._j_maps[n][1] for n in names]),
            np.concatenate([self._ab_scale_rows.get(n, np.full(len(self._j_maps[n][0]), -1)) for n in names]),
            np.concatenate([where for _, where, _ in self._h_maps]),
            np.concatenate([base[name] + dest for name, _, dest in self._h_maps]),
            eye_src, self.gap_index, self.x_index, self.u_index, self.path_index)]
        counts = (ctypes.c_int * 6)(len(i32[0]), len(i32[3]), n_gap, n_x, n_u, n_path)
        buffers = [self._blocks[n] for n in ("A", "B", "Q", "S", "R", "C", "D")] + vectors
        self._map_arrays = i32, buffers  # alive while the shim's handle points at them
        self._nlp_handle = self._lib.wbqp_nlp_new(counts, (ctypes.c_void_p * len(i32))(*[a.ctypes.data for a in i32]),
                                                  (ctypes.c_void_p * len(buffers))(*[a.ctypes.data for a in buffers]))
        self._n_var, self._n_row = n_var, n_row
        self._sizes = (self.hessian_sparsity.nnz(), n_var, self.jacobian_sparsity.nnz(), n_row, n_row, n_var, n_var)

    def _gap_position(self, rows: np.ndarray) -> np.ndarray:
        """Position of gap rows (NLP row numbers) among all gap rows."""
        return np.searchsorted(self.gap_index, rows)

    def _gap_position_of(self, off, name, nx, N, nu=None) -> np.ndarray:
        """For each entry of the flat A (or B) blocks, the position of its row among the gap rows."""
        positions, start = [], 0
        for k in range(N):
            cols = nx[k] if nu is None else nu[k]
            positions.append(np.tile(np.arange(nx[k + 1]), cols) + start)
            start += nx[k + 1]
        return np.concatenate(positions) if positions else np.zeros(0, dtype=int)

    def solve(self, H, gradient, J, lbg, ubg, lbx, ubx) -> QpResult:
        """Bounds are on the step (already shifted by the linearisation point's g and x). H, J: DMs of the
        sparsities given at construction, or their nonzeros."""
        start = time.perf_counter()
        h = np.asarray(H.nonzeros() if isinstance(H, ca.DM) else H, dtype=float)
        j = np.asarray(J.nonzeros() if isinstance(J, ca.DM) else J, dtype=float)
        g = np.asarray(gradient, dtype=float).ravel() if not isinstance(gradient, ca.DM) else \
            np.asarray(gradient.full()).ravel()
        h, g, j, lbg, ubg, lbx, ubx = (np.ascontiguousarray(v, dtype=float).ravel() for v in (h, g, j, lbg, ubg, lbx, ubx))
        sizes = (h.size, g.size, j.size, lbg.size, ubg.size, lbx.size, ubx.size)
        if sizes != self._sizes:  # the shim reads them by index
            raise ValueError(f"QP data of sizes {sizes} (H, gradient, J nonzeros, lbg, ubg, lbx, ubx), expected {self._sizes}")
        step, lam_x, lam_g = np.empty(self._n_var), np.empty(self._n_var), np.empty(self._n_row)
        addresses = [a.ctypes.data for a in (h, g, j, lbg, ubg, lbx, ubx, step, lam_g, lam_x)]
        tic = time.perf_counter()
        flag = self._lib.wbqp_nlp_solve(self._handle, self._nlp_handle, *addresses)
        hpipm_s = time.perf_counter() - tic  # (the shim's C loads the QP, solves and unpacks it)
        if flag == -10:
            raise WbmpcError("HPIPM's dynamics rows must be equalities (lbg == ubg on the gap rows)")
        success = flag == 0 and bool(np.all(np.isfinite(step)))
        return QpResult(step=step, lam_g=lam_g, lam_x=lam_x, status=HPIPM_STATUS.get(flag, f"hpipm_flag_{flag}"),
                        success=success, iterations=int(self._lib.wbqp_iterations(self._handle)),
                        solve_time_s=time.perf_counter() - start, pack_s=time.perf_counter() - start - hpipm_s)


def conic_config(config: QpConfig) -> QpConfig:
    """The settings for casadi's hpipm conic: it returns no equality multipliers in HPIPM's absolute mode
    (speed_abs), which the SQP's merit function and dual residual need, so it runs "speed" there."""
    return replace(config, mode="speed") if config.mode == "speed_abs" else config


def make_qp(problem: OcpProblem, hessian: ca.Sparsity, jacobian: ca.Sparsity, config: QpConfig,
            codegen: CodegenConfig = CodegenConfig()):
    """(QP on HPIPM directly, None), or (casadi's conic, why not) where the binding cannot be built here (no HPIPM
    headers or library in the casadi wheel, no compiler, a problem whose blocks are not HPIPM's stage form)."""
    try:
        return DirectQp(problem, hessian, jacobian, config, codegen=codegen), None
    except (WbmpcError, OSError) as exc:
        return StructuredQp(problem, hessian, jacobian, conic_config(config)), f"{type(exc).__name__}: {exc}"
