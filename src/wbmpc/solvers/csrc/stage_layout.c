/* What Fatrop sees of each stage: the split of its rows and variables into equalities and inequalities, as
 * casadi's Fatrop plugin makes it (a row or variable with lb == ub is an equality, one with a finite bound an
 * inequality, one with neither is left out; per stage the constraint rows first, then the variables, each in NLP
 * order), except for the inputs with lb == ub (a swing foot's zero force, the arm's commanded force): those are
 * eliminated, not equality rows. Fatrop sees each stage's free inputs u_free and its states x; the generated
 * functions get the whole u (the fixed inputs at their value), their blocks reduced to Fatrop's rows and columns.
 * Fewer inputs and equality rows make Fatrop's equality elimination (an LU per stage) and its Riccati recursion
 * smaller; the iterates are the same up to rounding. The fixed inputs' multipliers, which Fatrop no longer
 * computes, follow from the stationarity of the Lagrangian at the solution (wb_fixed_multipliers). */
#include <math.h>
#include <string.h>

#include "fatrop_shim.h"

static int wb_free(double lower, double upper) {
  return isinf(lower) && lower < 0 && isinf(upper) && upper > 0;
}

/* the runs of consecutive positions in stage k's rmap (a few: the free inputs between the fixed ones, the states) */
static void wb_stage_runs(wb_ctx* c, int k) {
  const int* map = c->rmap + c->rmap_i[k];
  int p, r = c->run_i[k], n = c->rmap_i[k + 1] - c->rmap_i[k];
  for (p = 0; p < n; ++p) {
    if (p > 0 && map[p] == map[p - 1] + 1) { c->run_len[r - 1]++; continue; }
    c->run_src[r] = map[p]; c->run_dst[r] = p; c->run_len[r] = 1; ++r;
  }
  c->run_i[k + 1] = r;
}

/* stage k's inputs: fixed ones listed, the others in Fatrop's order (rmap), the NLP -> Fatrop position map */
static void wb_reduce_stage(wb_ctx* c, int k) {
  const wb_stages* st = c->st;
  int i, nf = c->u_fixed_i[k], r = c->rmap_i[k], u0 = st->x_offset[k] + st->nx[k];
  for (i = 0; i < st->nu[k]; ++i) {
    if (c->eliminate && c->lbx[u0 + i] == c->ubx[u0 + i]) {
      c->u_fixed[nf++] = i;
      c->red_pos[u0 + i] = -1;
    } else {
      c->red_pos[u0 + i] = r - c->rmap_i[k];
      c->rmap[r++] = i;
    }
  }
  c->nur[k] = r - c->rmap_i[k];
  for (i = 0; i < st->nx[k]; ++i) {
    c->red_pos[st->x_offset[k] + i] = c->nur[k] + i;
    c->rmap[r++] = st->nu[k] + i;
  }
  c->u_fixed_i[k + 1] = nf;
  c->rmap_i[k + 1] = r;
  c->fix_i[k + 1] = c->fix_i[k] + (nf - c->u_fixed_i[k]) * ((k < st->n_stages - 1 ? st->nx[k + 1] : 0) + st->nr[k]);
  c->n_fatrop += c->nur[k] + st->nx[k];
  wb_stage_runs(c, k);
}

void wb_classify(wb_ctx* c) {
  const wb_stages* st = c->st;
  int k, i;
  c->a_eq_i[0] = c->a_ineq_i[0] = c->x_eq_i[0] = c->x_ineq_i[0] = 0;
  c->u_fixed_i[0] = c->rmap_i[0] = c->fix_i[0] = c->run_i[0] = c->n_fatrop = 0;
  for (k = 0; k < st->n_stages; ++k) {
    int ae = c->a_eq_i[k], ai = c->a_ineq_i[k], xe = c->x_eq_i[k], xi = c->x_ineq_i[k];
    int u0 = st->x_offset[k] + st->nx[k];
    for (i = st->row_offset[k]; i < st->row_offset[k] + st->nr[k]; ++i) {
      if (c->lbg[i] == c->ubg[i]) c->a_eq[ae++] = i;
      else if (!wb_free(c->lbg[i], c->ubg[i])) c->a_ineq[ai++] = i;
    }
    for (i = st->x_offset[k]; i < u0 + st->nu[k]; ++i) {
      if (c->lbx[i] == c->ubx[i]) { if (i < u0 || !c->eliminate) c->x_eq[xe++] = i; } /* fixed inputs: eliminated */
      else if (!wb_free(c->lbx[i], c->ubx[i])) c->x_ineq[xi++] = i;
    }
    c->a_eq_i[k + 1] = ae; c->a_ineq_i[k + 1] = ai; c->x_eq_i[k + 1] = xe; c->x_ineq_i[k + 1] = xi;
    wb_reduce_stage(c, k);
  }
}

/* stage k's whole u from Fatrop's free inputs (fixed ones at their bound); u_free itself when none is fixed */
const double* wb_full_inputs(const wb_ctx* c, double* ufull, int k, const double* u_free) {
  const wb_stages* st = c->st;
  int i, u0 = st->x_offset[k] + st->nx[k];
  if (c->nur[k] == st->nu[k]) return u_free;
  for (i = c->u_fixed_i[k]; i < c->u_fixed_i[k + 1]; ++i) ufull[c->u_fixed[i]] = c->lbx[u0 + c->u_fixed[i]];
  for (i = 0; i < c->nur[k]; ++i) ufull[c->rmap[c->rmap_i[k] + i]] = u_free[i];
  return ufull;
}

