/* wbmpc's Fatrop shim: Fatrop's OCP C interface on a problem's compiled stage functions (wbmpc_stages.h),
 * driven by the C++ driver (fatrop_driver.cpp: primal-dual warm start, time limit). Exported to Python
 * (solvers/fatrop_direct.py, ctypes): a context per solver object (the problem, its thread pool and
 * scratch), one Fatrop instance per row-count pattern, solves, and evaluations of g for checks. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fatrop_shim.h"

typedef struct {
  struct FatropOcpCInterface ocp;
  void* solver; /* the C++ driver */
  int *n_eq, *n_ineq, *nur; /* per stage: the dimensions Fatrop was built with */
} wb_solver;

/* each kind's lane output buffers (kinds with lane functions) */
static int wb_lane_buffers(wb_work* w, const wb_stages* st) {
  const size_t n = (size_t) st->max_n, L = (size_t) st->lanes;
  int kind, ok = 1;
  const int n_kinds = st->kinds->n_kinds;
  w->lane_hess = (double**) calloc(n_kinds, sizeof(double*));
  w->lane_jac_next = (double**) calloc(n_kinds, sizeof(double*));
  w->lane_jac_rows = (double**) calloc(n_kinds, sizeof(double*));
  w->lane_held = (int*) calloc(n_kinds * WB_N_LANE_FUNCTIONS, sizeof(int));
  if (!w->lane_hess || !w->lane_jac_next || !w->lane_jac_rows || !w->lane_held) return 0;
  for (kind = 0; kind < n_kinds && ok; ++kind) {
    if (wb_kind_lanes(st, kind) == 1) continue;
    w->lane_hess[kind] = (double*) calloc(L * n * n, sizeof(double));
    w->lane_jac_next[kind] = (double*) calloc(L * n * st->max_x, sizeof(double));
    w->lane_jac_rows[kind] = (double*) calloc(L * n * st->max_rows, sizeof(double));
    ok = w->lane_hess[kind] && w->lane_jac_next[kind] && w->lane_jac_rows[kind];
  }
  return ok;
}

static int wb_work_init(wb_work* w, const wb_stages* st) {
  size_t n = (size_t) st->max_n, L = (size_t) (st->lanes > 1 ? st->lanes : 1);
  int f;
  for (f = 0; f < WB_N_FUNCTIONS; ++f) w->last_kind[f] = -1;
  if (!wb_lane_buffers(w, st)) return 0;
  w->cover_lam = (double*) calloc(st->max_rows + 1, sizeof(double));
  w->cover_rows = (double*) calloc(n * st->max_rows + 1, sizeof(double));
  w->arg = (const double**) calloc(st->sz_arg + 8, sizeof(double*));
  w->res = (double**) calloc(st->sz_res + 8, sizeof(double*));
  w->iw = (long long int*) calloc(st->sz_iw + 1, sizeof(long long int));
  w->w = (double*) calloc(st->sz_w + 1, sizeof(double));
  w->hess = (double*) calloc(n * n + 1, sizeof(double));
  w->jac_next = (double*) calloc(n * st->max_x + 1, sizeof(double));
  w->jac_rows = (double*) calloc(n * st->max_rows + 1, sizeof(double));
  w->f = (double*) calloc(st->max_x + 1, sizeof(double));
  w->r = (double*) calloc(st->max_rows + 1, sizeof(double));
  w->lam_rows = (double*) calloc(L * (st->max_rows + 1), sizeof(double));
  w->ufull = (double*) calloc(L * (n + 1), sizeof(double));
  w->compact = (double*) calloc(n * (n + st->max_x + st->max_rows) + 1, sizeof(double));
  w->col = (double*) calloc(n + 1, sizeof(double));
  w->cols = (int*) calloc(st->max_rows + 1, sizeof(int));
  return w->arg && w->res && w->iw && w->w && w->hess && w->jac_next && w->jac_rows && w->f && w->r && w->lam_rows &&
         w->ufull && w->compact && w->col && w->cols && w->cover_lam && w->cover_rows;
}

