"""C shim between Fatrop's OCP C interface and our per-stage CasADi functions, generated and compiled once.

Fatrop (the casadi wheel ships `libfatrop` and its headers, `casadi/include/fatrop/ocp/OCPCInterface.h`)
asks an OCP for per-stage blocks: the transposed dynamics Jacobian BAbt, the Lagrangian Hessian
RSQrqt, the equality and inequality Jacobians Ggt / Ggt_ineq, constraint values, cost gradients and
bounds. casadi's nlpsol plugin answers from whole-NLP functions (`nlp_jac_g`, `nlp_hess_l`) and
copies each block out of the sparse results; here each stage kind's blocks are generated directly in
Fatrop's (u_k, x_k) order and dense, so every callback is one generated call and one BLASFEO pack.

The row split follows casadi's plugin, so both paths solve the same problem the same way: a row or
variable with lb == ub is an equality, one with a finite bound an inequality (with a slack), one with
both bounds infinite is left out; in each stage the constraint rows come first, then the variables,
each in NLP order. Fatrop's dynamics multipliers are those of f(x_k, u_k) - x_{k+1} = 0, the negative
of casadi's (our gap rows are x_{k+1} - f). Stage parameters are rows of a (N+1, n_p) array.

Fatrop itself is driven by a small C++ driver (`DRIVER_SOURCE`) built from the same exported pieces as
Fatrop's own `fatrop_ocp_c_create`, which adds a primal-dual warm start and a time limit (see there), and
carries faster kernels for Fatrop's equality elimination (`fatrop_kernels.py`).

The library (generated C of the stage functions, the shim and the driver) lands in the cache directory of
`codegen.py` under the hash of its sources, compiler, flags and the Fatrop headers' directory.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np

from wbmpc.errors import WbmpcError
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
from wbmpc.solvers.fatrop_kernels import KERNELS_SOURCE


class FatropUnavailable(WbmpcError, RuntimeError):
    """Fatrop's C interface cannot be built here (no headers or library in the casadi wheel, no compiler)."""


FUNCTION_KINDS = ("hess", "jac", "val", "grad", "cost")
O2_MAX_SOURCE_MB = 10.0  # generated C up to this size compiles at -O2 instead of CodegenConfig's -O1 (see build)


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


def _c_array(name: str, values, ctype: str = "int") -> str:
    return f"static const {ctype} {name}[] = {{{', '.join(str(int(v)) for v in values)}}};\n"


def generate_source(problem: OcpProblem) -> tuple[str, np.ndarray]:
    """The C source of the shim for `problem` and the (N+1, n_p) index map of the stage parameters into p."""
    N, nx = problem.N, problem.nx
    kinds: dict[str, int] = {}
    functions: list[ca.Function] = []
    stage_kind, n_x, n_u, n_rows, x_offsets, row_offsets, gap_offsets = [], [], [], [], [], [], []
    for k in range(N + 1):
        function, _ = problem.stage_function(k)
        if function.name() not in kinds:
            kinds[function.name()] = len(kinds)
            functions += stage_kind_functions(function, f"wbk{kinds[function.name()]}")
        state, inputs = problem.stage_slices[k]
        stage_kind.append(kinds[function.name()])
        n_x.append(nx)
        n_u.append(inputs.stop - inputs.start)
        n_rows.append(function.size1_out(1))
        x_offsets.append(state.start)
        gap = int(problem.stage_row_starts[k])
        gap_offsets.append(gap if k < N else -1)
        row_offsets.append(gap + (nx if k < N else 0))
    n_p = functions[0].size1_in(2)
    p_index = np.array([np.asarray(ca.evalf(problem.stage_parameters(ca.DM(np.arange(problem.params.size)), k)))
                        .ravel() for k in range(N + 1)]).round().astype(np.int64)
    assert p_index.shape == (N + 1, n_p)

    generator = ca.CodeGenerator("wbmpc_fatrop_direct.c", {"with_header": False})
    for function in functions:
        generator.add(function)
    code = generator.dump()
    sizes = np.array([[f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()] for f in functions]).max(axis=0)
    n_kinds = len(kinds)
    tables = "".join([
        f"#define WB_K {N + 1}\n#define WB_NP {n_p}\n#define WB_NV {problem.n_variables}\n"
        f"#define WB_NG {problem.n_constraints}\n#define WB_NKIND {n_kinds}\n",
        f"#define WB_SZ_ARG {sizes[0]}\n#define WB_SZ_RES {sizes[1]}\n#define WB_SZ_IW {sizes[2] + 1}\n"
        f"#define WB_SZ_W {sizes[3] + 1}\n",
        f"#define WB_MAXN {max(a + b for a, b in zip(n_x, n_u))}\n#define WB_MAXR {max(max(n_rows), 1)}\n"
        f"#define WB_MAXX {max(n_x)}\n",
        _c_array("wb_kind", stage_kind), _c_array("wb_nx", n_x), _c_array("wb_nu", n_u), _c_array("wb_nr", n_rows),
        _c_array("wb_xo", x_offsets), _c_array("wb_ro", row_offsets), _c_array("wb_go", gap_offsets),
        *[f"static const wb_fn wb_{kind}[] = {{{', '.join(f'wbk{i}_{kind}' for i in range(n_kinds))}}};\n"
          for kind in FUNCTION_KINDS],
    ])
    return code + SHIM_PRELUDE + tables + SHIM_BODY, p_index


