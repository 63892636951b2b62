/* Fixed inputs and the initial state left out of HPIPM's QP (see hpipm_shim.h's wbqp_reduction).
 *
 * An input with lb == ub (a swing foot's force, the arm's commanded force) is a known value: HPIPM's Riccati recursion
 * need not carry it, and as a box with lb == ub its interior-point slacks start at zero. Its columns are folded into
 * b (B c), r (R c), q (S' c) and the rows' bounds (D c); x_0, fixed by stage 0's initial-state rows, likewise into b_0
 * (A x_0), r_0 (S x_0) and the other rows' bounds (C x_0), HPIPM's stage 0 then having nx = 0. The solution is the same
 * QP's; the left-out multipliers follow from the stationarity of the full stage (HPIPM's sign convention):
 *     R u + S x + r + lam_u + D' lam_g + B' pi_k = 0,   Q x_0 + S' u_0 + q_0 + lam_x + C' lam_g + A' pi_0 = 0.
 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "hpipm_shim.h"

enum { A_, B_, b_, Q_, S_, R_, q_, r_, C_, D_, lbu_, ubu_, lbx_, ubx_, lg_, ug_ };
enum { u_, x_, pi_, lam_u_, lam_x_, lam_g_ };

static void stage_sizes(const wbqp_reduction *r, int k, int *sizes, int *sol_sizes) {
    int nx = r->nx[k], nu = r->nu[k], ng = r->ng[k], nx1 = k < r->N ? r->nx[k + 1] : 0;
    int s[WBQP_BLOCKS] = {nx1 * nx, nx1 * nu, nx1, nx * nx, nu * nx, nu * nu, nx, nu, ng * nx, ng * nu,
                          nu, nu, nx, nx, ng, ng};
    int t[WBQP_SOLS] = {nu, nx, nx1, nu, nx, ng};
    memcpy(sizes, s, sizeof(s));
    memcpy(sol_sizes, t, sizeof(t));
}

int wbqp_reduction_init(wbqp_reduction *r, int N, const int *nx, const int *nu, const int *ng, double inf,
                        int eliminate, int n_x0, const int *x0_row, const int *x0_col) {
    int k, j, total[WBQP_BLOCKS] = {0}, sol_total[WBQP_SOLS] = {0}, n_block = 0, n_sol = 0, widest = 0;
    memset(r, 0, sizeof(*r));
    r->N = N; r->inf = inf; r->eliminate = eliminate;
    r->nx = malloc(6 * (N + 1) * sizeof(int));
    r->nu = r->nx + N + 1; r->ng = r->nu + N + 1; r->rnx = r->ng + N + 1; r->rnu = r->rnx + N + 1; r->rng = r->rnu + N + 1;
    memcpy(r->nx, nx, (N + 1) * sizeof(int)); memcpy(r->nu, nu, (N + 1) * sizeof(int));
    memcpy(r->ng, ng, (N + 1) * sizeof(int));
    r->offset = malloc((N + 1) * (WBQP_BLOCKS + WBQP_SOLS) * sizeof(int));
    r->sol_offset = r->offset + (N + 1) * WBQP_BLOCKS;
    for (k = 0; k <= N; k++) {
        int sizes[WBQP_BLOCKS], sol_sizes[WBQP_SOLS];
        stage_sizes(r, k, sizes, sol_sizes);
        for (j = 0; j < WBQP_BLOCKS; j++) { r->offset[k * WBQP_BLOCKS + j] = total[j]; total[j] += sizes[j]; }
        for (j = 0; j < WBQP_SOLS; j++) { r->sol_offset[k * WBQP_SOLS + j] = sol_total[j]; sol_total[j] += sol_sizes[j]; }
        if (nx[k] + nu[k] + ng[k] > widest) widest = nx[k] + nu[k] + ng[k];
    }
    for (j = 0; j < WBQP_BLOCKS; j++) n_block += total[j];
    for (j = 0; j < WBQP_SOLS; j++) n_sol += sol_total[j];
    r->blocks[0] = malloc((n_block + n_sol + 2 * widest + nx[0] + total[lbu_]) * sizeof(double));
    for (j = 1; j < WBQP_BLOCKS; j++) r->blocks[j] = r->blocks[j - 1] + total[j - 1];
    r->sols[0] = r->blocks[WBQP_BLOCKS - 1] + total[WBQP_BLOCKS - 1];
    for (j = 1; j < WBQP_SOLS; j++) r->sols[j] = r->sols[j - 1] + sol_total[j - 1];
    r->work = r->sols[WBQP_SOLS - 1] + sol_total[WBQP_SOLS - 1];
    r->x0 = r->work + 2 * widest;
    r->fixed_u = r->x0 + nx[0];
    r->free_u = malloc((total[lbu_] + ng[0] + n_x0 * 2 + 1) * sizeof(int));
    r->kept_g = r->free_u + total[lbu_];
    r->x0_row = r->kept_g + ng[0]; r->x0_col = r->x0_row + n_x0;
    r->is_x0_row = calloc(ng[0] + 1, 1);
    {   /* the initial-state rows are used only where they fix each component of x_0 once */
        char *seen = calloc(nx[0] + 1, 1);
        int ok = n_x0 == nx[0];
        for (j = 0; ok && j < n_x0; j++) {
            ok = x0_row[j] >= 0 && x0_row[j] < ng[0] && x0_col[j] >= 0 && x0_col[j] < nx[0] && !seen[x0_col[j]];
            if (ok) seen[x0_col[j]] = 1;
        }
        free(seen);
        r->n_x0 = ok ? n_x0 : 0;
        for (j = 0; j < r->n_x0; j++) { r->x0_row[j] = x0_row[j]; r->x0_col[j] = x0_col[j]; r->is_x0_row[x0_row[j]] = 1; }
    }
    return r->nx && r->offset && r->blocks[0] && r->free_u && r->is_x0_row;
}

