/* Shared between hpipm_shim.c (HPIPM instances, solve), hpipm_reduce.c (fixed inputs and x_0 eliminated) and
 * hpipm_eqelim.c (the active-set guess). */
#ifndef WBMPC_HPIPM_SHIM_H
#define WBMPC_HPIPM_SHIM_H

#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_ocp_qp_ipm.h"

/* one HPIPM instance, kept between calls for the sizes (and equality flags) it was built for: the shim's, and the
 * active-set guess's (`eq` NULL). Built by wbqp_inst_dim (then the dimensions set), wbqp_inst_memory (then the
 * arguments set), wbqp_inst_workspace; freed by wbqp_inst_release. */
typedef struct {
    int *dims;
    char *eq;  /* per stage, 1 where [u, x, g] of the reduced stage is a declared equality */
    unsigned long used;
    void *dim_mem, *qp_mem, *sol_mem, *arg_mem, *ws_mem;
    struct d_ocp_qp_dim dim;
    struct d_ocp_qp qp;
    struct d_ocp_qp_sol sol;
    struct d_ocp_qp_ipm_arg arg;
    struct d_ocp_qp_ipm_ws ws;
} wbqp_inst;

void wbqp_inst_dim(wbqp_inst *i, int N);
void wbqp_inst_memory(wbqp_inst *i);
void wbqp_inst_workspace(wbqp_inst *i);
void wbqp_inst_release(wbqp_inst *i);

/* one stage's QP data, column-major blocks: A (nx1 x nx), B (nx1 x nu), b, Q (nx x nx), S (nu x nx), R (nu x nu), q, r,
 * C (ng x nx), D (ng x nu), bounds lbu/ubu, lbx/ubx, lg/ug (+-inf or beyond `inf`: absent) */
typedef struct {
    const double *A, *B, *b, *Q, *S, *R, *q, *r, *C, *D, *lbu, *ubu, *lbx, *ubx, *lg, *ug;
} wbqp_stage;

/* one stage's solution: u, x, pi (nx1), lam = (upper - lower) multipliers of u, x and g */
typedef struct {
    double *u, *x, *pi, *lam_u, *lam_x, *lam_g;
} wbqp_stage_sol;

enum { WBQP_BLOCKS = 16, WBQP_SOLS = 6 };

/* The reduced QP: per stage the inputs with lb == ub (finite) are left out, their values folded into b, r, q and the
 * rows' bounds; x_0, where rows of stage 0 fix each of its components (the initial state), is left out of stage 0
 * (HPIPM's nx[0] = 0), its value folded into b_0, r_0 and the other rows' bounds. Buffers are the full QP's size. */
typedef struct {
    int N, *nx, *nu, *ng;               /* the full QP's sizes */
    int *rnx, *rnu, *rng;               /* the reduced QP's */
    int *offset;                        /* (N + 1) x WBQP_BLOCKS: each stage's start in the flat blocks (wbqp_stage order) */
    int *sol_offset;                    /* (N + 1) x WBQP_SOLS: its start in the flat solution (wbqp_stage_sol order) */
    int eliminate;                      /* 0: the reduced QP is the full one */
    double inf;
    int n_x0, *x0_row, *x0_col;         /* stage 0's rows fixing x_0: row (among stage 0's rows), component */
    char *is_x0_row;                    /* per row of stage 0 */
    int x0_out;                         /* this call: x_0 left out */
    double *x0;                         /* its value */
    int *free_u;                        /* per stage (at the stage's u offset): the kept inputs, then the fixed ones */
    double *fixed_u;                    /* per stage: the fixed inputs' values, 0 at free ones */
    int *kept_g;                        /* stage 0: the kept rows */
    double *blocks[WBQP_BLOCKS];        /* the reduced blocks, at the full QP's offsets (one allocation) */
    double *sols[WBQP_SOLS];            /* the reduced solution, at the full solution's offsets (one allocation) */
    double *work;                       /* a stage's full-width scratch vector */
} wbqp_reduction;

int wbqp_reduction_init(wbqp_reduction *r, int N, const int *nx, const int *nu, const int *ng, double inf,
                        int eliminate, int n_x0, const int *x0_row, const int *x0_col);
void wbqp_reduction_free(wbqp_reduction *r);
/* stage k of flat data (wbqp_stage order, each array flat in stage order) */
wbqp_stage wbqp_stage_at(const wbqp_reduction *r, const double *const *flat, int k);
wbqp_stage_sol wbqp_sol_at(const wbqp_reduction *r, double *const *flat, int k);
/* the reduced QP of this call's bounds: sizes in rnx/rnu/rng, stage k's data in `out[k]` */
void wbqp_reduce(wbqp_reduction *r, const double *const *full, wbqp_stage *out);
/* the full solution from the reduced one (`reduced[k]`), the fixed inputs' and x_0 rows' multipliers from stationarity */
void wbqp_expand(wbqp_reduction *r, const double *const *full, const wbqp_stage_sol *reduced, double *const *sol);

/* The active-set guess "no inequality active" (hpipm_eqelim.c): the reduced QP's inequalities dropped, its equality
 * rows eliminated, one Riccati factorisation. 0: solved (reduced solution, multipliers included, in sol[k]); 1: an
 * inequality is violated (the guess is wrong); 2: rows the elimination does not handle; 3: HPIPM or the equality
 * residual (> tol) failed. */
typedef struct wbqp_eqelim wbqp_eqelim;
wbqp_eqelim *wbqp_eqelim_new(const wbqp_reduction *r);
void wbqp_eqelim_free(wbqp_eqelim *e);
int wbqp_eqelim_solve(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, wbqp_stage_sol *sol, double tol);

#endif
