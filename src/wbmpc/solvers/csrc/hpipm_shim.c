/* A thin C layer between our stage-wise QP (solvers/hpipm_direct.py) and HPIPM's OCP QP interface.
 *
 * casadi's conic('hpipm') boxes every variable and keeps every row with infinite bounds replaced by
 * +-1e8 (dummy constraints the interior point iterates on), passes equality rows as two inequalities
 * and allocates HPIPM's memory in every call. Here: every bound side that is infinite is masked out
 * (HPIPM's constraint masks), rows and bounds with lb == ub are declared equalities (idxe), the
 * memory is kept between calls and rebuilt only when the pattern of equalities changes (contact
 * switches). Data are dense column-major blocks per stage, flat in stage order (sizes in `wbqp_new`).
 * Inputs with lb == ub and x_0 fixed by its initial-state rows are left out of HPIPM's QP (hpipm_reduce.c): the
 * reduced QP's sizes change with the contact schedule, so HPIPM's instances are kept per size pattern (a small cache,
 * the least recently used one rebuilt; gaits are periodic).
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_ocp_qp_ipm.h"

#include "hpipm_shim.h"

#define WBQP_CACHE 48  /* HPIPM instances kept (b1_z1's trot at 80 Hz: ~40 size patterns a gait cycle) */
#define GUESS_SKIP 8   /* calls without the active-set guess after it failed (an active set persists for a while) */


typedef struct {
    wbqp_reduction red;
    int N, mode, iter_max, warm_start, declare_equalities, n_all, n_cached, rebuilds;
    double mu0, tol, inf;
    unsigned long clock;
    wbqp_inst cache[WBQP_CACHE];
    int *key_dims;  /* this call's reduced sizes (rnx, rnu, rng) and equality flags */
    char *key_eq;
    int **idxbu, **idxbx, **idxe, *idx_store;
    double *mask, *zeros, *lb, *ub;
    wbqp_stage *stages;
    wbqp_stage_sol *reduced;
    double res[4];
    int iter, status;
    wbqp_eqelim *eq;           /* the active-set guess (hpipm_eqelim.c), NULL: off */
    int guess_skip, guess_tries, guess_hits, guess_last;
} wbqp;

void wbqp_inst_release(wbqp_inst *i) {
    free(i->dim_mem); free(i->qp_mem); free(i->sol_mem); free(i->arg_mem); free(i->ws_mem); free(i->dims); free(i->eq);
    memset(i, 0, sizeof(*i));
}

void wbqp_inst_dim(wbqp_inst *i, int N) {
    i->dim_mem = malloc(d_ocp_qp_dim_memsize(N));
    d_ocp_qp_dim_create(N, &i->dim, i->dim_mem);
}

void wbqp_inst_memory(wbqp_inst *i) {
    i->qp_mem = malloc(d_ocp_qp_memsize(&i->dim));
    d_ocp_qp_create(&i->dim, &i->qp, i->qp_mem);
    i->sol_mem = malloc(d_ocp_qp_sol_memsize(&i->dim));
    d_ocp_qp_sol_create(&i->dim, &i->sol, i->sol_mem);
    i->arg_mem = malloc(d_ocp_qp_ipm_arg_memsize(&i->dim));
    d_ocp_qp_ipm_arg_create(&i->dim, &i->arg, i->arg_mem);
}

void wbqp_inst_workspace(wbqp_inst *i) {
    i->ws_mem = malloc(d_ocp_qp_ipm_ws_memsize(&i->dim, &i->arg));
    d_ocp_qp_ipm_ws_create(&i->dim, &i->arg, &i->ws, i->ws_mem);
}

static void index_lists(wbqp *s, const int *nx, const int *nu, const int *ng) {
    int k, i, *p = s->idx_store;
    for (k = 0; k <= s->N; k++) {
        s->idxbu[k] = p; for (i = 0; i < nu[k]; i++) p[i] = i; p += nu[k];
        s->idxbx[k] = p; for (i = 0; i < nx[k]; i++) p[i] = i; p += nx[k];
        s->idxe[k] = p; p += nu[k] + nx[k] + ng[k];
    }
}

