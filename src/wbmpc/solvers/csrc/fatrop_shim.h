/* Shared declarations of the Fatrop shim's C files (fatrop_shim.c: context and exported API,
 * fatrop_callbacks.c: Fatrop's OCP callbacks, stage_tasks.c: the per-stage evaluations run by the pool). */
#ifndef WBMPC_FATROP_SHIM_H
#define WBMPC_FATROP_SHIM_H

#include <blasfeo.h>
#include <fatrop/ocp/OCPCInterface.h>

#include "stage_pool.h"
#include "wbmpc_stages.h"

/* the C++ driver (fatrop_driver.cpp) */
void wb_throw(const char* what); /* throws std::runtime_error: unwinds to wbd_solve, which returns -1 */
void* wbd_create(void* ocp);
void wbd_destroy(void* d);
int wbd_option_double(void* d, const char* name, double value);
int wbd_option_int(void* d, const char* name, int value);
int wbd_option_bool(void* d, const char* name, int value);
int wbd_solve(void* d, int warm, double z_floor);
void wbd_forget(void* d);
double* wbd_given(void* d, int which, int* sizes);
const double* wbd_primal(void* d);
const double* wbd_dual(void* d);
const void* wbd_dims(void* d);
const void* wbd_stats(void* d);

/* one thread's work memory for the generated functions and its per-stage scratch */
typedef struct {
  const double** arg;
  double** res;
  long long int* iw;
  double* w;
  /* lam_rows, ufull: one block per lane of the kinds' lane functions (stride: the largest stage's size) */
  double *hess, *jac_next, *jac_rows, *f, *r, *lam_rows;
  double *ufull, *compact, *col; /* a stage's whole u; blocks of Fatrop's (free u, x) rows; one column */
  int* cols;                     /* the columns a block selects */
  int last_kind[WB_N_FUNCTIONS]; /* the stage kind this thread last evaluated each function of (-1: none) */
  /* per kind with lane functions: its lanes' output buffers (hess, jac_next, jac_rows: L blocks each, stride the
     largest stage's size; NULL for other kinds) and which lanes' buffers hold its outputs (bit l of
     lane_held[kind * WB_N_LANE_FUNCTIONS + function]): only the nonzeros are written, their zeros stay */
  double **lane_hess, **lane_jac_next, **lane_jac_rows;
  int* lane_held;
  double *cover_lam, *cover_rows; /* a covered kind's stage: its own row multipliers, its rows from the cover's */
} wb_work;

/* the evaluation a pool job runs on every stage (see stage_tasks.c) */
typedef struct {
  const double* primal;                /* Fatrop's (u_k, x_k) per stage, or the NLP's x (nlp_layout) */
  const double* lam;                   /* Fatrop's multipliers (Hessian) */
  double scale;                        /* objective scale (Hessian, gradient) */
  const struct FatropOcpCDims* dims;   /* Fatrop's offsets (NULL: the NLP's layout) */
  struct blasfeo_dmat *m0, *m1, *m2;   /* BLASFEO blocks per stage: RSQrqt or (BAbt, Ggt, Ggt_ineq) */
  double* out;                         /* flat outputs (violation, gradient, g) */
  int check_finite;                    /* flag non-finite values (the solve's first evaluations) */
  int cache_only;                      /* Jacobian / gradient: only the eliminated inputs' rows (multipliers) */
} wb_job;