static void wb_work_free(wb_work* w, int n_kinds) {
  int kind;
  for (kind = 0; kind < n_kinds && w->lane_hess; ++kind) {
    free(w->lane_hess[kind]); free(w->lane_jac_next[kind]); free(w->lane_jac_rows[kind]);
  }
  free(w->lane_hess); free(w->lane_jac_next); free(w->lane_jac_rows); free(w->lane_held);
  free((void*) w->arg); free(w->res); free(w->iw); free(w->w); free(w->hess);
  free(w->jac_next); free(w->jac_rows); free(w->f); free(w->r); free(w->lam_rows);
  free(w->ufull); free(w->compact); free(w->col); free(w->cols); free(w->cover_lam); free(w->cover_rows);
}

void wb_ctx_free(void* ctx) {
  wb_ctx* c = (wb_ctx*) ctx;
  int i;
  if (!c) return;
  wb_pool_free(c->pool);
  for (i = 0; c->work && i < c->n_work; ++i) wb_work_free(&c->work[i], c->st->kinds->n_kinds);
  free(c->work);
  free(c->a_eq); free(c->a_ineq); free(c->x_eq); free(c->x_ineq);
  free(c->a_eq_i); free(c->a_ineq_i); free(c->x_eq_i); free(c->x_ineq_i);
  free(c->zeros); free(c->stage_cost); free(c->stage_f); free(c->stage_r); free(c->last_primal);
  free(c->nur); free(c->u_fixed); free(c->u_fixed_i); free(c->rmap); free(c->rmap_i); free(c->red_pos);
  free(c->fix_jac); free(c->fix_grad); free(c->jac_primal); free(c->grad_primal); free(c->obj_primal);
  free(c->fix_i);
  free(c->p_index);
  free(c->run_src); free(c->run_dst); free(c->run_len); free(c->run_i);
  free(c->batch_i); free(c->batch_k);
  free(c->stages.kind);
  free(c);
}

/* the problem from the library's kinds and the layout table (WB_LAYOUT_ROWS x n_stages); 0 if inconsistent */
static int wb_stages_init(wb_stages* st, const wb_kinds* kinds, const int* layout, int n_stages, int n_params,
                          int n_variables, int n_constraints) {
  int k, *copy = (int*) malloc(sizeof(int) * WB_LAYOUT_ROWS * (n_stages > 0 ? n_stages : 1));
  if (!copy) return 0;
  memcpy(copy, layout, sizeof(int) * WB_LAYOUT_ROWS * n_stages);
  st->kinds = kinds; st->functions = kinds->functions; st->code = kinds->code;
  st->lanes = kinds->lane_functions && kinds->lanes > 1 && kinds->lanes <= WB_MAX_LANES ? kinds->lanes : 1;
  st->lane_functions = st->lanes > 1 ? kinds->lane_functions : 0;
  st->covers = kinds->covers;
  st->sz_arg = kinds->sz_arg; st->sz_res = kinds->sz_res; st->sz_iw = kinds->sz_iw; st->sz_w = kinds->sz_w;
  st->n_stages = n_stages; st->n_params = n_params; st->n_variables = n_variables; st->n_constraints = n_constraints;
  st->kind = copy + WB_L_KIND * n_stages; st->nx = copy + WB_L_NX * n_stages; st->nu = copy + WB_L_NU * n_stages;
  st->nr = copy + WB_L_NR * n_stages; st->x_offset = copy + WB_L_X_OFFSET * n_stages;
  st->row_offset = copy + WB_L_ROW_OFFSET * n_stages; st->gap_offset = copy + WB_L_GAP_OFFSET * n_stages;
  st->max_n = st->max_x = st->max_rows = 1;
  for (k = 0; k < n_stages; ++k) {
    if (st->kind[k] < 0 || st->kind[k] >= kinds->n_kinds) return 0;
    if (st->nu[k] + st->nx[k] > st->max_n) st->max_n = st->nu[k] + st->nx[k];
    if (st->nx[k] > st->max_x) st->max_x = st->nx[k];
    if (st->nr[k] > st->max_rows) st->max_rows = st->nr[k];
  }
  return n_stages > 0;
}