void wbqp_reduction_free(wbqp_reduction *r) {
    free(r->nx); free(r->offset); free(r->blocks[0]); free(r->free_u); free(r->is_x0_row);
    memset(r, 0, sizeof(*r));
}

wbqp_stage wbqp_stage_at(const wbqp_reduction *r, const double *const *flat, int k) {
    const int *o = r->offset + k * WBQP_BLOCKS;
    wbqp_stage s = {flat[A_] + o[A_], flat[B_] + o[B_], flat[b_] + o[b_], flat[Q_] + o[Q_], flat[S_] + o[S_],
                    flat[R_] + o[R_], flat[q_] + o[q_], flat[r_] + o[r_], flat[C_] + o[C_], flat[D_] + o[D_],
                    flat[lbu_] + o[lbu_], flat[ubu_] + o[ubu_], flat[lbx_] + o[lbx_], flat[ubx_] + o[ubx_],
                    flat[lg_] + o[lg_], flat[ug_] + o[ug_]};
    return s;
}

wbqp_stage_sol wbqp_sol_at(const wbqp_reduction *r, double *const *flat, int k) {
    const int *o = r->sol_offset + k * WBQP_SOLS;
    wbqp_stage_sol s = {flat[u_] + o[u_], flat[x_] + o[x_], flat[pi_] + o[pi_], flat[lam_u_] + o[lam_u_],
                        flat[lam_x_] + o[lam_x_], flat[lam_g_] + o[lam_g_]};
    return s;
}

static int is_fixed(const wbqp_reduction *r, double lower, double upper) {
    return lower == upper && fabs(lower) < r->inf;
}

