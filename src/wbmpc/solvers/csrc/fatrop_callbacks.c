/* Fatrop's OCP C interface (OCPCInterface.h) on the stage functions. Fatrop's mapping first offers each
 * evaluation whole ("full_eval_*"); answering there lets the shim evaluate all stages at once on the pool
 * (stage_tasks.c) instead of one stage per callback. The row split follows casadi's Fatrop plugin: a row or
 * variable with lb == ub is an equality, one with a finite bound an inequality, one with neither is left out;
 * per stage the constraint rows come first, then the variables, each in NLP order. */
#include <string.h>

#include "fatrop_shim.h"

/* the deadline (wb_solve's budget) and non-finite values at the start point end a solve by an exception
   through Fatrop (wbd_solve returns -1, wb_solve tells why from the flags) */
static void wb_check_deadline(wb_ctx* c) {
  if (c->deadline > 0 && wb_now() > c->deadline) {
    c->deadline = 0;
    c->deadline_hit = 1;
    wb_throw("wbmpc: deadline reached");
  }
}

static void wb_check_finite(wb_ctx* c) {
  if (c->nonfinite_hit) wb_throw("wbmpc: non-finite values at the start point");
}

/* a job on Fatrop's primal vector; `check_finite` while the solve has not yet seen its start point's values */
static void wb_begin(wb_ctx* c, const double* primal, const double* lam, double scale, const struct FatropOcpCDims* s) {
  wb_check_deadline(c);
  memset(&c->job, 0, sizeof(c->job));
  c->job.primal = primal;
  c->job.lam = lam;
  c->job.scale = scale;
  c->job.dims = s;
  c->job.check_finite = !c->checked;
}

fatrop_int wb_n_eq(wb_ctx* c, fatrop_int k) {
  return c->a_eq_i[k + 1] - c->a_eq_i[k] + c->x_eq_i[k + 1] - c->x_eq_i[k];
}
fatrop_int wb_n_ineq(wb_ctx* c, fatrop_int k) {
  return c->a_ineq_i[k + 1] - c->a_ineq_i[k] + c->x_ineq_i[k + 1] - c->x_ineq_i[k];
}

static fatrop_int cb_nx(fatrop_int k, void* d) {
  const wb_stages* st = ((wb_ctx*) d)->st;
  return st->nx[k < st->n_stages ? k : st->n_stages - 1];
}
static fatrop_int cb_nu(fatrop_int k, void* d) { return ((wb_ctx*) d)->nur[k]; } /* the free inputs */
static fatrop_int cb_ng(fatrop_int k, void* d) { return wb_n_eq((wb_ctx*) d, k); }
static fatrop_int cb_ng_ineq(fatrop_int k, void* d) { return wb_n_ineq((wb_ctx*) d, k); }
static fatrop_int cb_horizon(void* d) { return ((wb_ctx*) d)->st->n_stages; }

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
  memcpy(xk, c->x0 + c->st->x_offset[k], sizeof(double) * c->st->nx[k]);
  return 0;
}
static fatrop_int cb_initial_uk(double* uk, fatrop_int k, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  const double* u0 = c->x0 + c->st->x_offset[k] + c->st->nx[k];
  int i;
  for (i = 0; i < c->nur[k]; ++i) uk[i] = u0[c->rmap[c->rmap_i[k] + i]];
  return 0;
}

/* return 1: done, Fatrop skips its per-stage callbacks */
static fatrop_int cb_full_hess(double scale, const double* primal, const double* lam, const double* sp,
                               const double* gp, struct blasfeo_dmat* res, const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_begin(c, primal, lam, scale, s);
  c->job.m0 = res;
  wb_run_batches(c, wb_task_hess);
  wb_check_finite(c);
  return 1;
}

static fatrop_int cb_full_jac(const double* primal, const double* sp, const double* gp, struct blasfeo_dmat* BAbt,
                              struct blasfeo_dmat* Gg, struct blasfeo_dmat* Gg_ineq, const struct FatropOcpCDims* s,
                              void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_begin(c, primal, 0, 1.0, s);
  c->job.m0 = BAbt; c->job.m1 = Gg; c->job.m2 = Gg_ineq;
  wb_run_batches(c, wb_task_jac);
  wb_check_finite(c);
  memcpy(c->jac_primal, primal, sizeof(double) * c->n_fatrop); /* the fixed inputs' rows kept were there */
  c->has_jac = 1;
  return 1;
}

static fatrop_int cb_full_viol(const double* primal, const double* sp, const double* gp, double* res,
                               const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_begin(c, primal, 0, 1.0, s);
  c->job.out = res;
  wb_run(c, wb_task_viol);
  wb_check_finite(c);
  c->checked = 1; /* the start point's constraint values were finite */
  memcpy(c->last_primal, primal, sizeof(double) * c->n_fatrop);
  c->has_last = 1;
  return 1;
}

static fatrop_int cb_full_grad(double scale, const double* primal, const double* sp, const double* gp, double* res,
                               const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  wb_begin(c, primal, 0, scale, s);
  c->job.out = res;
  wb_run(c, wb_task_grad);
  wb_check_finite(c);
  memcpy(c->grad_primal, primal, sizeof(double) * c->n_fatrop);
  c->has_grad = 1;
  return 1;
}

/* the stage costs are cheap: evaluated in the caller, summed in stage order */
static fatrop_int cb_full_obj(double scale, const double* primal, const double* sp, const double* gp, double* res,
                              const struct FatropOcpCDims* s, void* d) {
  wb_ctx* c = (wb_ctx*) d;
  double total = 0;
  int k;
  wb_begin(c, primal, 0, scale, s);
  c->has_obj = 0;
  for (k = 0; k < c->st->n_stages; ++k) wb_task_cost(c, k, 0);
  for (k = 0; k < c->st->n_stages; ++k) total += c->stage_cost[k];
  *res = scale * total;
  memcpy(c->obj_primal, primal, sizeof(double) * c->n_fatrop); /* the solution's cost, when it was there */
  c->has_obj = 1;
  return 1;
}

void wb_fill_interface(struct FatropOcpCInterface* o, wb_ctx* c) {
  memset(o, 0, sizeof(*o));
  o->get_nx = cb_nx; o->get_nu = cb_nu; o->get_ng = cb_ng; o->get_ng_ineq = cb_ng_ineq;
  o->get_horizon_length = cb_horizon; o->get_bounds = cb_bounds;
  o->get_initial_xk = cb_initial_xk; o->get_initial_uk = cb_initial_uk;
  o->full_eval_lag_hess = cb_full_hess; o->full_eval_constr_jac = cb_full_jac;
  o->full_eval_contr_viol = cb_full_viol; o->full_eval_obj_grad = cb_full_grad; o->full_eval_obj = cb_full_obj;
  o->user_data = c;
}