static int wb_ctx_alloc(wb_ctx* c, int n_threads) {
  const wb_stages* st = c->st;
  size_t K = (size_t) st->n_stages;
  int i, ok;
  c->a_eq = (int*) calloc(st->n_constraints + 1, sizeof(int));
  c->a_ineq = (int*) calloc(st->n_constraints + 1, sizeof(int));
  c->x_eq = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->x_ineq = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->a_eq_i = (int*) calloc(K + 1, sizeof(int)); c->a_ineq_i = (int*) calloc(K + 1, sizeof(int));
  c->x_eq_i = (int*) calloc(K + 1, sizeof(int)); c->x_ineq_i = (int*) calloc(K + 1, sizeof(int));
  c->zeros = (double*) calloc(st->max_n + st->max_x + st->max_rows + 3, sizeof(double));
  c->stage_cost = (double*) calloc(K, sizeof(double));
  c->stage_f = (double*) calloc(K * st->max_x + 1, sizeof(double));
  c->stage_r = (double*) calloc(K * st->max_rows + 1, sizeof(double));
  c->last_primal = (double*) calloc(st->n_variables + 1, sizeof(double));
  c->jac_primal = (double*) calloc(st->n_variables + 1, sizeof(double));
  c->grad_primal = (double*) calloc(st->n_variables + 1, sizeof(double));
  c->obj_primal = (double*) calloc(st->n_variables + 1, sizeof(double));
  c->nur = (int*) calloc(K, sizeof(int));
  c->u_fixed = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->rmap = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->red_pos = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->u_fixed_i = (int*) calloc(K + 1, sizeof(int)); c->rmap_i = (int*) calloc(K + 1, sizeof(int));
  c->fix_i = (int*) calloc(K + 1, sizeof(int));
  c->run_src = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->run_dst = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->run_len = (int*) calloc(st->n_variables + 1, sizeof(int));
  c->run_i = (int*) calloc(K + 1, sizeof(int));
  c->fix_grad = (double*) calloc(st->n_variables + 1, sizeof(double));
  c->fix_jac = (double*) calloc((size_t) st->n_variables * (st->max_x + st->max_rows) + 1, sizeof(double));
  c->work = (wb_work*) calloc(n_threads, sizeof(wb_work));
  c->batch_i = (int*) calloc(K + 1, sizeof(int));
  c->batch_k = (int*) calloc(2 * K + 2, sizeof(int)); /* and wb_batches' scratch */
  ok = c->a_eq && c->a_ineq && c->x_eq && c->x_ineq && c->a_eq_i && c->a_ineq_i && c->x_eq_i && c->x_ineq_i &&
       c->zeros && c->stage_cost && c->stage_f && c->stage_r && c->last_primal && c->jac_primal && c->grad_primal &&
       c->obj_primal &&
       c->nur && c->u_fixed && c->rmap && c->red_pos && c->u_fixed_i && c->rmap_i && c->fix_i && c->fix_grad &&
       c->fix_jac && c->run_src && c->run_dst && c->run_len && c->run_i && c->work && c->batch_i && c->batch_k;
  if (ok) wb_batches(c);
  for (i = 0; ok && i < n_threads; ++i, ++c->n_work) ok = wb_work_init(&c->work[i], st);
  if (ok && n_threads > 1) ok = (c->pool = wb_pool_new(n_threads - 1)) != 0;
  return ok;
}

/* a context for a problem (the stage library's kinds, the layout of its stages: WB_LAYOUT_ROWS x n_stages ints)
   evaluating on `n_threads` threads (the caller and n_threads - 1 pool workers); NULL if inconsistent or out of
   memory */
void* wb_ctx_new(const wb_kinds* kinds, const int* layout, int n_stages, int n_params, int n_variables,
                 int n_constraints, int n_threads) {
  wb_ctx* c;
  if (!kinds || kinds->version != WB_KINDS_VERSION || !layout) return 0;
  if (n_threads < 1) n_threads = 1;
  wb_pack_ready();
  c = (wb_ctx*) calloc(1, sizeof(wb_ctx));
  if (!c) return 0;
  c->st = &c->stages;
  c->eliminate = 1;
  if (!wb_stages_init(&c->stages, kinds, layout, n_stages, n_params, n_variables, n_constraints) ||
      !wb_ctx_alloc(c, n_threads)) {
    wb_ctx_free(c);
    return 0;
  }
  return c;
}