def build(problem: OcpProblem, config: CodegenConfig = CodegenConfig()) -> tuple[CompileReport, np.ndarray]:
    """Generate, compile (unless cached) and return the shim library and the stage parameter map."""
    include, lib_dir = casadi_paths()
    start = time.perf_counter()
    code, p_index = generate_source(problem)
    generate_s = time.perf_counter() - start
    config = for_source(config, len(code) / 1e6)  # TALOS-sized sources at -O0 (CodegenConfig.large_source_mb)
    # libraries after the source and not --as-needed: the shim must record libfatrop as a dependency
    cache = Path(config.cache_dir or default_cache_dir())
    # CodegenConfig's default -O1 (chosen for the whole-NLP library's compile time) becomes -O2 for shims up to
    # O2_MAX_SOURCE_MB: b1_z1's stage functions evaluate 2.63 -> 1.60 ms per closed-loop step (0.89x the step's
    # CPU) for one longer, cached compile (7.6 MB of C, load ~4: 80 s and 0.86 GB at -O1, 254 s and 0.96 GB at
    # -O2); larger robots' shims and other levels are compiled as given
    optimize = len(code) <= O2_MAX_SOURCE_MB * 1e6
    flags = tuple("-O2" if flag == "-O1" and optimize else flag for flag in config.flags)
    stem_flags = (*flags, "-fexceptions", f"-I{include}", "-Wl,--no-as-needed", f"-L{lib_dir}", "-lfatrop",
                  "-lblasfeo", "-lstdc++", f"-Wl,-rpath,{lib_dir}")
    driver = DRIVER_SOURCE + KERNELS_SOURCE
    key = cache_key(code + driver, replace(config, flags=stem_flags))
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CompileError(f"cannot create the cache directory {cache}: {exc.strerror}; set WBMPC_CACHE_DIR") from exc
    stem = f"{problem.config.formulation}_fatrop_direct_{key}"
    library = cache / f"{stem}.so"
    source_mb = len(code) / 1e6
    if library.exists():
        return CompileReport(library, cached=True, source_mb=source_mb, generate_s=generate_s), p_index
    # per process: parallel builds of one key (campaign workers, test workers) never share a file
    source, helper = cache / f"{stem}.{os.getpid()}.c", cache / f"{stem}.{os.getpid()}_throw.cpp"
    source.write_text(code)
    helper.write_text(driver)
    try:  # the C++ helper rides along as one more input file of the same compiler call
        compile_s, peak_mb = _compile(source, library, replace(config, flags=(str(helper), *stem_flags)))
    finally:
        source.unlink(missing_ok=True)
        helper.unlink(missing_ok=True)
    return CompileReport(library, cached=False, source_mb=source_mb, compile_s=compile_s, peak_memory_mb=peak_mb,
                         generate_s=generate_s), p_index


SHIM_PRELUDE = r"""
/* ---- wbmpc: Fatrop OCP C interface shim ---- */
#include <blasfeo.h>
#include <fatrop/ocp/OCPCInterface.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include <time.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

typedef int (*wb_fn)(const casadi_real**, casadi_real**, casadi_int*, casadi_real*, int);
void wb_throw_deadline(void); /* C++ (DRIVER_SOURCE): throws std::runtime_error */
void* wbd_create(void* ocp);
void wbd_destroy(void* d);
int wbd_option_double(void* d, const char* name, double value);
int wbd_option_int(void* d, const char* name, int value);
int wbd_option_bool(void* d, const char* name, int value);
int wbd_solve(void* d, int warm);
const double* wbd_primal(void* d);
const double* wbd_dual(void* d);
const void* wbd_dims(void* d);
const void* wbd_stats(void* d);
"""

