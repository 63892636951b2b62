/* A thin C layer between our stage-wise QP (solvers/hpipm_direct.py) and HPIPM's OCP QP interface.
 *
 * casadi's conic('hpipm') boxes every variable and keeps every row with infinite bounds replaced by
 * +-1e8 (dummy constraints the interior point iterates on), passes equality rows as two inequalities
 * and allocates HPIPM's memory in every call. Here: every bound side that is infinite is masked out
 * (HPIPM's constraint masks), rows and bounds with lb == ub are declared equalities (idxe), the
 * memory is kept between calls and rebuilt only when the pattern of equalities changes (contact
 * switches). Data are dense column-major blocks per stage, flat in stage order (sizes in `wbqp_new`).
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_ocp_qp_ipm.h"

typedef struct {
    int N, *nx, *nu, *ng;
    int mode, iter_max, warm_start, declare_equalities;
    double mu0, tol, inf;
    /* current HPIPM instance and the equality pattern it was built for (per stage: nbue, nbxe, nge + flags) */
    int built;
    char *eq_pattern;  /* length n_all: 1 where [u, x, g] of a stage is an equality */
    int n_all;
    void *dim_mem, *qp_mem, *sol_mem, *arg_mem, *ws_mem;
    struct d_ocp_qp_dim dim;
    struct d_ocp_qp qp;
    struct d_ocp_qp_sol sol;
    struct d_ocp_qp_ipm_arg arg;
    struct d_ocp_qp_ipm_ws ws;
    int **idxbu, **idxbx, **idxe;
    int *idx_store;
    double *mask, *zeros, *lb, *ub;  /* work vectors */
    double res[4];
    int iter, status;
} wbqp;

static void release(wbqp *s) {
    free(s->dim_mem); free(s->qp_mem); free(s->sol_mem); free(s->arg_mem); free(s->ws_mem);
    s->dim_mem = s->qp_mem = s->sol_mem = s->arg_mem = s->ws_mem = NULL;
    s->built = 0;
}

void *wbqp_new(int N, const int *nx, const int *nu, const int *ng, int mode, int iter_max, double mu0,
               double tol, int warm_start, double inf, int declare_equalities) {
    wbqp *s = calloc(1, sizeof(wbqp));
    int k, total = 0, widest = 0;
    s->N = N;
    s->nx = malloc((N + 1) * sizeof(int)); s->nu = malloc((N + 1) * sizeof(int)); s->ng = malloc((N + 1) * sizeof(int));
    memcpy(s->nx, nx, (N + 1) * sizeof(int)); memcpy(s->nu, nu, (N + 1) * sizeof(int)); memcpy(s->ng, ng, (N + 1) * sizeof(int));
    s->mode = mode; s->iter_max = iter_max; s->mu0 = mu0; s->tol = tol; s->warm_start = warm_start; s->inf = inf;
    s->declare_equalities = declare_equalities;
    for (k = 0; k <= N; k++) {
        int n = nu[k] + nx[k] + ng[k];
        total += n;
        if (n > widest) widest = n;
    }
    s->n_all = total;
    s->eq_pattern = calloc(total, 1);
    s->idxbu = malloc((N + 1) * sizeof(int *)); s->idxbx = malloc((N + 1) * sizeof(int *)); s->idxe = malloc((N + 1) * sizeof(int *));
    s->idx_store = malloc(3 * total * sizeof(int));
    {
        int *p = s->idx_store;
        for (k = 0; k <= N; k++) {
            int i;
            s->idxbu[k] = p; for (i = 0; i < nu[k]; i++) p[i] = i; p += nu[k];
            s->idxbx[k] = p; for (i = 0; i < nx[k]; i++) p[i] = i; p += nx[k];
            s->idxe[k] = p; p += nu[k] + nx[k] + ng[k];
        }
    }
    s->mask = malloc(2 * widest * sizeof(double));
    s->zeros = calloc(widest, sizeof(double));
    s->lb = malloc(widest * sizeof(double));
    s->ub = malloc(widest * sizeof(double));
    return s;
}

void wbqp_free(void *handle) {
    wbqp *s = handle;
    if (!s) return;
    release(s);
    free(s->nx); free(s->nu); free(s->ng); free(s->eq_pattern); free(s->idxbu); free(s->idxbx); free(s->idxe);
    free(s->idx_store); free(s->mask); free(s->zeros); free(s->lb); free(s->ub);
    free(s);
}