int wb_ctx_threads(void* ctx) { return 1 + wb_pool_workers(((wb_ctx*) ctx)->pool); }

/* 1 (default): inputs with lb == ub are eliminated (stage_layout.c); 0: equality rows, as casadi's plugin. Set before
   the context's first solver is made: its Fatrop instances keep the dimensions they were built with */
void wb_ctx_eliminate_fixed(void* ctx, int on) { ((wb_ctx*) ctx)->eliminate = on != 0; }

/* where each stage's parameters are in the NLP's p (n_stages x n_params positions, row-major, each below n_p): wb_solve
   then takes the NLP's p and gathers the stages' parameters itself. 0, or -1 for a position out of range */
int wb_ctx_parameters(void* ctx, const long long* p_index, int n_p) {
  wb_ctx* c = (wb_ctx*) ctx;
  const size_t n = (size_t) c->st->n_stages * c->st->n_params;
  size_t i;
  int* copy = (int*) malloc(sizeof(int) * (n + 1));
  if (!copy || n_p < 0) { free(copy); return -1; }
  for (i = 0; i < n; ++i) {
    if (p_index[i] < 0 || p_index[i] >= n_p) { free(copy); return -1; }
    copy[i] = (int) p_index[i];
  }
  free(c->p_index);
  c->p_index = copy;
  c->n_p = n_p;
  return 0;
}

/* where wb_solve writes: the stages' parameters P (n_stages x n_params), x, lam_g, lam_x (the NLP's layout) and its
   stats (15, see wb_solve): the caller's buffers, set once (fewer arguments per call) */
void wb_ctx_outputs(void* ctx, double* P, double* x, double* lam_g, double* lam_x, double* stats) {
  wb_ctx* c = (wb_ctx*) ctx;
  c->P_out = P; c->x_out = x; c->lam_g_out = lam_g; c->lam_x_out = lam_x; c->stats_out = stats;
}

int wb_sizes(void* ctx, int* out) {
  const wb_stages* st = ((wb_ctx*) ctx)->st;
  out[0] = st->n_stages; out[1] = st->n_params; out[2] = st->n_variables; out[3] = st->n_constraints;
  return 0;
}

/* a Fatrop instance for the row split of these bounds (kept by the caller per row-count pattern) */
void* wb_solver_new(void* ctx, const double* lbx, const double* ubx, const double* lbg, const double* ubg,
                    int verbose) {
  wb_ctx* c = (wb_ctx*) ctx;
  wb_solver* s = (wb_solver*) calloc(1, sizeof(wb_solver));
  int k, K = c->st->n_stages;
  (void) verbose;
  if (!s) return 0;
  s->n_eq = (int*) calloc(K, sizeof(int));
  s->n_ineq = (int*) calloc(K, sizeof(int));
  s->nur = (int*) calloc(K, sizeof(int));
  c->lbx = lbx; c->ubx = ubx; c->lbg = lbg; c->ubg = ubg;
  wb_classify(c);
  wb_fill_interface(&s->ocp, c);
  for (k = 0; s->n_eq && s->n_ineq && s->nur && k < K; ++k) {
    s->n_eq[k] = wb_n_eq(c, k); s->n_ineq[k] = wb_n_ineq(c, k); s->nur[k] = c->nur[k];
  }
  s->solver = s->n_eq && s->n_ineq && s->nur ? wbd_create(&s->ocp) : 0;
  c->lbx = c->ubx = c->lbg = c->ubg = 0;
  if (!s->solver) { free(s->n_eq); free(s->n_ineq); free(s->nur); free(s); return 0; }
  return s;
}

void wb_solver_free(void* solver) {
  wb_solver* s = (wb_solver*) solver;
  if (!s) return;
  wbd_destroy(s->solver);
  free(s->n_eq); free(s->n_ineq); free(s->nur); free(s);
}

