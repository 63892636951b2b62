/* The per-stage evaluations behind Fatrop's callbacks: one generated call per stage and, for the derivative
 * blocks, their packing into Fatrop's BLASFEO matrices. Each task reads the job and writes only stage k's
 * outputs and its thread's scratch, so the pool may run them on any thread in any order with the same
 * results bit for bit (tests/test_fatrop_threads.py). */
#include <math.h>
#include <string.h>
#include <time.h>
#if defined(__AVX__)
#include <immintrin.h>
#endif

#include "fatrop_shim.h"

double wb_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int wb_panel4 = -1; /* BLASFEO's panel height is 4 (the layout wb_pack writes) */

/* whether BLASFEO stores 4-row panels; called once before any pool runs */
int wb_pack_ready(void) {
  double memory[256 + 64];
  struct blasfeo_dmat A;
  if (wb_panel4 >= 0) return wb_panel4;
  if (blasfeo_memsize_dmat(8, 8) > (int) sizeof(double) * 256) return wb_panel4 = 0;
  blasfeo_create_dmat(8, 8, &A, (void*) (((size_t) memory + 63) & ~(size_t) 63));
  memset(A.pA, 0, sizeof(double) * 64);
  blasfeo_dgein1(1.0, &A, 5, 1);
  return wb_panel4 = A.pA[4 * A.cn + 1 * 4 + 1] == 1.0;
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

/* runs `task` on every stage (on the pool when there is one) and counts the wall time as function time */
void wb_run(wb_ctx* c, wb_task_fn task) {
  double start = wb_now();
  wb_pool_run(c->pool, c->st->n_stages, task, c);
  c->t_functions += wb_now() - start;
}

/* the same for a task on the batches of stages evaluated at once (wb_task_hess, wb_task_jac) */
void wb_run_batches(wb_ctx* c, wb_task_fn task) {
  double start = wb_now();
  wb_pool_run(c->pool, c->n_batches, task, c);
  c->t_functions += wb_now() - start;
}

/* Reads function `function` of kind `kind` into this core's caches before its first call on this thread after
   another kind's. Each function is one straight-line block of machine code (g1's stage Hessian 1.5 MB), which the
   core fetches line by line when it is cold; between Fatrop iterations the linear algebra and other processes evict
   it, and the first call of each kind took 5-15 times the next ones (g1 in the solver: 0.67 ms against 0.05 ms).
   One load per cache line keeps many misses in flight (software prefetches were dropped: no gain); evicted
   first: 0.42 -> 0.28 ms (g1's Hessian), 0.35 -> 0.17 ms (its first Jacobian). Only the timing changes. */
static void wb_prefetch_code(const wb_stages* st, wb_work* w, int function, int kind) {
  const char *p, *end;
  const int last = w->last_kind[function];
  if (last == kind) return;
  w->last_kind[function] = kind;
  if (!st->code) return;
  p = st->code[2 * (kind * WB_N_FUNCTIONS + function)];
  end = st->code[2 * (kind * WB_N_FUNCTIONS + function) + 1];
  if (!p || end <= p) return;
  if (last >= 0 && st->code[2 * (last * WB_N_FUNCTIONS + function)] == p) return; /* a covered kind: the same code */
  for (; p < end; p += 64) (void) *(const volatile char*) p;
}

/* one generated call: inputs u, x, p_k (+ a3, a4, a5), outputs r0, r1 */
static void wb_call(const wb_ctx* c, wb_work* w, int function, int k, const double* u, const double* x,
                    const double* a3, const double* a4, const double* a5, double* r0, double* r1) {
  const wb_stages* st = c->st;
  w->arg[0] = u; w->arg[1] = x; w->arg[2] = c->P + (size_t) k * st->n_params;
  w->arg[3] = a3; w->arg[4] = a4; w->arg[5] = a5;
  w->res[0] = r0; w->res[1] = r1;
  wb_prefetch_code(st, w, function, st->kind[k]);
  st->functions[st->kind[k] * WB_N_FUNCTIONS + function](w->arg, w->res, w->iw, w->w, 0);
}

static int wb_all_finite(const double* v, int n) {
  int i;
  for (i = 0; i < n; ++i)
    if (!isfinite(v[i])) return 0;
  return 1;
}

/* stage k's inputs and states in the job's primal vector (Fatrop's (u_free, x) per stage, or the NLP's (x, u));
   the whole u (fixed inputs at their value, in `ufull` where there are some) */
static void wb_stage_point(const wb_ctx* c, double* ufull, int k, const double** u, const double** x) {
  const wb_job* j = &c->job;
  if (j->dims) {
    const double* u_free = j->primal + j->dims->ux_offs[k];
    *x = u_free + c->nur[k];
    *u = wb_full_inputs(c, ufull, k, u_free);
  } else {
    *x = j->primal + c->st->x_offset[k];
    *u = *x + c->st->nx[k];
  }
}

/* the stages a batch evaluates at once (batch_k[batch_i[b]] ...) */
static int wb_batch(const wb_ctx* c, int b, const int** stages) {
  *stages = c->batch_k + c->batch_i[b];
  return c->batch_i[b + 1] - c->batch_i[b];
}

/* the kind whose code evaluates stage k's Hessian and Jacobian (its cover's, stage_covers.py) */
static int wb_code_kind(const wb_stages* st, int k) {
  const int kind = st->kind[k];
  return st->covers && st->covers[kind].cover >= 0 ? st->covers[kind].cover : kind;
}

/* the lanes of a kind's calls: its lane functions' (1: its scalar code) */
int wb_kind_lanes(const wb_stages* st, int kind) {
  const wb_lane_fn* f = st->lane_functions;
  return f && f[kind * WB_N_LANE_FUNCTIONS + WB_LANE_HESS] && f[kind * WB_N_LANE_FUNCTIONS + WB_LANE_JAC] ? st->lanes : 1;
}

/* the Hessian's (WB_LANE_HESS) or Jacobian's lane function of `kind` on the n_l stages in lanes 0 .. n_l - 1 of arg
   and res (stride L, the unused lanes repeating lane 0; res in the kind's lane buffers, cleared on their first use);
   with L = 1 the function of stage k's kind (its scalar code or its cover's wrapper) */
static void wb_eval(const wb_ctx* c, wb_work* w, int lane_function, int kind, int k, int n_l, int L,
                    const double** arg, int n_in, double** res, int n_out) {
  const wb_stages* st = c->st;
  const int function = lane_function == WB_LANE_HESS ? WB_HESS : WB_JAC;
  int i, l, clear = 0;
  wb_prefetch_code(st, w, function, kind);
  if (L == 1) {
    st->functions[st->kind[k] * WB_N_FUNCTIONS + function](arg, res, w->iw, w->w, 0);
    return;
  }
  for (i = 0; i < n_in; ++i)
    for (l = n_l; l < L; ++l) arg[i * L + l] = arg[i * L];
  for (i = 0; i < n_out; ++i)
    for (l = n_l; l < L; ++l) res[i * L + l] = res[i * L];
  clear = ((1 << n_l) - 1) & ~w->lane_held[kind * WB_N_LANE_FUNCTIONS + lane_function];
  w->lane_held[kind * WB_N_LANE_FUNCTIONS + lane_function] |= clear;
  st->lane_functions[kind * WB_N_LANE_FUNCTIONS + lane_function](arg, res, clear);
}

/* RSQrqt of the batch's stages: each stage Lagrangian's Hessian in (u, x), multipliers of the stage's rows scattered
   to its r (a covered kind's: to its cover's) */
void wb_task_hess(void* job, int b, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_job* j = &c->job;
  const wb_stages* st = c->st;
  const struct FatropOcpCDims* s = j->dims;
  wb_work* w = &c->work[worker];
  const double* arg[6 * WB_MAX_LANES];
  double* res[WB_MAX_LANES];
  const int* ks;
  const int n_l = wb_batch(c, b, &ks), code = wb_code_kind(st, ks[0]), L = n_l > 1 ? st->lanes : wb_kind_lanes(st, code);
  int l, i, col;
  for (l = 0; l < n_l; ++l) {
    const int k = ks[l], r0 = st->row_offset[k];
    const double *lam_eq = j->lam + s->g_offs[k], *lam_ineq = j->lam + s->g_ineq_offs[k];
    double* lam_rows = w->lam_rows + (size_t) l * (st->max_rows + 1);
    double* own = L > 1 && st->kind[k] != code ? w->cover_lam : lam_rows;
    memset(own, 0, sizeof(double) * (st->nr[k] + 1));
    for (i = c->a_eq_i[k], col = 0; i < c->a_eq_i[k + 1]; ++i, ++col) own[c->a_eq[i] - r0] = lam_eq[col];
    for (i = c->a_ineq_i[k], col = 0; i < c->a_ineq_i[k + 1]; ++i, ++col) own[c->a_ineq[i] - r0] = lam_ineq[col];
    if (own != lam_rows) st->covers[st->kind[k]].lam(own, lam_rows);
    wb_stage_point(c, w->ufull + (size_t) l * (st->max_n + 1), k, &arg[l], &arg[L + l]);
    arg[2 * L + l] = c->P + (size_t) k * st->n_params;
    arg[3 * L + l] = &j->scale;
    arg[4 * L + l] = k < st->n_stages - 1 ? j->lam + s->dyn_eq_offs[k] : c->zeros;
    arg[5 * L + l] = lam_rows;
    res[l] = L > 1 ? w->lane_hess[code] + (size_t) l * st->max_n * st->max_n : w->hess;
  }
  wb_eval(c, w, WB_LANE_HESS, code, ks[0], n_l, L, arg, 6, res, 1);
  for (l = 0; l < n_l; ++l) {
    const int k = ks[l], n = st->nu[k] + st->nx[k], nr = c->nur[k] + st->nx[k];
    if (j->check_finite && !wb_all_finite(res[l], n * n)) c->nonfinite_hit = 1;
    wb_pack(nr, nr, wb_reduce_square(c, w, k, res[l], n), nr, j->m0 + k);
  }
}

/* Ggt / Ggt_ineq: the selected rows' transposed Jacobian columns (Fatrop's rows of them, gathered into one block and
   packed at once), then unit columns of the selected variables */
static void wb_pack_rows(const wb_ctx* c, wb_work* w, int k, const double* jac_rows, const int* rows, int n_rows,
                         const int* vars, int n_vars, struct blasfeo_dmat* res) {
  const wb_stages* st = c->st;
  int i, n = st->nu[k] + st->nx[k], nr = c->nur[k] + st->nx[k];
  if (n_rows > 0) {
    for (i = 0; i < n_rows; ++i) w->cols[i] = rows[i] - st->row_offset[k];
    wb_pack(nr, n_rows, wb_reduce_rows(c, w, k, jac_rows, n, n_rows, w->cols), nr, res);
  }
  if (n_vars > 0) {
    blasfeo_dgese(nr, n_vars, 0.0, res, 0, n_rows);
    for (i = 0; i < n_vars; ++i) blasfeo_dgein1(1.0, res, c->red_pos[vars[i]], n_rows + i);
  }
}

/* stage k's BAbt, Ggt and Ggt_ineq from its Jacobian blocks (with `cache_only`: the fixed inputs' rows alone) */
static void wb_jac_done(wb_ctx* c, wb_work* w, int k, const double* jac_next, const double* jac_rows) {
  const wb_job* j = &c->job;
  const wb_stages* st = c->st;
  int n = st->nu[k] + st->nx[k], nr = c->nur[k] + st->nx[k], n_next = k < st->n_stages - 1 ? st->nx[k + 1] : 0;
  if (j->check_finite && !(wb_all_finite(jac_next, n * n_next) && wb_all_finite(jac_rows, n * st->nr[k])))
    c->nonfinite_hit = 1;
  if (c->nur[k] < st->nu[k]) wb_keep_fixed_rows(c, k, jac_next, jac_rows, n);
  if (j->cache_only) return;
  if (n_next > 0) wb_pack(nr, n_next, wb_reduce_rows(c, w, k, jac_next, n, n_next, 0), nr, j->m0 + k);
  wb_pack_rows(c, w, k, jac_rows, c->a_eq + c->a_eq_i[k], c->a_eq_i[k + 1] - c->a_eq_i[k], c->x_eq + c->x_eq_i[k],
               c->x_eq_i[k + 1] - c->x_eq_i[k], j->m1 + k);
  wb_pack_rows(c, w, k, jac_rows, c->a_ineq + c->a_ineq_i[k], c->a_ineq_i[k + 1] - c->a_ineq_i[k],
               c->x_ineq + c->x_ineq_i[k], c->x_ineq_i[k + 1] - c->x_ineq_i[k], j->m2 + k);
}

/* the batch's stages' Jacobians, one call (a covered kind's rows from its cover's), then each stage's blocks */
void wb_task_jac(void* job, int b, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_stages* st = c->st;
  wb_work* w = &c->work[worker];
  const double* arg[3 * WB_MAX_LANES];
  double* res[2 * WB_MAX_LANES];
  const int* ks;
  const int n_l = wb_batch(c, b, &ks), code = wb_code_kind(st, ks[0]), L = n_l > 1 ? st->lanes : wb_kind_lanes(st, code);
  int l;
  for (l = 0; l < n_l; ++l) {
    const int k = ks[l];
    wb_stage_point(c, w->ufull + (size_t) l * (st->max_n + 1), k, &arg[l], &arg[L + l]);
    arg[2 * L + l] = c->P + (size_t) k * st->n_params;
    res[l] = L > 1 ? w->lane_jac_next[code] + (size_t) l * st->max_n * st->max_x : w->jac_next;
    res[L + l] = L > 1 ? w->lane_jac_rows[code] + (size_t) l * st->max_n * st->max_rows : w->jac_rows;
  }
  wb_eval(c, w, WB_LANE_JAC, code, ks[0], n_l, L, arg, 3, res, 2);
  for (l = 0; l < n_l; ++l) {
    const int k = ks[l];
    if (L > 1 && st->kind[k] != code) { /* the cover's rows into the kind's */
      st->covers[st->kind[k]].rows(res[L + l], w->cover_rows);
      wb_jac_done(c, w, k, res[l], w->cover_rows);
    } else {
      wb_jac_done(c, w, k, res[l], res[L + l]);
    }
  }
}

/* NLP variable v (of stage k, not eliminated) in Fatrop's primal vector */
static double wb_var(const wb_ctx* c, const double* primal, const struct FatropOcpCDims* s, int k, int v) {
  return primal[s->ux_offs[k] + c->red_pos[v]];
}

/* Fatrop's constraint values of stage k: dynamics gap, equality rows - lower bound, inequality rows; f and r
   kept per stage (the solution's violation and cost reuse them when the solve ends on this point) */
void wb_task_viol(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_job* j = &c->job;
  const wb_stages* st = c->st;
  const struct FatropOcpCDims* s = j->dims;
  double *f = c->stage_f + (size_t) k * st->max_x, *r = c->stage_r + (size_t) k * st->max_rows, *res = j->out;
  const double *u, *x;
  int i, col = 0, r0 = st->row_offset[k];
  wb_stage_point(c, c->work[worker].ufull, k, &u, &x);
  wb_call(c, &c->work[worker], WB_VAL, k, u, x, 0, 0, 0, f, r);
  if (j->check_finite && !(wb_all_finite(f, k < st->n_stages - 1 ? st->nx[k + 1] : 0) && wb_all_finite(r, st->nr[k])))
    c->nonfinite_hit = 1;
  if (k < st->n_stages - 1) {
    const double* x_next = j->primal + s->ux_offs[k + 1] + c->nur[k + 1];
    for (i = 0; i < st->nx[k + 1]; ++i) res[s->dyn_eq_offs[k] + i] = f[i] - x_next[i];
  }
  for (i = c->a_eq_i[k]; i < c->a_eq_i[k + 1]; ++i, ++col)
    res[s->g_offs[k] + col] = r[c->a_eq[i] - r0] - c->lbg[c->a_eq[i]];
  for (i = c->x_eq_i[k]; i < c->x_eq_i[k + 1]; ++i, ++col)
    res[s->g_offs[k] + col] = wb_var(c, j->primal, s, k, c->x_eq[i]) - c->lbx[c->x_eq[i]];
  col = 0;
  for (i = c->a_ineq_i[k]; i < c->a_ineq_i[k + 1]; ++i, ++col) res[s->g_ineq_offs[k] + col] = r[c->a_ineq[i] - r0];
  for (i = c->x_ineq_i[k]; i < c->x_ineq_i[k + 1]; ++i, ++col)
    res[s->g_ineq_offs[k] + col] = wb_var(c, j->primal, s, k, c->x_ineq[i]);
}

/* the objective's gradient in Fatrop's (u_free, x), scaled; the fixed inputs' entries kept (their multipliers) */
void wb_task_grad(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_job* j = &c->job;
  wb_work* w = &c->work[worker];
  const int* map = c->rmap + c->rmap_i[k];
  const double *u, *x;
  int i, n = c->st->nu[k] + c->st->nx[k], nr = c->nur[k] + c->st->nx[k];
  wb_stage_point(c, w->ufull, k, &u, &x);
  wb_call(c, w, WB_GRAD, k, u, x, 0, 0, 0, w->col, 0);
  if (j->check_finite && !wb_all_finite(w->col, n)) c->nonfinite_hit = 1;
  for (i = c->u_fixed_i[k]; i < c->u_fixed_i[k + 1]; ++i) c->fix_grad[i] = w->col[c->u_fixed[i]];
  if (j->cache_only) return;
  for (i = 0; i < nr; ++i) j->out[j->dims->ux_offs[k] + i] = j->scale != 1.0 ? j->scale * w->col[map[i]] : w->col[map[i]];
}

/* stage k's cost into stage_cost[k] (summed in stage order by the caller: the same sum on any thread count) */
void wb_task_cost(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const double *u, *x;
  wb_stage_point(c, c->work[worker].ufull, k, &u, &x);
  wb_call(c, &c->work[worker], WB_COST, k, u, x, 0, 0, 0, c->stage_cost + k, 0);
}

/* the NLP's g at x (NLP layout): gap rows x_{k+1} - f, then the path rows; f and r kept per stage */
void wb_task_nlp_g(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_stages* st = c->st;
  const double *u, *x, *primal = c->job.primal;
  double *f = c->stage_f + (size_t) k * st->max_x, *g = c->job.out;
  int i;
  wb_stage_point(c, c->work[worker].ufull, k, &u, &x);
  wb_call(c, &c->work[worker], WB_VAL, k, u, x, 0, 0, 0, f, g ? g + st->row_offset[k] : c->stage_r + (size_t) k * st->max_rows);
  if (g && k < st->n_stages - 1)
    for (i = 0; i < st->nx[k + 1]; ++i) g[st->gap_offset[k] + i] = primal[st->x_offset[k + 1] + i] - f[i];
}

/* every function of stage k once on zeros (the first call's page faults and each thread's scratch) */
void wb_task_warm(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  wb_work* w = &c->work[worker];
  double scale = 1.0, value;
  const double* z = c->job.primal;
  wb_call(c, w, WB_HESS, k, z, z, &scale, z, z, w->hess, 0);
  wb_call(c, w, WB_JAC, k, z, z, 0, 0, 0, w->jac_next, w->jac_rows);
  wb_call(c, w, WB_VAL, k, z, z, 0, 0, 0, w->f, w->r);
  wb_call(c, w, WB_GRAD, k, z, z, 0, 0, 0, w->hess, 0);
  wb_call(c, w, WB_COST, k, z, z, 0, 0, 0, &value, 0);
}

/* doubles of stage k's block in wb_eval_derivatives' output: gradient, Hessian, (d f)', (d r)' in (u, x) */
static size_t wb_derivative_size(const wb_stages* st, int k) {
  size_t n = (size_t) (st->nu[k] + st->nx[k]);
  return n + n * n + n * (k < st->n_stages - 1 ? st->nx[k + 1] : 0) + n * st->nr[k];
}

/* stage k's derivatives at the NLP's x and multipliers lam_g (NLP signs: gap rows x_{k+1} - f), dense and
   column-major, into the job's flat output (wb_eval_derivatives) */
void wb_task_derivatives(void* job, int k, int worker) {
  wb_ctx* c = (wb_ctx*) job;
  const wb_job* j = &c->job;
  const wb_stages* st = c->st;
  wb_work* w = &c->work[worker];
  const double *u, *x, *lam_dyn = c->zeros;
  double* out = j->out;
  int i, n = st->nu[k] + st->nx[k];
  for (i = 0; i < k; ++i) out += wb_derivative_size(st, i);
  if (k < st->n_stages - 1) {
    for (i = 0; i < st->nx[k + 1]; ++i) w->f[i] = -j->lam[st->gap_offset[k] + i]; /* Fatrop's sign */
    lam_dyn = w->f;
  }
  wb_stage_point(c, w->ufull, k, &u, &x);
  wb_call(c, w, WB_GRAD, k, u, x, 0, 0, 0, out, 0);
  wb_call(c, w, WB_HESS, k, u, x, &j->scale, lam_dyn, j->lam + st->row_offset[k], out + n, 0);
  wb_call(c, w, WB_JAC, k, u, x, 0, 0, 0, out + n + (size_t) n * n,
          out + n + (size_t) n * n + (size_t) n * (k < st->n_stages - 1 ? st->nx[k + 1] : 0));
}