static void build(wbqp *s) {
    int N = s->N, k, offset = 0;
    int *nbu = malloc((N + 1) * sizeof(int)), *nbx = malloc((N + 1) * sizeof(int)), *ns = calloc(N + 1, sizeof(int));
    release(s);
    for (k = 0; k <= N; k++) { nbu[k] = s->nu[k]; nbx[k] = s->nx[k]; }
    s->dim_mem = malloc(d_ocp_qp_dim_memsize(N));
    d_ocp_qp_dim_create(N, &s->dim, s->dim_mem);
    d_ocp_qp_dim_set_all(s->nx, s->nu, nbx, nbu, s->ng, ns, &s->dim);
    for (k = 0; k <= N; k++) {
        int i, nbue = 0, nbxe = 0, nge = 0, n = s->nu[k] + s->nx[k] + s->ng[k];
        for (i = 0; i < n; i++) {
            if (!s->eq_pattern[offset + i]) continue;
            if (i < s->nu[k]) nbue++; else if (i < s->nu[k] + s->nx[k]) nbxe++; else nge++;
        }
        d_ocp_qp_dim_set_nbue(k, nbue, &s->dim);
        d_ocp_qp_dim_set_nbxe(k, nbxe, &s->dim);
        d_ocp_qp_dim_set_nge(k, nge, &s->dim);
        offset += n;
    }
    s->qp_mem = malloc(d_ocp_qp_memsize(&s->dim));
    d_ocp_qp_create(&s->dim, &s->qp, s->qp_mem);
    s->sol_mem = malloc(d_ocp_qp_sol_memsize(&s->dim));
    d_ocp_qp_sol_create(&s->dim, &s->sol, s->sol_mem);
    s->arg_mem = malloc(d_ocp_qp_ipm_arg_memsize(&s->dim));
    d_ocp_qp_ipm_arg_create(&s->dim, &s->arg, s->arg_mem);
    d_ocp_qp_ipm_arg_set_default((enum hpipm_mode) s->mode, &s->arg);
    d_ocp_qp_ipm_arg_set_iter_max(&s->iter_max, &s->arg);
    d_ocp_qp_ipm_arg_set_mu0(&s->mu0, &s->arg);
    d_ocp_qp_ipm_arg_set_tol_stat(&s->tol, &s->arg);
    d_ocp_qp_ipm_arg_set_tol_eq(&s->tol, &s->arg);
    d_ocp_qp_ipm_arg_set_tol_ineq(&s->tol, &s->arg);
    d_ocp_qp_ipm_arg_set_tol_comp(&s->tol, &s->arg);
    d_ocp_qp_ipm_arg_set_warm_start(&s->warm_start, &s->arg);
    {   /* the absolute formulation (speed_abs) skips the equality multipliers unless asked: the SQP needs them */
        int one = 1;
        d_ocp_qp_ipm_arg_set_comp_dual_sol_eq(&one, &s->arg);
        d_ocp_qp_ipm_arg_set_comp_res_exit(&one, &s->arg);
    }
    s->ws_mem = malloc(d_ocp_qp_ipm_ws_memsize(&s->dim, &s->arg));
    d_ocp_qp_ipm_ws_create(&s->dim, &s->arg, &s->ws, s->ws_mem);
    free(nbu); free(nbx); free(ns);
    s->built = 1;
}

/* whether the equality pattern of these bounds differs from the one HPIPM was built for (it is updated) */
static int update_pattern(wbqp *s, const double *lbu, const double *ubu, const double *lbx, const double *ubx,
                          const double *lg, const double *ug) {
    const double *pl[3] = {lbu, lbx, lg}, *pu[3] = {ubu, ubx, ug};
    int o[3] = {0, 0, 0}, k, i, offset = 0, changed = !s->built;
    for (k = 0; k <= s->N; k++) {
        int sizes[3] = {s->nu[k], s->nx[k], s->ng[k]}, part, j = 0;
        for (part = 0; part < 3; part++) {
            for (i = 0; i < sizes[part]; i++, j++) {
                double lo = pl[part][o[part] + i], hi = pu[part][o[part] + i];
                char eq = s->declare_equalities && lo == hi && fabs(lo) < s->inf;
                if (s->eq_pattern[offset + j] != eq) { s->eq_pattern[offset + j] = eq; changed = 1; }
            }
            o[part] += sizes[part];
        }
        offset += j;
    }
    return changed;
}