typedef struct {
  const wb_stages* st;    /* = &stages */
  wb_stages stages;       /* the problem (layout arrays owned by the context) */
  const double *P, *lbx, *ubx, *lbg, *ubg, *x0;
  /* each stage's constraint rows and variables by class (equality, inequality), in NLP order; *_i: K + 1 starts */
  int *a_eq, *a_ineq, *x_eq, *x_ineq;
  int *a_eq_i, *a_ineq_i, *x_eq_i, *x_ineq_i;
  /* inputs with lb == ub are eliminated: Fatrop sees the free inputs u_free of each stage (nur of them) and x */
  int eliminate;             /* 0: fixed inputs stay variables with equality rows, as in casadi's plugin */
  int* nur;
  int *u_fixed, *u_fixed_i;  /* each stage's fixed inputs (positions in u), K + 1 starts */
  int *rmap, *rmap_i;        /* Fatrop's stage position in (u_free, x) -> position in (u, x); K + 1 starts */
  int* red_pos;              /* NLP variable -> its position in Fatrop's (u_free, x) of its stage, -1 if fixed */
  int *run_src, *run_dst, *run_len, *run_i; /* rmap as runs of consecutive positions; K + 1 starts */
  int n_fatrop;              /* length of Fatrop's primal vector */
  /* the fixed inputs' rows of (d f)' | (d r)' and gradient entries at the last evaluations (their multipliers) */
  double *fix_jac, *fix_grad, *jac_primal, *grad_primal, *obj_primal;
  int* fix_i;                /* K + 1 starts into fix_jac (fix_grad: u_fixed_i) */
  int has_jac, has_grad, has_obj;
  double* zeros;          /* max_x zeros: the last stage's dynamics multipliers */
  int* p_index;           /* n_stages x n_params: stage k's parameters' positions in the NLP's p (wb_ctx_parameters) */
  int n_p;                /* length of the NLP's p */
  double *P_out, *x_out, *lam_g_out, *lam_x_out, *stats_out; /* wb_solve's outputs (wb_ctx_outputs) */
  double* stage_cost;     /* per stage, of the last cost evaluation */
  double* stage_f;        /* K * max_x: f of the last violation evaluation, per stage */
  double* stage_r;        /* K * max_rows: r of the same */
  double* last_primal;    /* where that evaluation was (Fatrop's layout); has_last: valid */
  int has_last;
  /* the Hessian's and Jacobian's tasks: batches of stages of one kind evaluated in one call of its lane functions
     (stage_tasks.c), in order of their first stage; batch b holds stages batch_k[batch_i[b] .. batch_i[b + 1] - 1] */
  int n_batches;
  int *batch_i, *batch_k;
  wb_work* work;          /* one per thread: the caller's first */
  int n_work;
  wb_pool* pool;
  wb_job job;
  double t_functions;     /* s in the stage evaluations since the solve started (wall) */
  double deadline;        /* CLOCK_MONOTONIC s; 0: none */
  int deadline_hit, nonfinite_hit, checked;
} wb_ctx;

/* stage_layout.c */
void wb_classify(wb_ctx* c);
void wb_batches(wb_ctx* c);
const double* wb_full_inputs(const wb_ctx* c, double* ufull, int k, const double* u_free);
const double* wb_reduce_square(const wb_ctx* c, wb_work* w, int k, const double* A, int n);
const double* wb_reduce_rows(const wb_ctx* c, wb_work* w, int k, const double* A, int n, int n_cols, const int* cols);
void wb_keep_fixed_rows(wb_ctx* c, int k, const double* jac_next, const double* jac_rows, int n);
void wb_fixed_multipliers(const wb_ctx* c, const double* dual, const struct FatropOcpCDims* dims,
                          const double* lam_g, double* lam_x);

/* stage_tasks.c */
double wb_now(void);
int wb_pack_ready(void);
void wb_run(wb_ctx* c, wb_task_fn task);
void wb_run_batches(wb_ctx* c, wb_task_fn task);
int wb_kind_lanes(const wb_stages* st, int kind);
void wb_task_hess(void* job, int batch, int worker);
void wb_task_jac(void* job, int batch, int worker);
void wb_task_viol(void* job, int k, int worker);
void wb_task_grad(void* job, int k, int worker);
void wb_task_cost(void* job, int k, int worker);
void wb_task_nlp_g(void* job, int k, int worker);
void wb_task_warm(void* job, int k, int worker);
void wb_task_derivatives(void* job, int k, int worker);

/* fatrop_callbacks.c */
void wb_fill_interface(struct FatropOcpCInterface* o, wb_ctx* c);
fatrop_int wb_n_eq(wb_ctx* c, fatrop_int k);
fatrop_int wb_n_ineq(wb_ctx* c, fatrop_int k);

#endif