/* x0_row / x0_col: stage 0's rows fixing x_0 (row among stage 0's rows, component), n_x0 of them (0: none);
 * eliminate: leave inputs with lb == ub and such an x_0 out of HPIPM's QP */
void *wbqp_new(int N, const int *nx, const int *nu, const int *ng, int mode, int iter_max, double mu0,
               double tol, int warm_start, double inf, int declare_equalities, int eliminate, int n_x0,
               const int *x0_row, const int *x0_col) {
    wbqp *s = calloc(1, sizeof(wbqp));
    int k, total = 0, widest = 0;
    if (!s || !wbqp_reduction_init(&s->red, N, nx, nu, ng, inf, eliminate, n_x0, x0_row, x0_col)) { free(s); return NULL; }
    s->N = N; s->mode = mode; s->iter_max = iter_max; s->mu0 = mu0; s->tol = tol; s->warm_start = warm_start;
    s->inf = inf; s->declare_equalities = declare_equalities;
    for (k = 0; k <= N; k++) {
        int n = nu[k] + nx[k] + ng[k];
        total += n;
        if (n > widest) widest = n;
    }
    s->n_all = total;
    s->key_dims = calloc(3 * (N + 1), sizeof(int));
    s->key_eq = calloc(total + 1, 1);
    s->idxbu = malloc(3 * (N + 1) * sizeof(int *)); s->idxbx = s->idxbu + N + 1; s->idxe = s->idxbx + N + 1;
    s->idx_store = malloc((3 * total + 1) * sizeof(int));
    index_lists(s, nx, nu, ng);
    s->mask = malloc(2 * widest * sizeof(double));
    s->zeros = calloc(widest + 1, sizeof(double));
    s->lb = malloc(widest * sizeof(double));
    s->ub = malloc(widest * sizeof(double));
    s->stages = malloc((N + 1) * sizeof(wbqp_stage));
    s->reduced = malloc((N + 1) * sizeof(wbqp_stage_sol));
    return s;
}

void wbqp_free(void *handle) {
    wbqp *s = handle;
    int i;
    if (!s) return;
    for (i = 0; i < s->n_cached; i++) wbqp_inst_release(&s->cache[i]);
    wbqp_reduction_free(&s->red);
    wbqp_eqelim_free(s->eq);
    free(s->key_dims); free(s->key_eq); free(s->idxbu); free(s->idx_store); free(s->mask); free(s->zeros);
    free(s->lb); free(s->ub); free(s->stages); free(s->reduced);
    free(s);
}

static int n_flags(const wbqp *s, const int *dims) {
    int k, n = 0;
    for (k = 0; k < 3 * (s->N + 1); k++) n += dims[k];
    return n;
}

static void set_arguments(wbqp *s, wbqp_inst *i) {
    int one = 1;
    d_ocp_qp_ipm_arg_set_default((enum hpipm_mode) s->mode, &i->arg);
    d_ocp_qp_ipm_arg_set_iter_max(&s->iter_max, &i->arg);
    d_ocp_qp_ipm_arg_set_mu0(&s->mu0, &i->arg);
    d_ocp_qp_ipm_arg_set_tol_stat(&s->tol, &i->arg);
    d_ocp_qp_ipm_arg_set_tol_eq(&s->tol, &i->arg);
    d_ocp_qp_ipm_arg_set_tol_ineq(&s->tol, &i->arg);
    d_ocp_qp_ipm_arg_set_tol_comp(&s->tol, &i->arg);
    d_ocp_qp_ipm_arg_set_warm_start(&s->warm_start, &i->arg);
    /* the absolute formulation (speed_abs) skips the equality multipliers unless asked: the SQP needs them */
    d_ocp_qp_ipm_arg_set_comp_dual_sol_eq(&one, &i->arg);
    d_ocp_qp_ipm_arg_set_comp_res_exit(&one, &i->arg);
}