/* the QP's data, read stage after stage (each pointer moves past its stage's block) */
typedef struct {
    const double *A, *B, *b, *Q, *S, *R, *q, *r, *C, *D, *lbu, *ubu, *lbx, *ubx, *lg, *ug;
} qp_data;

/* bounds clipped to +-inf, with masks: 0 where a side is absent */
#define BOUNDS(n, lo, hi, set_lo, set_hi, set_lo_mask, set_hi_mask) \
    for (j = 0; j < (n); j++) { \
        double l = (lo)[j], h = (hi)[j]; \
        s->mask[j] = l > -inf; s->mask[(n) + j] = h < inf; \
        s->lb[j] = s->mask[j] ? l : -inf; s->ub[j] = s->mask[(n) + j] ? h : inf; \
    } \
    set_lo(k, s->lb, &s->qp); set_hi(k, s->ub, &s->qp); \
    set_lo_mask(k, s->mask, &s->qp); set_hi_mask(k, s->mask + (n), &s->qp);

/* stage k's blocks, bounds and equalities into HPIPM's QP; `offset`: the stage's start in eq_pattern */
static void set_stage(wbqp *s, int k, qp_data *d, int offset) {
    int nx = s->nx[k], nu = s->nu[k], ng = s->ng[k], ne = 0, j;
    const double inf = s->inf;
    if (k < s->N) {
        int nx1 = s->nx[k + 1];
        d_ocp_qp_set_A(k, (double *) d->A, &s->qp); d->A += nx1 * nx;
        d_ocp_qp_set_B(k, (double *) d->B, &s->qp); d->B += nx1 * nu;
        d_ocp_qp_set_b(k, (double *) d->b, &s->qp); d->b += nx1;
    }
    d_ocp_qp_set_Q(k, (double *) d->Q, &s->qp); d->Q += nx * nx;
    d_ocp_qp_set_S(k, (double *) d->S, &s->qp); d->S += nu * nx;
    d_ocp_qp_set_R(k, (double *) d->R, &s->qp); d->R += nu * nu;
    d_ocp_qp_set_q(k, (double *) d->q, &s->qp); d->q += nx;
    d_ocp_qp_set_r(k, (double *) d->r, &s->qp); d->r += nu;
    d_ocp_qp_set_C(k, (double *) d->C, &s->qp); d->C += ng * nx;
    d_ocp_qp_set_D(k, (double *) d->D, &s->qp); d->D += ng * nu;
    d_ocp_qp_set_idxbu(k, s->idxbu[k], &s->qp);
    d_ocp_qp_set_idxbx(k, s->idxbx[k], &s->qp);
    BOUNDS(nu, d->lbu, d->ubu, d_ocp_qp_set_lbu, d_ocp_qp_set_ubu, d_ocp_qp_set_lbu_mask, d_ocp_qp_set_ubu_mask)
    BOUNDS(nx, d->lbx, d->ubx, d_ocp_qp_set_lbx, d_ocp_qp_set_ubx, d_ocp_qp_set_lbx_mask, d_ocp_qp_set_ubx_mask)
    if (ng > 0) {
        BOUNDS(ng, d->lg, d->ug, d_ocp_qp_set_lg, d_ocp_qp_set_ug, d_ocp_qp_set_lg_mask, d_ocp_qp_set_ug_mask)
    }
    for (j = 0; j < nu + nx + ng; j++)
        if (s->eq_pattern[offset + j]) s->idxe[k][ne++] = j;
    if (ne > 0) d_ocp_qp_set_idxe(k, s->idxe[k], &s->qp);
    d->lbu += nu; d->ubu += nu; d->lbx += nx; d->ubx += nx; d->lg += ng; d->ug += ng;
}
#undef BOUNDS

