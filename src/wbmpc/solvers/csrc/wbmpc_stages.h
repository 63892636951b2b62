/* The stage functions of one OCP, compiled from CasADi's generated C (solvers/stage_library.py writes the
 * tables below next to that code and compiles both into one library). The Fatrop shim (fatrop_shim.c)
 * is compiled once per machine and reads a problem only through this description. */
#ifndef WBMPC_STAGES_H
#define WBMPC_STAGES_H

#ifdef __cplusplus
extern "C" {
#endif

/* CasADi's calling convention (casadi_real double, casadi_int long long int: CasADi's defaults) */
typedef int (*wb_fn)(const double** arg, double** res, long long int* iw, double* w, int mem);

/* the five functions of a stage kind, inputs (u_k, x_k, p_k, ...) in Fatrop's order, dense outputs:
   hess (u, x, p, sigma, lam_dyn, lam_rows) -> Lagrangian Hessian in (u, x);
   jac (u, x, p) -> (d f / d(u, x))', (d r / d(u, x))';  val -> f, r;  grad -> d l / d(u, x);  cost -> l */
enum { WB_HESS = 0, WB_JAC, WB_VAL, WB_GRAD, WB_COST, WB_N_FUNCTIONS };

#define WB_STAGES_VERSION 1

typedef struct {
  int version;       /* WB_STAGES_VERSION of the header the tables were compiled with */
  int n_stages;      /* K = N + 1 */
  int n_params;      /* parameters per stage (rows of the (K, n_params) stage parameter array) */
  int n_variables;   /* of the NLP (x0, u0, x1, u1, ..., xN) */
  int n_constraints; /* of the NLP (gap rows x_{k+1} - f, then each stage's path rows) */
  int n_kinds;
  const int* kind;       /* stage -> kind */
  const int* nx;         /* states of stage k */
  const int* nu;         /* inputs of stage k */
  const int* nr;         /* path rows of stage k */
  const int* x_offset;   /* first NLP variable of stage k (x_k, then u_k) */
  const int* row_offset; /* first NLP path row of stage k */
  const int* gap_offset; /* first gap row of stage k (-1 on the last) */
  const wb_fn* functions; /* kind * WB_N_FUNCTIONS + function */
  int sz_arg, sz_res, sz_iw, sz_w; /* largest work sizes over the functions */
  int max_n;             /* largest nu + nx */
  int max_x;             /* largest nx */
  int max_rows;          /* largest nr (>= 1) */
} wb_stages;

#ifdef __cplusplus
}
#endif
#endif