/* an HPIPM instance for this call's key (sizes and equality flags) into `i` */
static void build(wbqp *s, wbqp_inst *i) {
    int N = s->N, k, offset = 0, n = n_flags(s, s->key_dims);
    int *nx = s->key_dims, *nu = nx + N + 1, *ng = nu + N + 1, *ns = calloc(N + 1, sizeof(int));
    i->dims = malloc(3 * (N + 1) * sizeof(int)); memcpy(i->dims, s->key_dims, 3 * (N + 1) * sizeof(int));
    i->eq = malloc(n + 1); memcpy(i->eq, s->key_eq, n);
    wbqp_inst_dim(i, N);
    d_ocp_qp_dim_set_all(nx, nu, nx, nu, ng, ns, &i->dim);
    for (k = 0; k <= N; k++) {
        int j, counts[3] = {0, 0, 0};
        for (j = 0; j < nu[k] + nx[k] + ng[k]; j++)
            if (i->eq[offset + j]) counts[j < nu[k] ? 0 : j < nu[k] + nx[k] ? 1 : 2]++;
        d_ocp_qp_dim_set_nbue(k, counts[0], &i->dim);
        d_ocp_qp_dim_set_nbxe(k, counts[1], &i->dim);
        d_ocp_qp_dim_set_nge(k, counts[2], &i->dim);
        offset += nu[k] + nx[k] + ng[k];
    }
    wbqp_inst_memory(i);
    set_arguments(s, i);
    wbqp_inst_workspace(i);
    free(ns);
    s->rebuilds++;
}

/* this call's key: the reduced sizes and, where equalities are declared, which bounds and rows have lb == ub */
static void make_key(wbqp *s) {
    int N = s->N, k, i, offset = 0;
    const wbqp_reduction *r = &s->red;
    memcpy(s->key_dims, r->rnx, (N + 1) * sizeof(int));
    memcpy(s->key_dims + N + 1, r->rnu, (N + 1) * sizeof(int));
    memcpy(s->key_dims + 2 * (N + 1), r->rng, (N + 1) * sizeof(int));
    for (k = 0; k <= N; k++) {
        const wbqp_stage *d = &s->stages[k];
        const double *lower[3] = {d->lbu, d->lbx, d->lg}, *upper[3] = {d->ubu, d->ubx, d->ug};
        int sizes[3] = {r->rnu[k], r->rnx[k], r->rng[k]}, part;
        for (part = 0; part < 3; part++)
            for (i = 0; i < sizes[part]; i++, offset++)
                s->key_eq[offset] = s->declare_equalities && lower[part][i] == upper[part][i] &&
                                    fabs(lower[part][i]) < s->inf;
    }
}

/* the cached instance of this call's key, else a new one (in place of the least recently used one) */
static wbqp_inst *instance(wbqp *s) {
    int i, n_dims = 3 * (s->N + 1), n, oldest = 0;
    make_key(s);
    n = n_flags(s, s->key_dims);
    for (i = 0; i < s->n_cached; i++) {
        wbqp_inst *c = &s->cache[i];
        if (!memcmp(c->dims, s->key_dims, n_dims * sizeof(int)) && !memcmp(c->eq, s->key_eq, n)) {
            c->used = ++s->clock;
            return c;
        }
        if (c->used < s->cache[oldest].used) oldest = i;
    }
    i = s->n_cached < WBQP_CACHE ? s->n_cached++ : oldest;
    wbqp_inst_release(&s->cache[i]);
    build(s, &s->cache[i]);
    s->cache[i].used = ++s->clock;
    return &s->cache[i];
}

/* bounds clipped to +-inf, with masks: 0 where a side is absent */
#define BOUNDS(n, lo, hi, set_lo, set_hi, set_lo_mask, set_hi_mask) \
    for (j = 0; j < (n); j++) { \
        double l = (lo)[j], h = (hi)[j]; \
        s->mask[j] = l > -inf; s->mask[(n) + j] = h < inf; \
        s->lb[j] = s->mask[j] ? l : -inf; s->ub[j] = s->mask[(n) + j] ? h : inf; \
    } \
    set_lo(k, s->lb, qp); set_hi(k, s->ub, qp); \
    set_lo_mask(k, s->mask, qp); set_hi_mask(k, s->mask + (n), qp);