/* the solution: u, x, pi (nx[k+1] per k < N) and the (upper - lower) multipliers of u, x and g per stage */
static void get_solution(wbqp *s, double *u, double *x, double *pi, double *lam_u, double *lam_x, double *lam_g) {
    int k, j;
    for (k = 0; k <= s->N; k++) {
        int nx = s->nx[k], nu = s->nu[k], ng = s->ng[k];
        d_ocp_qp_sol_get_u(k, &s->sol, u); u += nu;
        d_ocp_qp_sol_get_x(k, &s->sol, x); x += nx;
        if (k < s->N) { d_ocp_qp_sol_get_pi(k, &s->sol, pi); pi += s->nx[k + 1]; }
        d_ocp_qp_sol_get_lam_lbu(k, &s->sol, s->lb); d_ocp_qp_sol_get_lam_ubu(k, &s->sol, s->ub);
        for (j = 0; j < nu; j++) lam_u[j] = s->ub[j] - s->lb[j];
        lam_u += nu;
        d_ocp_qp_sol_get_lam_lbx(k, &s->sol, s->lb); d_ocp_qp_sol_get_lam_ubx(k, &s->sol, s->ub);
        for (j = 0; j < nx; j++) lam_x[j] = s->ub[j] - s->lb[j];
        lam_x += nx;
        if (ng > 0) {
            d_ocp_qp_sol_get_lam_lg(k, &s->sol, s->lb); d_ocp_qp_sol_get_lam_ug(k, &s->sol, s->ub);
            for (j = 0; j < ng; j++) lam_g[j] = s->ub[j] - s->lb[j];
            lam_g += ng;
        }
    }
}

/* Solve. Blocks flat in stage order, column-major: A_k (nx[k+1] x nx[k]), B_k (nx[k+1] x nu[k]), b_k, Q_k (nx x nx),
 * S_k (nu x nx), R_k (nu x nu), q_k, r_k, C_k (ng x nx), D_k (ng x nu); bounds lbu/ubu, lbx/ubx, lg/ug per stage
 * (+-inf or beyond `inf`: absent). Outputs u, x, pi (nx[k+1] per k < N), lam = (upper - lower) multipliers of
 * u, x and g per stage. Returns HPIPM's status (0 solved, 1 iteration cap, 2 minimum step, 3 NaN). */
int wbqp_solve(void *handle, const double *A, const double *B, const double *b, const double *Q, const double *S,
               const double *R, const double *q, const double *r, const double *C, const double *D,
               const double *lbu, const double *ubu, const double *lbx, const double *ubx,
               const double *lg, const double *ug, double *u, double *x, double *pi, double *lam_u, double *lam_x,
               double *lam_g) {
    wbqp *s = handle;
    qp_data d = {A, B, b, Q, S, R, q, r, C, D, lbu, ubu, lbx, ubx, lg, ug};
    int k, offset = 0;
    if (update_pattern(s, lbu, ubu, lbx, ubx, lg, ug)) build(s);
    for (k = 0; k <= s->N; k++) {
        set_stage(s, k, &d, offset);
        offset += s->nu[k] + s->nx[k] + s->ng[k];
    }
    /* primal guess: zero (the linearisation point) */
    for (k = 0; k <= s->N; k++) {
        d_ocp_qp_sol_set_u(k, s->zeros, &s->sol);
        d_ocp_qp_sol_set_x(k, s->zeros, &s->sol);
    }
    d_ocp_qp_ipm_solve(&s->qp, &s->sol, &s->arg, &s->ws);
    d_ocp_qp_ipm_get_status(&s->ws, &s->status);
    d_ocp_qp_ipm_get_iter(&s->ws, &s->iter);
    d_ocp_qp_ipm_get_max_res_stat(&s->ws, &s->res[0]);
    d_ocp_qp_ipm_get_max_res_eq(&s->ws, &s->res[1]);
    d_ocp_qp_ipm_get_max_res_ineq(&s->ws, &s->res[2]);
    d_ocp_qp_ipm_get_max_res_comp(&s->ws, &s->res[3]);
    get_solution(s, u, x, pi, lam_u, lam_x, lam_g);
    return s->status;
}

int wbqp_iterations(void *handle) { return ((wbqp *) handle)->iter; }
void wbqp_residuals(void *handle, double *out) { memcpy(out, ((wbqp *) handle)->res, 4 * sizeof(double)); }