# The driver: what Fatrop's own C interface (fatrop_ocp_c_create / _solve) does, built from the same
# exported pieces (FatropOcpCMapping on our callbacks, IpAlgBuilder<OcpType>), plus two things its C
# interface lacks:
# - a primal-dual warm start: the builder's equality-multiplier initializer (a least-squares solve, one
#   KKT factorisation per solve) is replaced by one that, when asked, starts the slacks, bound and
#   equality multipliers from this instance's last converged solution (IpIterate's setters are defined
#   in the shipped ip_iterate.hpp) and else delegates; the builder keeps that initializer in a private
#   member, reached by the standard explicit-instantiation access rule;
# - a time limit: a callback past the deadline throws (wb_throw_deadline), the solve catches it and
#   returns -1 with the last accepted iterate in place (the C shim is built with -fexceptions so the
#   exception unwinds through its frames too).
DRIVER_SOURCE = r"""
#include <algorithm>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <fatrop/common/options.hpp>
#include <fatrop/common/printing.hpp>
#include <fatrop/ip_algorithm/ip_alg_builder.hpp>
#include <fatrop/ip_algorithm/ip_algorithm.hpp>
#include <fatrop/ocp/hessian.hpp>
#include <fatrop/ocp/jacobian.hpp>
#include <fatrop/ip_algorithm/ip_data.hpp>
#include <fatrop/ip_algorithm/ip_eq_mult_initializer.hpp>
#include <fatrop/ip_algorithm/ip_iterate.hpp>
#include <fatrop/ocp/OCPCInterfaceInternal.hpp>
#include <fatrop/ocp/problem_info.hpp>
#include <fatrop/ocp/type.hpp>

using namespace fatrop;

extern "C" void wb_throw_deadline(void) { throw std::runtime_error("wbmpc: deadline reached"); }

namespace {
template <typename Tag, typename Tag::type Member> struct Reach {
  friend typename Tag::type reach(Tag) { return Member; }
};
struct EqMultSlot {
  typedef std::shared_ptr<IpEqMultInitializerBase> IpAlgBuilder<OcpType>::*type;
  friend type reach(EqMultSlot);
};
template struct Reach<EqMultSlot, &IpAlgBuilder<OcpType>::eq_mult_initializer_>;

class WarmEqMult : public IpEqMultInitializerBase {
 public:
  WarmEqMult(const std::shared_ptr<IpData<OcpType>>& data, const std::shared_ptr<IpEqMultInitializer<OcpType>>& base)
      : data_(data), base_(base), duals_(data->current_iterate().dual_eq().m()),
        slacks_(data->current_iterate().primal_s().m()), z_l_(slacks_.m()), z_u_(slacks_.m()),
        s_(slacks_.m()), zl_(slacks_.m()), zu_(slacks_.m()) {}
  /* runs last in Fatrop's initializer: the warm start replaces its slacks, bound multipliers (z = 1) and
     equality multipliers (least squares) by the last converged solution's, slacks kept inside the bounds */
  void initialize_eq_mult(bool trial_it) override {
    if (!use_ || trial_it) { base_->initialize_eq_mult(trial_it); return; }
    IpIterate<OcpType>& it = data_->current_iterate();
    const Index m = slacks_.m();
    const double *lower = it.lower_bounds().data(), *upper = it.upper_bounds().data();
    for (Index i = 0; i < m; ++i) {
      const bool has_l = it.lower_bounded()[i], has_u = it.upper_bounded()[i];
      double value = slacks_(i);
      const double l_gap = has_l ? 1e-8 * std::max(1.0, std::abs(lower[i])) : 0.0;
      const double u_gap = has_u ? 1e-8 * std::max(1.0, std::abs(upper[i])) : 0.0;
      if (has_l && has_u && upper[i] - lower[i] <= l_gap + u_gap) value = 0.5 * (lower[i] + upper[i]);
      else {
        if (has_l) value = std::max(value, lower[i] + l_gap);
        if (has_u) value = std::min(value, upper[i] - u_gap);
      }
      s_(i) = value;
      zl_(i) = has_l ? (z_l_(i) > 0 ? z_l_(i) : 1.0) : 0.0;
      zu_(i) = has_u ? (z_u_(i) > 0 ? z_u_(i) : 1.0) : 0.0;
    }
    it.set_primal_s(s_);
    it.set_dual_bounds_l(zl_);
    it.set_dual_bounds_u(zu_);
    it.set_dual_eq(duals_);
  }
  void store(const IpIterate<OcpType>& it) {
    duals_ = it.dual_eq();
    slacks_ = it.primal_s();
    z_l_ = it.dual_bounds_l();
    z_u_ = it.dual_bounds_u();
    valid_ = true;
  }
  void register_options(OptionRegistry& registry) override { base_->register_options(registry); }
  void reset() override { base_->reset(); }
  std::shared_ptr<IpData<OcpType>> data_;
  std::shared_ptr<IpEqMultInitializer<OcpType>> base_;
  VecRealAllocated duals_, slacks_, z_l_, z_u_, s_, zl_, zu_;
  bool use_ = false, valid_ = false;
};

struct Driver {
  explicit Driver(FatropOcpCInterface* ocp) : m(std::make_shared<FatropOcpCMapping>(ocp)) {
    IpAlgBuilder<OcpType> builder(m);
    builder.with_options_registry(&options);
    builder.create_ipdata();
    builder.create_pdsolver();
    auto base = std::make_shared<IpEqMultInitializer<OcpType>>(builder.get_ipdata(), builder.get_pd_solver());
    warm = std::make_shared<WarmEqMult>(builder.get_ipdata(), base);
    options.register_options(*warm);
    builder.*reach(EqMultSlot()) = warm;
    Banner::set_suppress(true);
    algo = builder.build();
    data = builder.get_ipdata();
    const ProblemInfo<OcpType>& info = algo->info();
    FatropOcpCDims& s = m->s;
    s.nx = info.dims.number_of_states.data();
    s.nu = info.dims.number_of_controls.data();
    s.ng = info.dims.number_of_eq_constraints.data();
    s.ng_ineq = info.dims.number_of_ineq_constraints.data();
    s.K = info.dims.K;
    s.ux_offs = info.offsets_primal_u.data();
    s.g_offs = info.offsets_g_eq_path.data();
    s.dyn_offs = info.offsets_dyn.data();
    s.dyn_eq_offs = info.offsets_g_eq_dyn.data();
    s.g_ineq_offs = info.offsets_g_eq_slack.data();
    s.n_ineqs = info.number_of_g_eq_slack;
  }
  std::shared_ptr<FatropOcpCMapping> m;
  OptionRegistry options;
  std::shared_ptr<WarmEqMult> warm;
  std::shared_ptr<IpAlgorithm<OcpType>> algo;
  std::shared_ptr<IpData<OcpType>> data;
  IpSolverReturnFlag flag = IpSolverReturnFlag::Unknown;
  FatropOcpCStats stats{};
};
}  // namespace

extern "C" {
void* wbd_create(void* ocp) {
  try { return new Driver(static_cast<FatropOcpCInterface*>(ocp)); } catch (const std::exception&) { return nullptr; }
}
void wbd_destroy(void* d) { delete static_cast<Driver*>(d); }
int wbd_option_double(void* d, const char* name, double value) {
  try { static_cast<Driver*>(d)->options.set_option<double>(name, value); return 0; } catch (const std::exception&) { return 1; }
}
int wbd_option_int(void* d, const char* name, int value) {
  try { static_cast<Driver*>(d)->options.set_option<int>(name, value); return 0; } catch (const std::exception&) { return 1; }
}
int wbd_option_bool(void* d, const char* name, int value) {
  try { static_cast<Driver*>(d)->options.set_option<bool>(name, value != 0); return 0; } catch (const std::exception&) { return 1; }
}
/* warm: start the equality multipliers from this instance's last converged solution (if it has one) */
int wbd_solve(void* handle, int warm) {
  Driver* d = static_cast<Driver*>(handle);
  d->warm->use_ = warm && d->warm->valid_;
  int ret;
  d->flag = IpSolverReturnFlag::Unknown;
  try {
    d->flag = d->algo->optimize();
    ret = d->flag == IpSolverReturnFlag::Success ? 0 : 1;
  } catch (const std::exception&) {
    ret = -1;
  }
  if (ret == 0 || d->flag == IpSolverReturnFlag::StopAtAcceptablePoint) d->warm->store(d->data->current_iterate());
  return ret;
}
const double* wbd_primal(void* d) { return static_cast<Driver*>(d)->algo->solution_primal().data(); }
const double* wbd_dual(void* d) { return static_cast<Driver*>(d)->algo->solution_dual().data(); }
const void* wbd_dims(void* d) { return &static_cast<Driver*>(d)->m->s; }
const void* wbd_stats(void* handle) {
  Driver* d = static_cast<Driver*>(handle);
  IpTimingStatistics& t = d->data->timing_statistics();
  FatropOcpCStats& s = d->stats;
  s.compute_sd_time = t.compute_search_dir.elapsed();
  s.eval_hess_time = t.eval_hessian.elapsed();
  s.eval_jac_time = t.eval_jacobian.elapsed();
  s.eval_cv_time = t.eval_constraint_violation.elapsed();
  s.eval_grad_time = t.eval_gradient.elapsed();
  s.eval_obj_time = t.eval_objective.elapsed();
  s.initialization_time = t.initialization.elapsed();
  s.time_total = t.full_algorithm.elapsed();
  s.iterations_count = d->data->iteration_number();
  s.return_flag = int(d->flag);
  return &s;
}
}
"""