/* stage k's blocks, bounds and equalities into the instance's QP; `offset`: the stage's start in its flags */
static void set_stage(wbqp *s, wbqp_inst *in, int k, const wbqp_stage *d, int offset) {
    int N = s->N, nx = in->dims[k], nu = in->dims[N + 1 + k], ng = in->dims[2 * (N + 1) + k], ne = 0, j;
    struct d_ocp_qp *qp = &in->qp;
    const double inf = s->inf;
    if (k < N) {
        d_ocp_qp_set_A(k, (double *) d->A, qp);
        d_ocp_qp_set_B(k, (double *) d->B, qp);
        d_ocp_qp_set_b(k, (double *) d->b, qp);
    }
    d_ocp_qp_set_Q(k, (double *) d->Q, qp);
    d_ocp_qp_set_S(k, (double *) d->S, qp);
    d_ocp_qp_set_R(k, (double *) d->R, qp);
    d_ocp_qp_set_q(k, (double *) d->q, qp);
    d_ocp_qp_set_r(k, (double *) d->r, qp);
    d_ocp_qp_set_C(k, (double *) d->C, qp);
    d_ocp_qp_set_D(k, (double *) d->D, qp);
    d_ocp_qp_set_idxbu(k, s->idxbu[k], qp);
    d_ocp_qp_set_idxbx(k, s->idxbx[k], qp);
    BOUNDS(nu, d->lbu, d->ubu, d_ocp_qp_set_lbu, d_ocp_qp_set_ubu, d_ocp_qp_set_lbu_mask, d_ocp_qp_set_ubu_mask)
    BOUNDS(nx, d->lbx, d->ubx, d_ocp_qp_set_lbx, d_ocp_qp_set_ubx, d_ocp_qp_set_lbx_mask, d_ocp_qp_set_ubx_mask)
    if (ng > 0) {
        BOUNDS(ng, d->lg, d->ug, d_ocp_qp_set_lg, d_ocp_qp_set_ug, d_ocp_qp_set_lg_mask, d_ocp_qp_set_ug_mask)
    }
    for (j = 0; j < nu + nx + ng; j++)
        if (in->eq[offset + j]) s->idxe[k][ne++] = j;
    if (ne > 0) d_ocp_qp_set_idxe(k, s->idxe[k], qp);
}
#undef BOUNDS

/* the instance's solution into stage k's reduced solution (wbqp_stage_sol) */
static void get_solution(wbqp *s, wbqp_inst *in, int k, wbqp_stage_sol *o) {
    int N = s->N, nx = in->dims[k], nu = in->dims[N + 1 + k], ng = in->dims[2 * (N + 1) + k], j;
    struct d_ocp_qp_sol *sol = &in->sol;
    d_ocp_qp_sol_get_u(k, sol, o->u);
    d_ocp_qp_sol_get_x(k, sol, o->x);
    if (k < N) d_ocp_qp_sol_get_pi(k, sol, o->pi);
    d_ocp_qp_sol_get_lam_lbu(k, sol, s->lb); d_ocp_qp_sol_get_lam_ubu(k, sol, s->ub);
    for (j = 0; j < nu; j++) o->lam_u[j] = s->ub[j] - s->lb[j];
    d_ocp_qp_sol_get_lam_lbx(k, sol, s->lb); d_ocp_qp_sol_get_lam_ubx(k, sol, s->ub);
    for (j = 0; j < nx; j++) o->lam_x[j] = s->ub[j] - s->lb[j];
    if (ng > 0) {
        d_ocp_qp_sol_get_lam_lg(k, sol, s->lb); d_ocp_qp_sol_get_lam_ug(k, sol, s->ub);
        for (j = 0; j < ng; j++) o->lam_g[j] = s->ub[j] - s->lb[j];
    }
}