void wb_solver_forget(void* solver) { if (solver) wbd_forget(((wb_solver*) solver)->solver); }

int wb_option_double(void* solver, const char* name, double value) {
  return wbd_option_double(((wb_solver*) solver)->solver, name, value);
}
int wb_option_int(void* solver, const char* name, int value) {
  return wbd_option_int(((wb_solver*) solver)->solver, name, value);
}
int wb_option_bool(void* solver, const char* name, int value) {
  return wbd_option_bool(((wb_solver*) solver)->solver, name, value);
}

/* every generated function once on every thread and one Fatrop instance (every row free) built and freed: a new
   process's first MPC step would otherwise pay the library's page faults, the threads' first wake-up and the
   heap's first growth to this problem's size */
int wb_warm_up(void* ctx) {
  wb_ctx* c = (wb_ctx*) ctx;
  const wb_stages* st = c->st;
  double* P = (double*) calloc((size_t) st->n_stages * st->n_params + 1, sizeof(double));
  double* bounds = (double*) malloc(sizeof(double) * 2 * (st->n_variables + st->n_constraints));
  double *lo = bounds, *hi = bounds ? bounds + st->n_variables + st->n_constraints : 0;
  void* solver = 0;
  int i;
  if (P && bounds) {
    c->P = P;
    memset(&c->job, 0, sizeof(c->job));
    c->job.primal = c->zeros;
    wb_pool_run(c->pool, st->n_stages, wb_task_warm, c);
    for (i = 0; i < st->n_variables + st->n_constraints; ++i) { lo[i] = -INFINITY; hi[i] = INFINITY; }
    solver = wb_solver_new(ctx, lo, hi, lo + st->n_variables, hi + st->n_variables, 0);
    if (solver) wb_solver_free(solver);
  }
  c->P = 0;
  free(P); free(bounds);
  return solver ? 0 : -1;
}

/* NLP constraint values g(x) (gap rows x_{k+1} - f, then path rows), for checks and reports */
int wb_eval_g(void* ctx, const double* P, const double* x, double* g) {
  wb_ctx* c = (wb_ctx*) ctx;
  c->P = P;
  memset(&c->job, 0, sizeof(c->job));
  c->job.primal = x;
  c->job.out = g;
  wb_pool_run(c->pool, c->st->n_stages, wb_task_nlp_g, c);
  return 0;
}

/* every stage's cost gradient, Lagrangian Hessian (cost scaled by sigma, rows by lam_g with the NLP's signs) and
   transposed dynamics and row Jacobians at x, dense, stage after stage (checks and other algorithms) */
int wb_eval_derivatives(void* ctx, const double* P, const double* x, double sigma, const double* lam_g, double* out) {
  wb_ctx* c = (wb_ctx*) ctx;
  c->P = P;
  memset(&c->job, 0, sizeof(c->job));
  c->job.primal = x;
  c->job.lam = lam_g;
  c->job.scale = sigma;
  c->job.out = out;
  wb_pool_run(c->pool, c->st->n_stages, wb_task_derivatives, c);
  return 0;
}

/* largest violation of the NLP's bounds at x (nlp.bound_violation's measure: rows g(x), then the variables), from
   f and r per stage in stage_f / stage_r (evaluated at x) */
static double wb_violation(const wb_ctx* c, const double* x) {
  const wb_stages* st = c->st;
  int k, i;
  double worst = 0, v;
#define WB_VIOL(value, lo, hi) \
  v = (value); v = ((lo) - v > 0 ? (lo) - v : 0) + (v - (hi) > 0 ? v - (hi) : 0); if (v > worst) worst = v;
  for (k = 0; k < st->n_stages; ++k) {
    const double *f = c->stage_f + (size_t) k * st->max_x, *r = c->stage_r + (size_t) k * st->max_rows;
    int go = st->gap_offset[k], ro = st->row_offset[k];
    if (k < st->n_stages - 1)
      for (i = 0; i < st->nx[k + 1]; ++i) { WB_VIOL(x[st->x_offset[k + 1] + i] - f[i], c->lbg[go + i], c->ubg[go + i]) }
    for (i = 0; i < st->nr[k]; ++i) { WB_VIOL(r[i], c->lbg[ro + i], c->ubg[ro + i]) }
  }
  for (i = 0; i < st->n_variables; ++i) { WB_VIOL(x[i], c->lbx[i], c->ubx[i]) }
#undef WB_VIOL
  return worst;
}