SHIM_BODY = r"""
typedef struct {
  const double *P, *lbx, *ubx, *lbg, *ubg, *x0;
  int a_eq[WB_NG + 1], a_ineq[WB_NG + 1], x_eq[WB_NV + 1], x_ineq[WB_NV + 1];
  int a_eq_i[WB_K + 1], a_ineq_i[WB_K + 1], x_eq_i[WB_K + 1], x_ineq_i[WB_K + 1];
  const casadi_real* arg[WB_SZ_ARG + 8];
  casadi_real* res[WB_SZ_RES + 8];
  casadi_int iw[WB_SZ_IW];
  casadi_real w[WB_SZ_W];
  double jac_next[WB_K][WB_MAXN * WB_MAXX];
  double jac_rows[WB_K][WB_MAXN * WB_MAXR];
  double hess[WB_MAXN * WB_MAXN];
  double f[WB_MAXX + 1], r[WB_MAXR + 1], lam_rows[WB_MAXR + 1], zeros[WB_MAXX + 1];
  double t_functions; /* s in generated functions since the last solve started */
  double deadline;    /* CLOCK_MONOTONIC s; 0: none */
  int deadline_hit;
} wb_ctx;

typedef struct {
  struct FatropOcpCInterface ocp;
  void* solver; /* the C++ driver (DRIVER_SOURCE) */
  int n_eq[WB_K], n_ineq[WB_K];
} wb_solver;

static int wb_panel4 = -1; /* BLASFEO's panel height is 4 (the layout wb_pack writes) */

static int wb_check_panel4(void) {
  double memory[256 + 64];
  struct blasfeo_dmat A;
  if (blasfeo_memsize_dmat(8, 8) > (int) sizeof(double) * 256) return 0;
  blasfeo_create_dmat(8, 8, &A, (void*) (((size_t) memory + 63) & ~(size_t) 63));
  memset(A.pA, 0, sizeof(double) * 64);
  blasfeo_dgein1(1.0, &A, 5, 1);
  return A.pA[4 * A.cn + 1 * 4 + 1] == 1.0;
}

/* blasfeo_pack_dmat(m, n, A, lda, B, 0, 0): column-major A into panel-major B (BLASFEO's took ~8 % of a solve) */
static void wb_pack(int m, int n, const double* A, int lda, struct blasfeo_dmat* B) {
#if defined(__AVX__)
  if (wb_panel4 == 1) {
    double* pB = B->pA;
    int p, j, t;
    for (p = 0; p + 4 <= m; p += 4) {
      double* panel = pB + (size_t) p * B->cn;
      for (j = 0; j < n; ++j) _mm256_storeu_pd(panel + 4 * j, _mm256_loadu_pd(A + p + (size_t) j * lda));
    }
    if (p < m) {
      double* panel = pB + (size_t) p * B->cn;
      for (j = 0; j < n; ++j)
        for (t = 0; t < m - p; ++t) panel[4 * j + t] = A[p + t + (size_t) j * lda];
    }
    B->use_dA = 0;
    return;
  }
#endif
  blasfeo_pack_dmat(m, n, (double*) A, lda, B, 0, 0);
}

static double wb_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* one generated call: inputs u, x, p_k (+ extra), outputs res0, res1 */
static void wb_call(wb_ctx* c, wb_fn fn, const double* u, const double* x, int k, const double* a3,
                    const double* a4, const double* a5, double* r0, double* r1) {
  double start = wb_now();
  if (c->deadline > 0 && start > c->deadline) { /* unwinds to wbd_solve, which returns -1 */
    c->deadline = 0;
    c->deadline_hit = 1;
    wb_throw_deadline();
  }
  c->arg[0] = u; c->arg[1] = x; c->arg[2] = c->P + (size_t) k * WB_NP;
  c->arg[3] = a3; c->arg[4] = a4; c->arg[5] = a5;
  c->res[0] = r0; c->res[1] = r1;
  fn(c->arg, c->res, c->iw, c->w, 0);
  c->t_functions += wb_now() - start;
}

/* variable j of the NLP (in stage k) inside Fatrop's primal vector */
static double wb_var(const double* primal, const struct FatropOcpCDims* s, int k, int j) {
  int local = j - wb_xo[k];
  return local < wb_nx[k] ? primal[s->ux_offs[k] + wb_nu[k] + local] : primal[s->ux_offs[k] + local - wb_nx[k]];
}

static int wb_fatrop_row(int k, int j) { /* position of NLP variable j of stage k in (u_k, x_k) */
  int local = j - wb_xo[k];
  return local < wb_nx[k] ? wb_nu[k] + local : local - wb_nx[k];
}

static void wb_classify(wb_ctx* c) {
  int k, i;
  c->a_eq_i[0] = c->a_ineq_i[0] = c->x_eq_i[0] = c->x_ineq_i[0] = 0;
  for (k = 0; k < WB_K; ++k) {
    int ae = c->a_eq_i[k], ai = c->a_ineq_i[k], xe = c->x_eq_i[k], xi = c->x_ineq_i[k];
    for (i = wb_ro[k]; i < wb_ro[k] + wb_nr[k]; ++i) {
      if (c->lbg[i] == c->ubg[i]) c->a_eq[ae++] = i;
      else if (!(isinf(c->lbg[i]) && c->lbg[i] < 0 && isinf(c->ubg[i]) && c->ubg[i] > 0)) c->a_ineq[ai++] = i;
    }
    for (i = wb_xo[k]; i < wb_xo[k] + wb_nx[k] + wb_nu[k]; ++i) {
      if (c->lbx[i] == c->ubx[i]) c->x_eq[xe++] = i;
      else if (!(isinf(c->lbx[i]) && c->lbx[i] < 0 && isinf(c->ubx[i]) && c->ubx[i] > 0)) c->x_ineq[xi++] = i;
    }
    c->a_eq_i[k + 1] = ae; c->a_ineq_i[k + 1] = ai; c->x_eq_i[k + 1] = xe; c->x_ineq_i[k + 1] = xi;
  }
}

/* ---- Fatrop callbacks ---- */
static fatrop_int cb_nx(fatrop_int k, void* d) { return wb_nx[k < WB_K ? k : WB_K - 1]; }
static fatrop_int cb_nu(fatrop_int k, void* d) { return wb_nu[k]; }
static fatrop_int cb_ng(fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  return c->a_eq_i[k + 1] - c->a_eq_i[k] + c->x_eq_i[k + 1] - c->x_eq_i[k];
}
static fatrop_int cb_ng_ineq(fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  return c->a_ineq_i[k + 1] - c->a_ineq_i[k] + c->x_ineq_i[k + 1] - c->x_ineq_i[k];
}
static fatrop_int cb_horizon(void* d) { return WB_K; }

static fatrop_int cb_bounds(double* lower, double* upper, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int i, col = 0;
  for (i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1]; ++i, ++col) {
    lower[col] = c->lbg[c->a_ineq[i]]; upper[col] = c->ubg[c->a_ineq[i]];
  }
  for (i = c->x_ineq_i[k]; i < c->x_ineq_i[k + 1]; ++i, ++col) {
    lower[col] = c->lbx[c->x_ineq[i]]; upper[col] = c->ubx[c->x_ineq[i]];
  }
  return 0;
}
static fatrop_int cb_initial_xk(double* xk, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  memcpy(xk, c->x0 + wb_xo[k], sizeof(double) * wb_nx[k]);
  return 0;
}
static fatrop_int cb_initial_uk(double* uk, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  memcpy(uk, c->x0 + wb_xo[k] + wb_nx[k], sizeof(double) * wb_nu[k]);
  return 0;
}

/* the Hessian and Jacobian blocks come per stage (return 0: Fatrop then calls the stage callbacks) */
static fatrop_int cb_full_hess(double scale, const double* primal, const double* lam, const double* sp,
                               const double* gp, struct blasfeo_dmat* res, const struct FatropOcpCDims* s, void* d) {
  return 0;
}
static fatrop_int cb_full_jac(const double* primal, const double* sp, const double* gp, struct blasfeo_dmat* BAbt,
                              struct blasfeo_dmat* Gg, struct blasfeo_dmat* Gg_ineq, const struct FatropOcpCDims* s,
                              void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int k;
  for (k = 0; k < WB_K; ++k) {
    const double* u = primal + s->ux_offs[k];
    wb_call(c, wb_jac[wb_kind[k]], u, u + wb_nu[k], k, 0, 0, 0, c->jac_next[k], c->jac_rows[k]);
  }
  return 0;
}

static fatrop_int cb_RSQrqt(const double* scale, const double* u, const double* x, const double* lam_dyn,
                            const double* lam_eq, const double* lam_ineq, const double* sp, const double* gp,
                            struct blasfeo_dmat* res, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int i, col, n = wb_nu[k] + wb_nx[k];
  memset(c->lam_rows, 0, sizeof(double) * (wb_nr[k] + 1));
  for (i = c->a_eq_i[k], col = 0; i < c->a_eq_i[k + 1]; ++i, ++col) c->lam_rows[c->a_eq[i] - wb_ro[k]] = lam_eq[col];
  for (i = c->a_ineq_i[k], col = 0; i < c->a_ineq_i[k + 1]; ++i, ++col)
    c->lam_rows[c->a_ineq[i] - wb_ro[k]] = lam_ineq[col];
  wb_call(c, wb_hess[wb_kind[k]], u, x, k, scale, lam_dyn ? lam_dyn : c->zeros, c->lam_rows, c->hess, 0);
  wb_pack(n, n, c->hess, n, res);
  return 0;
}

static fatrop_int cb_BAbt(const double* x_next, const double* u, const double* x, const double* sp, const double* gp,
                          struct blasfeo_dmat* res, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int n = wb_nu[k] + wb_nx[k];
  wb_pack(n, wb_nx[k + 1], c->jac_next[k], n, res);
  return 0;
}

/* columns: the selected constraint rows (transposed Jacobian rows), then unit columns of the variables */
static void wb_pack_rows(wb_ctx* c, int k, const int* rows, int n_rows, const int* vars, int n_vars,
                         struct blasfeo_dmat* res) {
  int i, n = wb_nu[k] + wb_nx[k];
  for (i = 0; i < n_rows; ++i) blasfeo_pack_dmat(n, 1, c->jac_rows[k] + (size_t) (rows[i] - wb_ro[k]) * n, n, res, 0, i);
  if (n_vars > 0) {
    blasfeo_dgese(n, n_vars, 0.0, res, 0, n_rows);
    for (i = 0; i < n_vars; ++i) blasfeo_dgein1(1.0, res, wb_fatrop_row(k, vars[i]), n_rows + i);
  }
}
static fatrop_int cb_Ggt(const double* u, const double* x, const double* sp, const double* gp,
                         struct blasfeo_dmat* res, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_pack_rows(c, k, c->a_eq + c->a_eq_i[k], c->a_eq_i[k + 1] - c->a_eq_i[k], c->x_eq + c->x_eq_i[k],
               c->x_eq_i[k + 1] - c->x_eq_i[k], res);
  return 0;
}
static fatrop_int cb_Ggt_ineq(const double* u, const double* x, const double* sp, const double* gp,
                              struct blasfeo_dmat* res, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_pack_rows(c, k, c->a_ineq + c->a_ineq_i[k], c->a_ineq_i[k + 1] - c->a_ineq_i[k], c->x_ineq + c->x_ineq_i[k],
               c->x_ineq_i[k + 1] - c->x_ineq_i[k], res);
  return 0;
}

static fatrop_int cb_full_viol(const double* primal, const double* sp, const double* gp, double* res,
                               const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int k, i, col;
  for (k = 0; k < WB_K; ++k) {
    const double* u = primal + s->ux_offs[k];
    wb_call(c, wb_val[wb_kind[k]], u, u + wb_nu[k], k, 0, 0, 0, c->f, c->r);
    if (k < WB_K - 1) {
      const double* x_next = primal + s->ux_offs[k + 1] + wb_nu[k + 1];
      for (i = 0; i < wb_nx[k + 1]; ++i) res[s->dyn_eq_offs[k] + i] = c->f[i] - x_next[i];
    }
    col = 0;
    for (i = c->a_eq_i[k]; i < c->a_eq_i[k + 1]; ++i, ++col)
      res[s->g_offs[k] + col] = c->r[c->a_eq[i] - wb_ro[k]] - c->lbg[c->a_eq[i]];
    for (i = c->x_eq_i[k]; i < c->x_eq_i[k + 1]; ++i, ++col)
      res[s->g_offs[k] + col] = wb_var(primal, s, k, c->x_eq[i]) - c->lbx[c->x_eq[i]];
    col = 0;
    for (i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1]; ++i, ++col)
      res[s->g_ineq_offs[k] + col] = c->r[c->a_ineq[i] - wb_ro[k]];
    for (i = c->x_ineq_i[k]; i < c->x_ineq_i[k + 1]; ++i, ++col)
      res[s->g_ineq_offs[k] + col] = wb_var(primal, s, k, c->x_ineq[i]);
  }
  return 1; /* done: skip the stage callbacks */
}

static fatrop_int cb_full_grad(double scale, const double* primal, const double* sp, const double* gp, double* res,
                               const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int k, i;
  for (k = 0; k < WB_K; ++k) {
    const double* u = primal + s->ux_offs[k];
    double* g = res + s->ux_offs[k];
    wb_call(c, wb_grad[wb_kind[k]], u, u + wb_nu[k], k, 0, 0, 0, g, 0);
    if (scale != 1.0) for (i = 0; i < wb_nu[k] + wb_nx[k]; ++i) g[i] *= scale;
  }
  return 1;
}

static fatrop_int cb_full_obj(double scale, const double* primal, const double* sp, const double* gp, double* res,
                              const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  int k;
  double total = 0, value;
  for (k = 0; k < WB_K; ++k) {
    const double* u = primal + s->ux_offs[k];
    wb_call(c, wb_cost[wb_kind[k]], u, u + wb_nu[k], k, 0, 0, 0, &value, 0);
    total += value;
  }
  *res = scale * total;
  return 1;
}

/* ---- exported API (ctypes) ---- */
void* wb_ctx_new(void) {
  if (wb_panel4 < 0) wb_panel4 = wb_check_panel4();
  return calloc(1, sizeof(wb_ctx));
}
void wb_ctx_free(void* c) { free(c); }
int wb_sizes(int* out) { out[0] = WB_K; out[1] = WB_NP; out[2] = WB_NV; out[3] = WB_NG; return 0; }

void* wb_solver_new(void* ctx, const double* lbx, const double* ubx, const double* lbg, const double* ubg,
                    int verbose) {
  wb_ctx* c = (wb_ctx*) ctx;
  wb_solver* s = (wb_solver*) calloc(1, sizeof(wb_solver));
  struct FatropOcpCInterface* o = &s->ocp;
  int k;
  c->lbx = lbx; c->ubx = ubx; c->lbg = lbg; c->ubg = ubg;
  wb_classify(c);
  o->get_nx = cb_nx; o->get_nu = cb_nu; o->get_ng = cb_ng; o->get_ng_ineq = cb_ng_ineq;
  o->get_horizon_length = cb_horizon; o->get_bounds = cb_bounds;
  o->get_initial_xk = cb_initial_xk; o->get_initial_uk = cb_initial_uk;
  o->full_eval_lag_hess = cb_full_hess; o->full_eval_constr_jac = cb_full_jac;
  o->full_eval_contr_viol = cb_full_viol; o->full_eval_obj_grad = cb_full_grad; o->full_eval_obj = cb_full_obj;
  o->eval_RSQrqt = cb_RSQrqt; o->eval_BAbt = cb_BAbt; o->eval_Ggt = cb_Ggt; o->eval_Ggt_ineq = cb_Ggt_ineq;
  o->user_data = c;
  for (k = 0; k < WB_K; ++k) { s->n_eq[k] = cb_ng(k, c); s->n_ineq[k] = cb_ng_ineq(k, c); }
  s->solver = wbd_create(o);
  if (!s->solver) { free(s); return 0; }
  return s;
}
void wb_solver_free(void* solver) {
  wb_solver* s = (wb_solver*) solver;
  if (s) { wbd_destroy(s->solver); free(s); }
}
int wb_option_double(void* solver, const char* name, double value) {
  return wbd_option_double(((wb_solver*) solver)->solver, name, value);
}
int wb_option_int(void* solver, const char* name, int value) {
  return wbd_option_int(((wb_solver*) solver)->solver, name, value);
}
int wb_option_bool(void* solver, const char* name, int value) {
  return wbd_option_bool(((wb_solver*) solver)->solver, name, value);
}

/* one call of every generated function and one Fatrop instance (every row free) built and freed: a new process's
   first MPC step would otherwise pay the library's page faults and the heap's first growth to this problem's size */
int wb_warm_up(void* ctx) {
  wb_ctx* c = (wb_ctx*) ctx;
  double *P = (double*) calloc((size_t) WB_K * WB_NP + 1, sizeof(double));
  double *zeros = (double*) calloc(WB_MAXN + WB_MAXX + WB_MAXR + 3, sizeof(double));
  double *lo = (double*) malloc(sizeof(double) * (WB_NV + WB_NG)), *hi = (double*) malloc(sizeof(double) * (WB_NV + WB_NG));
  double *grad = (double*) calloc(WB_MAXN + 1, sizeof(double)), scale = 1.0, value;
  int k, i;
  void* solver;
  if (!P || !zeros || !lo || !hi || !grad) { free(P); free(zeros); free(lo); free(hi); free(grad); return -1; }
  c->P = P;
  for (k = 0; k < WB_K; ++k) {
    int kind = wb_kind[k];
    wb_call(c, wb_hess[kind], zeros, zeros, k, &scale, zeros, zeros, c->hess, 0);
    wb_call(c, wb_jac[kind], zeros, zeros, k, 0, 0, 0, c->jac_next[k], c->jac_rows[k]);
    wb_call(c, wb_val[kind], zeros, zeros, k, 0, 0, 0, c->f, c->r);
    wb_call(c, wb_grad[kind], zeros, zeros, k, 0, 0, 0, grad, 0);
    wb_call(c, wb_cost[kind], zeros, zeros, k, 0, 0, 0, &value, 0);
  }
  for (i = 0; i < WB_NV + WB_NG; ++i) { lo[i] = -INFINITY; hi[i] = INFINITY; }
  solver = wb_solver_new(ctx, lo, hi, lo + WB_NV, hi + WB_NV, 0);
  if (solver) wb_solver_free(solver);
  c->P = c->lbx = c->ubx = c->lbg = c->ubg = 0;
  free(P); free(zeros); free(lo); free(hi); free(grad);
  return solver ? 0 : -1;
}

/* NLP constraint values g(x) (gap rows x_{k+1} - f, then path rows), for checks and reports */
int wb_eval_g(void* ctx, const double* P, const double* x, double* g) {
  wb_ctx* c = (wb_ctx*) ctx;
  int k, i;
  c->P = P;
  for (k = 0; k < WB_K; ++k) {
    const double* xk = x + wb_xo[k];
    wb_call(c, wb_val[wb_kind[k]], xk + wb_nx[k], xk, k, 0, 0, 0, c->f, g + wb_ro[k]);
    if (k < WB_K - 1) for (i = 0; i < wb_nx[k + 1]; ++i) g[wb_go[k] + i] = x[wb_xo[k + 1] + i] - c->f[i];
  }
  return 0;
}

/* largest violation of the NLP's bounds at x (nlp.bound_violation's measure: rows g(x), then the variables) */
static double wb_violation(wb_ctx* c, const double* x) {
  int k, i;
  double worst = 0, v;
#define WB_VIOL(value, lo, hi) \
  v = (value); v = ((lo) - v > 0 ? (lo) - v : 0) + (v - (hi) > 0 ? v - (hi) : 0); if (v > worst) worst = v;
  for (k = 0; k < WB_K; ++k) {
    const double* xk = x + wb_xo[k];
    wb_call(c, wb_val[wb_kind[k]], xk + wb_nx[k], xk, k, 0, 0, 0, c->f, c->r);
    if (k < WB_K - 1)
      for (i = 0; i < wb_nx[k + 1]; ++i) { WB_VIOL(x[wb_xo[k + 1] + i] - c->f[i], c->lbg[wb_go[k] + i], c->ubg[wb_go[k] + i]) }
    for (i = 0; i < wb_nr[k]; ++i) { WB_VIOL(c->r[i], c->lbg[wb_ro[k] + i], c->ubg[wb_ro[k] + i]) }
  }
  for (i = 0; i < WB_NV; ++i) { WB_VIOL(x[i], c->lbx[i], c->ubx[i]) }
#undef WB_VIOL
  return worst;
}

/* stats: iterations, return flag, total, search directions, initialization, hess, jac, cv, grad, obj (s),
   generated functions (s), cost, largest bound violation at the solution. budget_s > 0: stop at the first callback after that many seconds and
   return the last accepted iterate (return value 3, flag -3). */
#define WB_NSTATS 13
int wb_solve(void* ctx, void* solver, const double* P, const double* lbx, const double* ubx, const double* lbg,
             const double* ubg, const double* x0, double* x_out, double* lam_g_out, double* lam_x_out,
             double* stats, double budget_s, int warm_duals) {
  wb_ctx* c = (wb_ctx*) ctx;
  wb_solver* s = (wb_solver*) solver;
  const struct FatropOcpCStats* st;
  const struct FatropOcpCDims* dims;
  const double *primal, *dual;
  int k, i, col, ret;
  c->P = P; c->lbx = lbx; c->ubx = ubx; c->lbg = lbg; c->ubg = ubg; c->x0 = x0;
  wb_classify(c);
  for (k = 0; k < WB_K; ++k)
    if (cb_ng(k, c) != s->n_eq[k] || cb_ng_ineq(k, c) != s->n_ineq[k]) return -2; /* another structure */
  c->t_functions = 0;
  c->deadline_hit = 0;
  c->deadline = budget_s > 0 ? wb_now() + budget_s : 0;
  ret = wbd_solve(s->solver, warm_duals);
  c->deadline = 0;
  st = (const struct FatropOcpCStats*) wbd_stats(s->solver);
  stats[0] = st->iterations_count; stats[1] = st->return_flag;
  /* Fatrop resets its timers at every solve */
  stats[2] = st->time_total; stats[3] = st->compute_sd_time; stats[4] = st->initialization_time;
  stats[5] = st->eval_hess_time; stats[6] = st->eval_jac_time; stats[7] = st->eval_cv_time;
  stats[8] = st->eval_grad_time; stats[9] = st->eval_obj_time;
  stats[10] = c->t_functions;
  if (c->deadline_hit) { ret = 3; stats[1] = -3; }
  else if (ret == -1) return -1; /* exception inside Fatrop */
  dims = (const struct FatropOcpCDims*) wbd_dims(s->solver);
  primal = wbd_primal(s->solver);
  dual = wbd_dual(s->solver);
  memset(lam_g_out, 0, sizeof(double) * WB_NG);
  memset(lam_x_out, 0, sizeof(double) * WB_NV);
  stats[11] = 0;
  for (k = 0; k < WB_K; ++k) {
    double value;
    memcpy(x_out + wb_xo[k], primal + dims->ux_offs[k] + wb_nu[k], sizeof(double) * wb_nx[k]);
    memcpy(x_out + wb_xo[k] + wb_nx[k], primal + dims->ux_offs[k], sizeof(double) * wb_nu[k]);
    wb_call(c, wb_cost[wb_kind[k]], primal + dims->ux_offs[k], primal + dims->ux_offs[k] + wb_nu[k], k, 0, 0, 0,
            &value, 0);
    stats[11] += value;
    col = 0;
    for (i = c->a_eq_i[k]; i < c->a_eq_i[k + 1]; ++i, ++col) lam_g_out[c->a_eq[i]] = dual[dims->g_offs[k] + col];
    for (i = c->x_eq_i[k]; i < c->x_eq_i[k + 1]; ++i, ++col) lam_x_out[c->x_eq[i]] = dual[dims->g_offs[k] + col];
    col = 0;
    for (i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1]; ++i, ++col)
      lam_g_out[c->a_ineq[i]] = dual[dims->g_ineq_offs[k] + col];
    for (i = c->x_ineq_i[k]; i < c->x_ineq_i[k + 1]; ++i, ++col)
      lam_x_out[c->x_ineq[i]] = dual[dims->g_ineq_offs[k] + col];
    if (k < WB_K - 1)
      for (i = 0; i < wb_nx[k + 1]; ++i) lam_g_out[wb_go[k] + i] = -dual[dims->dyn_eq_offs[k] + i];
  }
  stats[12] = wb_violation(c, x_out);
  return ret;
}
"""