static void read_status(wbqp *s, wbqp_inst *in) {
    d_ocp_qp_ipm_get_status(&in->ws, &s->status);
    d_ocp_qp_ipm_get_iter(&in->ws, &s->iter);
    d_ocp_qp_ipm_get_max_res_stat(&in->ws, &s->res[0]);
    d_ocp_qp_ipm_get_max_res_eq(&in->ws, &s->res[1]);
    d_ocp_qp_ipm_get_max_res_ineq(&in->ws, &s->res[2]);
    d_ocp_qp_ipm_get_max_res_comp(&in->ws, &s->res[3]);
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
    const double *full[WBQP_BLOCKS] = {A, B, b, Q, S, R, q, r, C, D, lbu, ubu, lbx, ubx, lg, ug};
    double *sol[WBQP_SOLS] = {u, x, pi, lam_u, lam_x, lam_g};
    wbqp_inst *in;
    int k, offset = 0, N = s->N;
    wbqp_reduce(&s->red, full, s->stages);
    s->guess_last = -1;
    if (s->eq && s->guess_skip > 0) s->guess_skip--;
    else if (s->eq) {  /* one factorisation where no inequality is active; the interior point where one is */
        for (k = 0; k <= N; k++) s->reduced[k] = wbqp_sol_at(&s->red, s->red.sols, k);
        s->guess_tries++;
        s->guess_last = wbqp_eqelim_solve(s->eq, &s->red, s->stages, s->reduced, s->tol);
        if (s->guess_last == 0) {
            s->guess_hits++;
            s->status = 0; s->iter = 1; memset(s->res, 0, sizeof(s->res));
            wbqp_expand(&s->red, full, s->reduced, sol);
            return 0;
        }
        s->guess_skip = GUESS_SKIP;
    }
    in = instance(s);
    for (k = 0; k <= N; k++) {
        set_stage(s, in, k, &s->stages[k], offset);
        offset += in->dims[k] + in->dims[N + 1 + k] + in->dims[2 * (N + 1) + k];
    }
    /* primal guess: zero (the linearisation point) */
    for (k = 0; k <= N; k++) {
        d_ocp_qp_sol_set_u(k, s->zeros, &in->sol);
        d_ocp_qp_sol_set_x(k, s->zeros, &in->sol);
    }
    d_ocp_qp_ipm_solve(&in->qp, &in->sol, &in->arg, &in->ws);
    read_status(s, in);
    for (k = 0; k <= N; k++) {
        s->reduced[k] = wbqp_sol_at(&s->red, s->red.sols, k);
        get_solution(s, in, k, &s->reduced[k]);
    }
    wbqp_expand(&s->red, full, s->reduced, sol);
    return s->status;
}

int wbqp_iterations(void *handle) { return ((wbqp *) handle)->iter; }
/* the active-set guess on (1) or off (0) */
int wbqp_set_guess(void *handle, int on) {
    wbqp *s = handle;
    if (on && !s->eq) s->eq = wbqp_eqelim_new(&s->red);
    if (!on && s->eq) { wbqp_eqelim_free(s->eq); s->eq = NULL; }
    s->guess_skip = 0;
    return on ? s->eq != NULL : 1;
}
/* tries, hits and the last call's outcome (-1: not tried, else wbqp_eqelim_solve's code) of the guess */
void wbqp_guess_stats(void *handle, int *out) {
    wbqp *s = handle;
    out[0] = s->guess_tries; out[1] = s->guess_hits; out[2] = s->guess_last;
}
void wbqp_residuals(void *handle, double *out) { memcpy(out, ((wbqp *) handle)->res, 4 * sizeof(double)); }
/* the sizes of the last call's QP as HPIPM solved it: nx, nu, ng per stage (3 (N + 1) ints) */
void wbqp_sizes(void *handle, int *out) {
    wbqp *s = handle;
    memcpy(out, s->key_dims, 3 * (s->N + 1) * sizeof(int));
}
/* HPIPM instances built so far (a new size or equality pattern not in the cache) */
int wbqp_rebuilds(void *handle) { return ((wbqp *) handle)->rebuilds; }