/* stage k's kept inputs then fixed ones (free_u) and the fixed values (fixed_u, 0 at kept ones); the kept count */
static int classify_inputs(wbqp_reduction *r, int k, const wbqp_stage *f) {
    int i, n = 0, nu = r->nu[k], o = r->offset[k * WBQP_BLOCKS + lbu_], last = o + nu;
    for (i = 0; i < nu; i++) {
        int fixed = r->eliminate && is_fixed(r, f->lbu[i], f->ubu[i]);
        r->fixed_u[o + i] = fixed ? f->lbu[i] : 0.0;
        if (fixed) r->free_u[--last] = i;
        else r->free_u[o + n++] = i;
    }
    return n;
}

/* whether stage 0's initial-state rows fix x_0 in this call (equal finite bounds, unit rows, no bounds on x_0 itself);
 * its value into r->x0 */
static int initial_state_fixed(wbqp_reduction *r, const wbqp_stage *f) {
    int nx = r->nx[0], ng = r->ng[0], i, j;
    if (!r->eliminate || r->n_x0 == 0) return 0;
    for (i = 0; i < nx; i++)
        if (f->lbx[i] > -r->inf || f->ubx[i] < r->inf) return 0;
    for (i = 0; i < r->n_x0; i++) {
        int row = r->x0_row[i], col = r->x0_col[i];
        double a = f->C[row + col * ng];
        if (!is_fixed(r, f->lg[row], f->ug[row]) || a == 0.0) return 0;
        for (j = 0; j < nx; j++)
            if (j != col && f->C[row + j * ng] != 0.0) return 0;
        for (j = 0; j < r->nu[0]; j++)
            if (f->D[row + j * ng] != 0.0) return 0;
        r->x0[col] = f->lg[row] / a;
    }
    return 1;
}

static double *block(wbqp_reduction *r, int part, int k) { return r->blocks[part] + r->offset[k * WBQP_BLOCKS + part]; }

static void axpy(int n, double alpha, const double *x, double *y) {
    int i;
    if (alpha != 0.0)
        for (i = 0; i < n; i++) y[i] += alpha * x[i];
}

/* y = M[:, cols] v (M: m rows, column-major), or all columns where cols is NULL */
static void gemv_cols(int m, int n, const double *M, const double *v, double *y) {
    int j;
    for (j = 0; j < n; j++) axpy(m, v[j], M + j * m, y);
}

/* y += M[:, fixed] c[fixed] (M: m rows, column-major): the fixed inputs' share, fixed = free_u's tail */
static void add_fixed_columns(const wbqp_reduction *r, int k, int m, const double *M, double *y) {
    int o = r->offset[k * WBQP_BLOCKS + lbu_], j;
    for (j = r->rnu[k]; j < r->nu[k]; j++) {
        int i = r->free_u[o + j];
        axpy(m, r->fixed_u[o + i], M + i * m, y);
    }
}

/* the dynamics of the reduced stage k: B's kept columns, b + B c (+ A x_0) */
static void reduce_dynamics(wbqp_reduction *r, int k, const wbqp_stage *f, wbqp_stage *o, int drop_x) {
    int nx1 = r->nx[k + 1], j;
    const int *kept = r->free_u + r->offset[k * WBQP_BLOCKS + lbu_];
    double *B = block(r, B_, k), *b = block(r, b_, k);
    for (j = 0; j < r->rnu[k]; j++) memcpy(B + j * nx1, f->B + kept[j] * nx1, nx1 * sizeof(double));
    memcpy(b, f->b, nx1 * sizeof(double));
    add_fixed_columns(r, k, nx1, f->B, b);
    if (drop_x) gemv_cols(nx1, r->nx[k], f->A, r->x0, b);
    o->B = B; o->b = b;
}