/* Fatrop's solution in the NLP's layout: x (the fixed inputs at their value), and the multipliers of the rows (gap
   rows: the negative of Fatrop's dynamics multipliers, ours being x_{k+1} - f) and of the variables */
static void wb_unpack_stage(wb_ctx* c, int k, const double* primal, const double* dual,
                            const struct FatropOcpCDims* dims, double* x_out, double* lam_g_out, double* lam_x_out) {
  const wb_stages* st = c->st;
  const double* u_free = primal + dims->ux_offs[k];
  int i, col = 0;
  memcpy(x_out + st->x_offset[k], u_free + c->nur[k], sizeof(double) * st->nx[k]);
  memcpy(x_out + st->x_offset[k] + st->nx[k], wb_full_inputs(c, c->work[0].ufull, k, u_free), sizeof(double) * st->nu[k]);
  for (i = c->a_eq_i[k]; i < c->a_eq_i[k + 1]; ++i, ++col) lam_g_out[c->a_eq[i]] = dual[dims->g_offs[k] + col];
  for (i = c->x_eq_i[k]; i < c->x_eq_i[k + 1]; ++i, ++col) lam_x_out[c->x_eq[i]] = dual[dims->g_offs[k] + col];
  col = 0;
  for (i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1]; ++i, ++col) lam_g_out[c->a_ineq[i]] = dual[dims->g_ineq_offs[k] + col];
  for (i = c->x_ineq_i[k]; i < c->x_ineq_i[k + 1]; ++i, ++col) lam_x_out[c->x_ineq[i]] = dual[dims->g_ineq_offs[k] + col];
  if (k < st->n_stages - 1)
    for (i = 0; i < st->nx[k + 1]; ++i) lam_g_out[st->gap_offset[k] + i] = -dual[dims->dyn_eq_offs[k] + i];
}

/* multipliers in the NLP's layout (lam_g, lam_x: casadi's signs) into the driver's given-start buffers in Fatrop's
   order, wb_unpack_stage's map backwards: equality rows' multipliers, and per inequality (row or bounded variable,
   a slack for Fatrop) lam > 0 as its upper bound's multiplier, -lam as its lower bound's */
static void wb_pack_given(const wb_ctx* c, void* solver, const double* lam_g, const double* lam_x) {
  const wb_stages* st = c->st;
  const struct FatropOcpCDims* dims = (const struct FatropOcpCDims*) wbd_dims(solver);
  int sizes[2], k, i, col;
  double *dual = wbd_given(solver, 0, sizes), *zl = wbd_given(solver, 1, sizes), *zu = wbd_given(solver, 2, sizes);
  const int slack0 = dims->g_ineq_offs[0];
  double lam;
  memset(dual, 0, sizeof(double) * sizes[0]);
  for (k = 0; k < st->n_stages; ++k) {
    for (col = 0, i = c->a_eq_i[k]; i < c->a_eq_i[k + 1]; ++i, ++col) dual[dims->g_offs[k] + col] = lam_g[c->a_eq[i]];
    for (i = c->x_eq_i[k]; i < c->x_eq_i[k + 1]; ++i, ++col) dual[dims->g_offs[k] + col] = lam_x[c->x_eq[i]];
    for (col = 0, i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1] + (c->x_ineq_i[k + 1] - c->x_ineq_i[k]); ++i, ++col) {
      const int row = dims->g_ineq_offs[k] + col;
      lam = i < c->a_ineq_i[k + 1] ? lam_g[c->a_ineq[i]] : lam_x[c->x_ineq[c->x_ineq_i[k] + i - c->a_ineq_i[k + 1]]];
      dual[row] = lam;
      zu[row - slack0] = lam > 0 ? lam : 0.0;
      zl[row - slack0] = lam < 0 ? -lam : 0.0;
    }
    if (k < st->n_stages - 1)
      for (i = 0; i < st->nx[k + 1]; ++i) dual[dims->dyn_eq_offs[k] + i] = -lam_g[st->gap_offset[k] + i];
  }
}

