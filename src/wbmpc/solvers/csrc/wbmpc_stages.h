/* The stage functions of an OCP, compiled from CasADi's generated C (solvers/stage_library.py writes the table of
 * the stage kinds below next to that code and compiles both into one library). The Fatrop shim (fatrop_shim.c) is
 * compiled once per machine and reads a problem only through this table and the stage layout it is given
 * (wb_ctx_new): the library depends on the kinds of stages only, not on how many there are. */
#ifndef WBMPC_STAGES_H
#define WBMPC_STAGES_H

#ifdef __cplusplus
extern "C" {
#endif

/* CasADi's calling convention (casadi_real double, casadi_int long long int: CasADi's defaults) */
typedef int (*wb_fn)(const double** arg, double** res, long long int* iw, double* w, int mem);

/* the five functions of a stage kind, inputs (u_k, x_k, p_k, ...) in Fatrop's order, dense column-major outputs
   (every output pointer given: the generated code writes without null checks):
   hess (u, x, p, sigma, lam_dyn, lam_rows) -> Lagrangian Hessian in (u, x);
   jac (u, x, p) -> (d f / d(u, x))', (d r / d(u, x))';  val -> f, r;  grad -> d l / d(u, x);  cost -> l */
enum { WB_HESS = 0, WB_JAC, WB_VAL, WB_GRAD, WB_COST, WB_N_FUNCTIONS };

/* a kind's Hessian or Jacobian on `lanes` stages at once (solvers/stage_vectors.py): input i of stage l at
   arg[i * lanes + l], output i at res[i * lanes + l]; unused lanes repeat a used lane's pointers. Only the outputs'
   structural nonzeros are written, after clearing the outputs of the lanes l with bit l of `clear` set (a lane's
   buffers that hold this function's last outputs need no clearing: the same places are written) */
typedef int (*wb_lane_fn)(const double** arg, double** res, int clear);
/* a kind whose Hessian and Jacobian are another kind's (solvers/stage_covers.py): its row multipliers as the
   cover's, and its transposed row Jacobian from the cover's */
typedef struct {
  int cover; /* the kind whose code runs; -1: the kind's own */
  int cover_rows;
  void (*lam)(const double* lam, double* cover_lam);
  void (*rows)(const double* cover_rows, double* rows);
} wb_cover;
enum { WB_LANE_HESS = 0, WB_LANE_JAC, WB_N_LANE_FUNCTIONS };
#define WB_MAX_LANES 8

#define WB_KINDS_VERSION 3

/* what the stage library exports (wbmpc_stage_kinds()) */
typedef struct {
  int version;            /* WB_KINDS_VERSION of the header the library was compiled with */
  int n_kinds;
  const wb_fn* functions; /* kind * WB_N_FUNCTIONS + function */
  int sz_arg, sz_res, sz_iw, sz_w; /* largest work sizes over the functions */
  /* [2 * (kind * WB_N_FUNCTIONS + function)] and [... + 1]: the first and the past-the-end byte of each function's
     generated machine code (0, 0 where unknown), prefetched before a kind's first call (stage_tasks.c) */
  const char* const* code;
  int lanes;                        /* stages per lane function call (1: none) */
  const wb_lane_fn* lane_functions; /* kind * WB_N_LANE_FUNCTIONS + WB_LANE_*: NULL where a kind has none */
  const wb_cover* covers;           /* per kind */
} wb_kinds;

/* a problem: its stage kinds and the layout of its stages (the shim's copy) */
typedef struct {
  const wb_kinds* kinds;
  int n_stages;      /* K = N + 1 */
  int n_params;      /* parameters per stage (rows of the (K, n_params) stage parameter array) */
  int n_variables;   /* of the NLP (x0, u0, x1, u1, ..., xN) */
  int n_constraints; /* of the NLP (gap rows x_{k+1} - f, then each stage's path rows) */
  int *kind;         /* stage -> kind */
  int *nx, *nu, *nr; /* states, inputs and path rows of stage k */
  int* x_offset;     /* first NLP variable of stage k (x_k, then u_k) */
  int* row_offset;   /* first NLP path row of stage k */
  int* gap_offset;   /* first gap row of stage k (-1 on the last) */
  const wb_fn* functions;
  const char* const* code; /* the kinds' code ranges (wb_kinds.code) */
  int lanes;
  const wb_lane_fn* lane_functions;
  const wb_cover* covers;
  int sz_arg, sz_res, sz_iw, sz_w;
  int max_n, max_x, max_rows; /* largest nu + nx, nx, nr (>= 1) */
} wb_stages;

/* the layout's rows in wb_ctx_new's table (WB_LAYOUT_ROWS x n_stages ints, row-major) */
enum { WB_L_KIND = 0, WB_L_NX, WB_L_NU, WB_L_NR, WB_L_X_OFFSET, WB_L_ROW_OFFSET, WB_L_GAP_OFFSET, WB_LAYOUT_ROWS };

#ifdef __cplusplus
}
#endif
#endif