/* the reduced cost: R and S at the kept inputs, r + R c (+ S x_0), q + S' c */
static void reduce_cost(wbqp_reduction *r, int k, const wbqp_stage *f, wbqp_stage *o, int drop_x) {
    int nx = r->nx[k], nu = r->nu[k], n = r->rnu[k], i, j;
    const int *kept = r->free_u + r->offset[k * WBQP_BLOCKS + lbu_];
    const double *c = r->fixed_u + r->offset[k * WBQP_BLOCKS + lbu_];
    double *R = block(r, R_, k), *S = block(r, S_, k), *rr = block(r, r_, k), *q = block(r, q_, k);
    double *full_r = r->work, *bounds = block(r, lbu_, k), *upper = block(r, ubu_, k);
    memcpy(full_r, f->r, nu * sizeof(double));
    add_fixed_columns(r, k, nu, f->R, full_r);
    if (drop_x) gemv_cols(nu, nx, f->S, r->x0, full_r);
    for (j = 0; j < n; j++) {
        rr[j] = full_r[kept[j]]; bounds[j] = f->lbu[kept[j]]; upper[j] = f->ubu[kept[j]];
        for (i = 0; i < n; i++) R[i + j * n] = f->R[kept[i] + kept[j] * nu];
    }
    if (!drop_x) {
        for (j = 0; j < nx; j++) {
            for (i = 0; i < n; i++) S[i + j * n] = f->S[kept[i] + j * nu];
            q[j] = f->q[j];
            for (i = n; i < nu; i++) q[j] += c[kept[i]] * f->S[kept[i] + j * nu];
        }
        o->q = q;
    }
    o->R = R; o->S = S; o->r = rr; o->lbu = bounds; o->ubu = upper;
}

/* the reduced rows: D's kept columns, bounds shifted by D c (+ C x_0); stage 0 without x_0 drops its initial-state rows
 * (and C: the reduced stage has no state) */
static void reduce_rows(wbqp_reduction *r, int k, const wbqp_stage *f, wbqp_stage *o, int drop_x) {
    int ng = r->ng[k], n = r->rnu[k], m = 0, i, j;
    int rows = ng - (drop_x ? r->n_x0 : 0);
    const int *kept = r->free_u + r->offset[k * WBQP_BLOCKS + lbu_];
    double *D = block(r, D_, k), *lg = block(r, lg_, k), *ug = block(r, ug_, k), *shift = r->work;
    memset(shift, 0, ng * sizeof(double));
    add_fixed_columns(r, k, ng, f->D, shift);
    if (drop_x) gemv_cols(ng, r->nx[k], f->C, r->x0, shift);
    for (i = 0; i < ng; i++) {
        if (drop_x && r->is_x0_row[i]) continue;
        if (drop_x) r->kept_g[m] = i;
        lg[m] = f->lg[i] > -r->inf ? f->lg[i] - shift[i] : f->lg[i];
        ug[m] = f->ug[i] < r->inf ? f->ug[i] - shift[i] : f->ug[i];
        if (drop_x)
            for (j = 0; j < n; j++) D[m + j * rows] = f->D[i + kept[j] * ng];
        m++;
    }
    if (!drop_x)  /* all rows kept: whole columns */
        for (j = 0; j < n; j++) memcpy(D + j * ng, f->D + kept[j] * ng, ng * sizeof(double));
    r->rng[k] = m;
    o->D = D; o->lg = lg; o->ug = ug;
}

void wbqp_reduce(wbqp_reduction *r, const double *const *full, wbqp_stage *out) {
    int k;
    r->x0_out = 0;
    for (k = 0; k <= r->N; k++) {
        wbqp_stage f = wbqp_stage_at(r, full, k);
        int drop_x = k == 0 && (r->x0_out = initial_state_fixed(r, &f));
        out[k] = f;
        r->rnu[k] = classify_inputs(r, k, &f);
        r->rnx[k] = drop_x ? 0 : r->nx[k];
        r->rng[k] = r->ng[k];
        if (r->rnu[k] == r->nu[k] && !drop_x) continue;
        if (k < r->N) reduce_dynamics(r, k, &f, &out[k], drop_x);
        reduce_cost(r, k, &f, &out[k], drop_x);
        reduce_rows(r, k, &f, &out[k], drop_x);
    }
}