static int wb_same_point(const wb_ctx* c, int valid, const double* stored, const double* primal) {
  return valid && memcmp(stored, primal, sizeof(double) * c->n_fatrop) == 0;
}

/* the solution unpacked (wb_unpack_stage), its cost summed over the stages; f and r at the solution (the
   violation) and the eliminated inputs' derivative rows (their multipliers) are those of Fatrop's last evaluations
   when they were at the solution (the accepted iterate, usually), else evaluated now */
static double wb_unpack(wb_ctx* c, void* solver, double* x_out, double* lam_g_out, double* lam_x_out) {
  const wb_stages* st = c->st;
  const struct FatropOcpCDims* dims = (const struct FatropOcpCDims*) wbd_dims(solver);
  const double *primal = wbd_primal(solver), *dual = wbd_dual(solver);
  double cost = 0;
  int k;
  memset(lam_g_out, 0, sizeof(double) * st->n_constraints);
  memset(lam_x_out, 0, sizeof(double) * st->n_variables);
  memset(&c->job, 0, sizeof(c->job));
  c->job.primal = primal;
  c->job.dims = dims;
  const int costed = wb_same_point(c, c->has_obj, c->obj_primal, primal); /* stage_cost holds its costs */
  for (k = 0; k < st->n_stages; ++k) {
    wb_unpack_stage(c, k, primal, dual, dims, x_out, lam_g_out, lam_x_out);
    if (!costed) wb_task_cost(c, k, 0);
    cost += c->stage_cost[k];
  }
  if (c->u_fixed_i[st->n_stages] > 0) {
    if (!(wb_same_point(c, c->has_jac, c->jac_primal, primal) && wb_same_point(c, c->has_grad, c->grad_primal, primal))) {
      c->job.cache_only = 1;
      wb_pool_run(c->pool, c->n_batches, wb_task_jac, c);
      wb_pool_run(c->pool, st->n_stages, wb_task_grad, c);
    }
    wb_fixed_multipliers(c, dual, dims, lam_g_out, lam_x_out);
  }
  if (!wb_same_point(c, c->has_last, c->last_primal, primal)) {
    memset(&c->job, 0, sizeof(c->job));
    c->job.primal = x_out;
    wb_pool_run(c->pool, st->n_stages, wb_task_nlp_g, c);
  }
  return cost;
}

static void wb_fill_stats(const wb_ctx* c, void* solver, double* stats) {
  const struct FatropOcpCStats* st = (const struct FatropOcpCStats*) wbd_stats(solver);
  stats[0] = st->iterations_count; stats[1] = st->return_flag;
  /* Fatrop resets its timers at every solve */
  stats[2] = st->time_total; stats[3] = st->compute_sd_time; stats[4] = st->initialization_time;
  stats[5] = st->eval_hess_time; stats[6] = st->eval_jac_time; stats[7] = st->eval_cv_time;
  stats[8] = st->eval_grad_time; stats[9] = st->eval_obj_time;
  stats[10] = c->t_functions;
}

/* 1 if every value is finite: v - v is 0 for a finite v and NaN otherwise (two sums, no branch per value) */
static int wb_all_finite(const double* v, int n) {
  double a = 0, b = 0;
  int i;
  for (i = 0; i + 2 <= n; i += 2) { a += v[i] - v[i]; b += v[i + 1] - v[i + 1]; }
  if (i < n) a += v[i] - v[i];
  return a + b == 0;
}

/* 1 if lower[i] <= upper[i] for every i (NaN fails) */
static int wb_in_order(const double* lower, const double* upper, int n) {
  int i, bad = 0;
  for (i = 0; i < n; ++i) bad |= !(lower[i] <= upper[i]);
  return !bad;
}

/* the inputs a solve refuses before any work: 0 if fine, -5 a parameter or an entry of the initial guess is not
   finite (Fatrop can hang on a NaN start), -6 a variable's or a row's bounds are out of order (lb > ub) or NaN */