/* Fatrop's rows of column `src` (n long) of stage k into `dst` (n_r long), run by run */
static void wb_gather_column(const wb_ctx* c, int k, const double* src, double* dst) {
  int r;
  for (r = c->run_i[k]; r < c->run_i[k + 1]; ++r)
    memcpy(dst + c->run_dst[r], src + c->run_src[r], sizeof(double) * c->run_len[r]);
}

/* the (n_r x n_r) block of Fatrop's rows and columns of a column-major (n x n) matrix of stage k */
const double* wb_reduce_square(const wb_ctx* c, wb_work* w, int k, const double* A, int n) {
  const int* map = c->rmap + c->rmap_i[k];
  int j, nr = c->nur[k] + c->st->nx[k];
  if (nr == n) return A;
  for (j = 0; j < nr; ++j) wb_gather_column(c, k, A + (size_t) map[j] * n, w->compact + (size_t) j * nr);
  return w->compact;
}

/* the (n_r x n_cols) block of Fatrop's rows of the columns `cols` (all: NULL) of a column-major (n x .) matrix of
   stage k; A itself when nothing is to gather */
const double* wb_reduce_rows(const wb_ctx* c, wb_work* w, int k, const double* A, int n, int n_cols, const int* cols) {
  int j, nr = c->nur[k] + c->st->nx[k];
  if (nr == n && !cols) return A;
  for (j = 0; j < n_cols; ++j) {
    const double* src = A + (size_t) (cols ? cols[j] : j) * n;
    if (nr == n) memcpy(w->compact + (size_t) j * nr, src, sizeof(double) * n);
    else wb_gather_column(c, k, src, w->compact + (size_t) j * nr);
  }
  return w->compact;
}

/* the fixed inputs' rows of stage k's transposed Jacobians (n rows): [(d f / d u_j)', (d r / d u_j)'] per input */
void wb_keep_fixed_rows(wb_ctx* c, int k, const double* jac_next, const double* jac_rows, int n) {
  const wb_stages* st = c->st;
  int f, i, n_next = k < st->n_stages - 1 ? st->nx[k + 1] : 0, width = n_next + st->nr[k];
  double* out = c->fix_jac + c->fix_i[k];
  for (f = c->u_fixed_i[k]; f < c->u_fixed_i[k + 1]; ++f, out += width) {
    int j = c->u_fixed[f];
    for (i = 0; i < n_next; ++i) out[i] = jac_next[(size_t) i * n + j];
    for (i = 0; i < st->nr[k]; ++i) out[n_next + i] = jac_rows[(size_t) i * n + j];
  }
}

/* the fixed inputs' multipliers from the stationarity of the NLP's Lagrangian f + lam_g' g + lam_x' x in u_j:
   lam_x_j = -(d l / d u_j + sum_i pi_i d f_i / d u_j + sum_r lam_r d r_r / d u_j), pi Fatrop's dynamics multipliers
   (of f - x_{k+1}, the negative of the gap rows'), lam the rows' (lam_g, already unpacked) */
void wb_fixed_multipliers(const wb_ctx* c, const double* dual, const struct FatropOcpCDims* dims,
                          const double* lam_g, double* lam_x) {
  const wb_stages* st = c->st;
  int k, f, i;
  for (k = 0; k < st->n_stages; ++k) {
    int n_next = k < st->n_stages - 1 ? st->nx[k + 1] : 0, width = n_next + st->nr[k];
    int u0 = st->x_offset[k] + st->nx[k];
    const double* row = c->fix_jac + c->fix_i[k];
    const double* lam_rows = lam_g + st->row_offset[k];
    for (f = c->u_fixed_i[k]; f < c->u_fixed_i[k + 1]; ++f, row += width) {
      double value = c->fix_grad[f];
      for (i = 0; i < n_next; ++i) value += dual[dims->dyn_eq_offs[k] + i] * row[i];
      for (i = 0; i < st->nr[k]; ++i) value += lam_rows[i] * row[n_next + i];
      lam_x[u0 + c->u_fixed[f]] = -value;
    }
  }
}

/* the Hessian's and Jacobian's batches: stages whose code (their kind's or its cover's) has lane functions, up to its
   lanes a batch, in the order of their first stage; every other stage a batch of its own */
void wb_batches(wb_ctx* c) {
  const wb_stages* st = c->st;
  int k, m, n = 0, pos = 0, *code = c->batch_k + st->n_stages + 1; /* scratch past the batches' stages */
  for (k = 0; k < st->n_stages; ++k) {
    const int kind = st->kind[k];
    code[k] = st->covers && st->covers[kind].cover >= 0 ? st->covers[kind].cover : kind;
  }
  for (k = 0; k < st->n_stages; ++k) {
    int lanes;
    if (code[k] < 0) continue; /* placed */
    lanes = wb_kind_lanes(st, code[k]);
    c->batch_i[n++] = pos;
    for (m = k; m < st->n_stages && pos - c->batch_i[n - 1] < lanes; ++m)
      if (m == k || (code[m] == code[k] && lanes > 1)) {
        c->batch_k[pos++] = m;
        if (m != k) code[m] = -1;
      }
    code[k] = -1;
  }
  c->batch_i[n] = pos;
  c->n_batches = n;
}