/* stage k's full u, x, pi and lam_g (the initial-state rows' multipliers still 0) from the reduced solution */
static void expand_primal(wbqp_reduction *r, int k, const wbqp_stage_sol *red, wbqp_stage_sol *s, int drop_x) {
    int nu = r->nu[k], nx = r->nx[k], ng = r->ng[k], nx1 = k < r->N ? r->nx[k + 1] : 0, j;
    const int *kept = r->free_u + r->offset[k * WBQP_BLOCKS + lbu_];
    memcpy(s->u, r->fixed_u + r->offset[k * WBQP_BLOCKS + lbu_], nu * sizeof(double));
    memset(s->lam_u, 0, nu * sizeof(double));
    for (j = 0; j < r->rnu[k]; j++) { s->u[kept[j]] = red->u[j]; s->lam_u[kept[j]] = red->lam_u[j]; }
    memcpy(s->x, drop_x ? r->x0 : red->x, nx * sizeof(double));
    if (drop_x) memset(s->lam_x, 0, nx * sizeof(double));
    else memcpy(s->lam_x, red->lam_x, nx * sizeof(double));
    memcpy(s->pi, red->pi, nx1 * sizeof(double));
    if (!drop_x) { memcpy(s->lam_g, red->lam_g, ng * sizeof(double)); return; }
    memset(s->lam_g, 0, ng * sizeof(double));
    for (j = 0; j < r->rng[k]; j++) s->lam_g[r->kept_g[j]] = red->lam_g[j];
}

static double dot(int n, const double *x, const double *y) {
    double sum = 0.0;
    int i;
    for (i = 0; i < n; i++) sum += x[i] * y[i];
    return sum;
}

/* the fixed inputs' multipliers from their stationarity (R symmetric: its row i is its column i) */
static void fixed_multipliers(const wbqp_reduction *r, int k, const wbqp_stage *f, wbqp_stage_sol *s) {
    int nu = r->nu[k], nx = r->nx[k], ng = r->ng[k], nx1 = k < r->N ? r->nx[k + 1] : 0, j, l;
    const int *order = r->free_u + r->offset[k * WBQP_BLOCKS + lbu_];
    for (j = r->rnu[k]; j < nu; j++) {
        int i = order[j];
        double v = f->r[i] + dot(nu, f->R + i * nu, s->u) + dot(ng, f->D + i * ng, s->lam_g) +
                   dot(nx1, f->B + i * nx1, s->pi);
        for (l = 0; l < nx; l++) v += f->S[i + l * nu] * s->x[l];
        s->lam_u[i] = -v;
    }
}

/* the initial-state rows' multipliers from x_0's stationarity (its own bounds are infinite: lam_x = 0) */
static void initial_state_multipliers(wbqp_reduction *r, const wbqp_stage *f, wbqp_stage_sol *s) {
    int nu = r->nu[0], nx = r->nx[0], ng = r->ng[0], nx1 = r->N > 0 ? r->nx[1] : 0, i, j;
    double *v = r->work;
    for (j = 0; j < nx; j++) {
        v[j] = f->q[j] + dot(nx, f->Q + j * nx, s->x) + dot(nu, f->S + j * nu, s->u) + dot(ng, f->C + j * ng, s->lam_g) +
               dot(nx1, f->A + j * nx1, s->pi);
    }
    for (i = 0; i < r->n_x0; i++) {
        int row = r->x0_row[i], col = r->x0_col[i];
        s->lam_g[row] = -v[col] / f->C[row + col * ng];
    }
}

void wbqp_expand(wbqp_reduction *r, const double *const *full, const wbqp_stage_sol *reduced, double *const *sol) {
    int k;
    for (k = 0; k <= r->N; k++) {
        wbqp_stage f = wbqp_stage_at(r, full, k);
        wbqp_stage_sol s = wbqp_sol_at(r, sol, k);
        int drop_x = k == 0 && r->x0_out;
        expand_primal(r, k, &reduced[k], &s, drop_x);
        fixed_multipliers(r, k, &f, &s);
        if (drop_x) initial_state_multipliers(r, &f, &s);
    }
}