static int wb_check_inputs(const wb_ctx* c, const double* p, const double* x0) {
  const wb_stages* st = c->st;
  if (!wb_all_finite(p, c->n_p) || !wb_all_finite(x0, st->n_variables)) return -5;
  if (!wb_in_order(c->lbx, c->ubx, st->n_variables) || !wb_in_order(c->lbg, c->ubg, st->n_constraints)) return -6;
  return 0;
}

/* One MPC solve from the NLP's p, bounds and initial guess (the inputs checked first, wb_check_inputs): the stages'
   parameters gathered into P (n_stages x n_params, wb_ctx_parameters' positions), the solution unpacked into x,
   lam_g, lam_x and the stats written into wb_ctx_outputs' buffers. solver NULL: the checks and the row
   classification only, returning -2 (the caller makes the instance of these bounds' rows and calls again).
   stats: iterations, return flag, total, search directions, initialization, hess, jac, cv, grad, obj (s), stage
   evaluations (s), cost, largest bound violation at the solution, the call's wall time outside Fatrop's timer (s:
   checks, rows, warm start, unpacking), 1 if every entry of x is finite (else 0). budget_s > 0: stop at the first
   evaluation after that many seconds with the last accepted iterate (return 3, flag -3). Returns 0 converged, 1 not,
   -1 Fatrop raised, -2 another row structure than the solver's, -4 non-finite constraint values or derivatives at
   x0, -5 / -6 refused inputs (wb_check_inputs), -7 no parameter positions or outputs (wb_ctx_parameters,
   wb_ctx_outputs). warm_duals: 0 Fatrop's own start (bound multipliers 1, least-squares equality multipliers), 1
   this instance's last solution's, 2 the given lam_g0 / lam_x0 (NLP layout), bound multipliers at least z_floor /
   their slack's distance */
int wb_solve(void* ctx, void* solver, const double* p, const double* lbx, const double* ubx, const double* lbg,
             const double* ubg, const double* x0, double budget_s, int warm_duals, const double* lam_g0,
             const double* lam_x0, double z_floor) {
  const double start = wb_now();
  wb_ctx* c = (wb_ctx*) ctx;
  wb_solver* s = (wb_solver*) solver;
  const int n_p = c->st->n_stages * c->st->n_params;
  double *P = c->P_out, *x_out = c->x_out, *stats = c->stats_out;
  int k, ret;
  if (!c->p_index || !P || !x_out || !c->lam_g_out || !c->lam_x_out || !stats) return -7;
  c->lbx = lbx; c->ubx = ubx; c->lbg = lbg; c->ubg = ubg; c->x0 = x0;
  ret = wb_check_inputs(c, p, x0);
  if (ret) return ret;
  for (k = 0; k < n_p; ++k) P[k] = p[c->p_index[k]];
  c->P = P;
  wb_classify(c);
  for (k = 0; s && k < c->st->n_stages; ++k)
    if (wb_n_eq(c, k) != s->n_eq[k] || wb_n_ineq(c, k) != s->n_ineq[k] || c->nur[k] != s->nur[k]) return -2;
  if (!s) return -2;
  c->t_functions = 0;
  c->deadline_hit = c->nonfinite_hit = c->checked = c->has_last = c->has_jac = c->has_grad = c->has_obj = 0;
  c->deadline = budget_s > 0 ? wb_now() + budget_s : 0;
  if (warm_duals == 2) wb_pack_given(c, s->solver, lam_g0, lam_x0);
  ret = wbd_solve(s->solver, warm_duals, z_floor);
  c->deadline = 0;
  wb_fill_stats(c, s->solver, stats);
  if (c->nonfinite_hit) return -4;
  if (c->deadline_hit) { ret = 3; stats[1] = -3; }
  else if (ret == -1) return -1; /* exception inside Fatrop */
  stats[11] = wb_unpack(c, s->solver, x_out, c->lam_g_out, c->lam_x_out);
  stats[12] = wb_violation(c, x_out);
  stats[14] = wb_all_finite(x_out, c->st->n_variables);
  stats[13] = wb_now() - start - stats[2];
  return ret;
}
