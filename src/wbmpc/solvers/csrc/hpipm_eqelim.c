/* The active-set guess of the RTI's QP: no inequality active (hpipm_shim.h's wbqp_eqelim_solve; docs/design/rti.md).
 * HPIPM's interior point iterates on the equality rows (inequalities with lb == ub to it) even where no inequality is
 * active (b1_z1's trot: every QP). Here the inequalities are dropped and the equality rows eliminated:
 *   - stage k's equality rows with inputs and stage k+1's rows on the state alone, moved onto stage k through the
 *     dynamics (c' x_{k+1} = c' (A x + B u + b)), form G_x x + G_u u = e; Gauss-Jordan elimination with partial pivoting
 *     picks pivot inputs, u_P = X x + Y w + z, the other inputs w free (b1_z1: 28 -> 11 a stage);
 *   - HPIPM without constraints solves the QP of (x, w): one factorisation; the inputs follow;
 *   - the dropped inequalities are checked (one violated: the guess is wrong, the caller runs the interior point);
 *   - the equality rows' multipliers follow backwards from u_k's stationarity, with pi_{k-1} = Q x + S' u + q + C' lam
 *     + A' pi_k: G_u' lam = -(R u + S x + r + B' pi_known), solved on the pivots (G_P' lam = rhs_P).
 * Rows on x_0 alone are refused unless x_0 is out of the QP (then they are constants, checked). */
#pragma GCC optimize("O3,associative-math,no-signed-zeros,no-trapping-math")  /* the project's flags stop at -O2 */
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_sol.h"
#include "hpipm_d_ocp_qp_ipm.h"
#include "blasfeo_d_aux.h"
#include "blasfeo_d_blas.h"
#include "hpipm_shim.h"

#define EQ_CACHE 48
#define PIVOT_RATIO 1e-9  /* a pivot below this fraction of G_u's largest entry: rank deficient, no guess */


typedef struct {
    int m, nf, *rows, *piv, *free;  /* rows: stage k's equality rows with inputs (>= 0) then k+1's on x (-1 - row) */
    double *X, *Y, *z, *Ginv;       /* u_P = X x + Y w + z (X: m x nx, Y: m x nf); G_P^{-1} (m x m) */
    double *A, *B, *b, *Q, *S, *R, *q, *r;  /* the stage of (x, w) */
    double *w;
} eq_stage;

struct wbqp_eqelim {
    int N, n_cached, widest, *key;
    unsigned long clock;
    eq_stage *st;
    wbqp_inst cache[EQ_CACHE];
    double *G, *work, *work2, *pi_known;
    char *pure;  /* per stage and row: an equality row on the state alone */
    void *blasfeo_mem;  /* BLASFEO's panel-major matrices of the two large products in `transform` */
    struct blasfeo_dmat sRP, sX, sS, sA2, sB2, sQ, sC1, sAB, sPr, sY, sSF;
    double *gather;
};

wbqp_eqelim *wbqp_eqelim_new(const wbqp_reduction *r) {
    int N = r->N, k, w = 0, mmax = 0;
    wbqp_eqelim *e = calloc(1, sizeof(wbqp_eqelim));
    if (!e) return NULL;
    e->N = N;
    e->st = calloc(N + 1, sizeof(eq_stage));
    e->key = calloc(2 * (N + 1), sizeof(int));
    if (!e->st || !e->key) { free(e->st); free(e->key); free(e); return NULL; }
    for (k = 0; k <= N; k++) {
        int nx = r->nx[k], nu = r->nu[k], nx1 = k < N ? r->nx[k + 1] : 0, m = r->ng[k] + (k < N ? r->ng[k + 1] : 0);
        eq_stage *s = &e->st[k];
        if (nx + nu + r->ng[k] + nx1 > w) w = nx + nu + r->ng[k] + nx1;
        if (m > mmax) mmax = m;
        s->rows = malloc((m + 2 * nu + 1) * sizeof(int)); s->piv = s->rows + m; s->free = s->piv + nu;
        s->X = malloc((m * nx + m * nu + m + m * m + nx1 * nx + nx1 * nu + nx1 + nx * nx + nu * nx + nu * nu + nx + nu + nu + 1)
                      * sizeof(double));
        s->Y = s->X + m * nx; s->z = s->Y + m * nu; s->Ginv = s->z + m; s->A = s->Ginv + m * m; s->B = s->A + nx1 * nx;
        s->b = s->B + nx1 * nu; s->Q = s->b + nx1; s->S = s->Q + nx * nx; s->R = s->S + nu * nx; s->q = s->R + nu * nu;
        s->r = s->q + nx; s->w = s->r + nu;
    }
    e->widest = w;
    e->G = malloc((mmax * (2 * w + mmax + 1) + 1) * sizeof(double));
    e->work = malloc(4 * (w + mmax + 1) * w * sizeof(double));
    e->work2 = e->work + 2 * (w + mmax + 1) * w;
    e->pi_known = malloc((w + 1) * sizeof(double));
    {  /* the BLASFEO matrices, at their largest sizes, in one aligned allocation */
        int nmax = 1, pmax = 1, k2, wide;
        size_t size = 0;
        char *mem;
        struct blasfeo_dmat *mats[11] = {&e->sRP, &e->sX, &e->sS, &e->sA2, &e->sB2, &e->sQ, &e->sC1, &e->sAB, &e->sPr,
                                         &e->sY, &e->sSF};
        for (k2 = 0; k2 <= N; k2++) { if (r->nx[k2] > nmax) nmax = r->nx[k2]; if (r->nu[k2] > pmax) pmax = r->nu[k2]; }
        if (mmax < 1) mmax = 1;
        wide = nmax + pmax + 1;
        {
            int rows[11] = {pmax, mmax, pmax, 2 * mmax, 2 * mmax, nmax, mmax, nmax, mmax, mmax, pmax};
            int cols[11] = {mmax, nmax, nmax, nmax, nmax, nmax, nmax, wide, wide, pmax, nmax};
            for (k2 = 0; k2 < 11; k2++) size += blasfeo_memsize_dmat(rows[k2], cols[k2]);
            e->blasfeo_mem = mem = aligned_alloc(64, (size + 63) / 64 * 64);
            for (k2 = 0; k2 < 11; k2++) {
                blasfeo_create_dmat(rows[k2], cols[k2], mats[k2], mem);
                mem += blasfeo_memsize_dmat(rows[k2], cols[k2]);
            }
        }
        e->gather = malloc((pmax * mmax + 2 * mmax * nmax + mmax * (nmax + pmax + 1) + 1) * sizeof(double));
    }
    {
        int total = 0;
        for (k = 0; k <= N; k++) total += r->ng[k];
        e->pure = calloc(total + 1, 1);
    }
    for (k = 0; k <= N; k++) if (!e->st[k].rows || !e->st[k].X) w = -1;
    if (w < 0 || !e->G || !e->work || !e->pi_known || !e->blasfeo_mem || !e->gather || !e->pure) {
        wbqp_eqelim_free(e);
        return NULL;
    }
    return e;
}

void wbqp_eqelim_free(wbqp_eqelim *e) {
    int k;
    if (!e) return;
    for (k = 0; k < e->n_cached; k++) wbqp_inst_release(&e->cache[k]);
    for (k = 0; k <= e->N; k++) { free(e->st[k].rows); free(e->st[k].X); }
    free(e->st); free(e->key); free(e->G); free(e->work); free(e->pi_known); free(e->pure);
    free(e->blasfeo_mem); free(e->gather); free(e);
}

static int is_equality(const wbqp_reduction *r, double l, double u) { return l == u && fabs(l) < r->inf; }

/* the pure flags (rows of stage k on its state alone, in the reduced QP) at stage k's offset */
static char *pure_at(wbqp_eqelim *e, const wbqp_reduction *r, int k) {
    int j, o = 0;
    for (j = 0; j < k; j++) o += r->ng[j];
    return e->pure + o;
}

static void classify_rows(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, int k) {
    int g = r->rng[k], p = r->rnu[k], i, j;
    char *pure = pure_at(e, r, k);
    for (i = 0; i < g; i++) {
        int on_u = 0;
        for (j = 0; j < p && !on_u; j++) on_u = d->D[i + j * g] != 0.0;
        pure[i] = is_equality(r, d->lg[i], d->ug[i]) && !on_u;
    }
}

/* stage k's G = [G_x | G_u | e] (m rows, row-major, width n + p + 1 + m with an identity appended) from its mixed
 * rows and stage k+1's pure ones (into e->G); 0 where there are more rows than inputs */
static int build_rows(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, const wbqp_stage *d1, int k) {
    eq_stage *s = &e->st[k];
    int n = r->rnx[k], p = r->rnu[k], g = r->rng[k], n1 = r->rnx[k + 1], g1 = r->rng[k + 1], m = 0, m1, i, j, l, c;
    int width = n + p + 1;
    const char *pure = pure_at(e, r, k), *pure1 = pure_at(e, r, k + 1);
    double *G;
    for (i = 0; i < g; i++) if (is_equality(r, d->lg[i], d->ug[i]) && !pure[i]) s->rows[m++] = i;
    m1 = m;
    for (i = 0; i < g1; i++) if (pure1[i]) s->rows[m++] = -1 - i;
    s->m = m;
    if (m > p) return 0;
    width += m;
    G = e->G;
    memset(G, 0, m * width * sizeof(double));
    for (c = 0; c < m; c++) {
        int row = s->rows[c];
        double *Gc = G + c * width;
        if (row >= 0) {
            for (j = 0; j < n; j++) Gc[j] = d->C[row + j * g];
            for (j = 0; j < p; j++) Gc[n + j] = d->D[row + j * g];
            Gc[n + p] = d->lg[row];
        }
        Gc[n + p + 1 + c] = 1.0;
    }
    if (m > m1) {  /* stage k+1's rows on its state, c' (A x + B u + b) = d: [G_x | G_u | c' b] = C1 [A | B | b] (BLASFEO) */
        int m2 = m - m1;
        double *C1 = e->gather, *prod = C1 + m2 * n1;
        for (c = 0; c < m2; c++)
            for (l = 0; l < n1; l++) C1[c + l * m2] = d1->C[(-1 - s->rows[m1 + c]) + l * g1];
        blasfeo_pack_dmat(m2, n1, C1, m2, &e->sC1, 0, 0);
        if (n > 0) blasfeo_pack_dmat(n1, n, (double *) d->A, n1, &e->sAB, 0, 0);
        blasfeo_pack_dmat(n1, p, (double *) d->B, n1, &e->sAB, 0, n);
        blasfeo_pack_dmat(n1, 1, (double *) d->b, n1, &e->sAB, 0, n + p);
        blasfeo_dgemm_nn(m2, n + p + 1, n1, 1.0, &e->sC1, 0, 0, &e->sAB, 0, 0, 0.0, &e->sPr, 0, 0, &e->sPr, 0, 0);
        blasfeo_unpack_dmat(m2, n + p + 1, &e->sPr, 0, 0, prod, m2);
        for (c = 0; c < m2; c++) {
            double *Gc = G + (m1 + c) * width;
            for (j = 0; j < n + p; j++) Gc[j] = prod[c + j * m2];
            Gc[n + p] = d1->lg[-1 - s->rows[m1 + c]] - prod[c + (n + p) * m2];
        }
    }
    return 1;
}

/* Gauss-Jordan elimination of e->G with partial pivoting on G_u, G_P^{-1} accumulated in the identity's place; X, Y, z,
 * G_P^{-1}, the pivots and the free inputs into stage k; 0 where G_u has no full row rank */
static int eliminate(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, const wbqp_stage *d1, int k) {
    eq_stage *s = &e->st[k];
    int n = r->rnx[k], p = r->rnu[k], m, width, i, j, c;
    double *G = e->G, big = 0.0;
    if (!build_rows(e, r, d, d1, k)) return 0;
    m = s->m; width = n + p + 1 + m;
    for (c = 0; c < m; c++)
        for (j = 0; j < p; j++) if (fabs(G[c * width + n + j]) > big) big = fabs(G[c * width + n + j]);
    for (j = 0; j < p; j++) s->free[j] = 1;  /* 1: not a pivot yet */
    for (c = 0; c < m; c++) {  /* pivot c: row c's largest entry among the free columns of G_u (LU of G_u' with
                                * partial pivoting: the rows have full rank or the elimination stops) */
        int pc = -1;
        double best = 0.0, *Gc = G + c * width;
        for (j = 0; j < p; j++)
            if (s->free[j] && fabs(Gc[n + j]) > best) { best = fabs(Gc[n + j]); pc = j; }
        if (pc < 0 || best <= PIVOT_RATIO * big) return 0;
        s->free[pc] = 0; s->piv[c] = pc;
        {
            double inv = 1.0 / Gc[n + pc];
            for (j = 0; j < width; j++) Gc[j] *= inv;
        }
        for (i = 0; i < m; i++) {
            double f = i == c ? 0.0 : G[i * width + n + pc], *Gi = G + i * width;
            if (f == 0.0) continue;
            for (j = 0; j < width; j++) Gi[j] -= f * Gc[j];
        }
    }
    /* row c of G now belongs to pivot c; its identity part is G_P^{-1}'s row c */
    for (j = 0, c = 0; j < p; j++) if (s->free[j]) s->free[c++] = j;
    s->nf = p - m;
    for (c = 0; c < m; c++) {
        const double *Gc = G + c * width;
        for (j = 0; j < n; j++) s->X[c + j * m] = -Gc[j];
        for (j = 0; j < s->nf; j++) s->Y[c + j * m] = -Gc[n + s->free[j]];
        s->z[c] = Gc[n + p];
        for (j = 0; j < m; j++) s->Ginv[c + j * m] = Gc[n + p + 1 + j];
    }
    return 1;
}

/* stage k's input blocks of (x, w) from u = T_x x + T_w w + t (rows P: X, Y, z; rows F: 0, I, 0): R', r', S's rows F
 * of R T_x + S; R T_x + S and R t + r (p rows) stay in e->work for `transform_states` */
static void transform_inputs(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, int k) {
    eq_stage *s = &e->st[k];
    int n = r->rnx[k], p = r->rnu[k], m = s->m, nf = s->nf, i, j, l;
    const int *P = s->piv, *F = s->free;
    double *RTx = e->work, *Rt = RTx + p * n, *RTw = Rt + p;  /* R T_x + S, R t + r, R T_w (p rows) */
    if (m > 0 && n > 0) {  /* R T_x + S = S + R_{:,P} X (BLASFEO) */
        double *RP = e->gather;
        for (l = 0; l < m; l++) memcpy(RP + l * p, d->R + P[l] * p, p * sizeof(double));
        blasfeo_pack_dmat(p, m, RP, p, &e->sRP, 0, 0);
        blasfeo_pack_dmat(m, n, s->X, m, &e->sX, 0, 0);
        blasfeo_pack_dmat(p, n, (double *) d->S, p, &e->sS, 0, 0);
        blasfeo_dgemm_nn(p, n, m, 1.0, &e->sRP, 0, 0, &e->sX, 0, 0, 1.0, &e->sS, 0, 0, &e->sS, 0, 0);
        blasfeo_unpack_dmat(p, n, &e->sS, 0, 0, RTx, p);
    } else {
        memcpy(RTx, d->S, p * n * sizeof(double));
    }
    for (j = 0; j < nf; j++) {
        memcpy(RTw + j * p, d->R + F[j] * p, p * sizeof(double));
        for (l = 0; l < m; l++) {
            double y = s->Y[l + j * m];
            const double *Rc = d->R + P[l] * p;
            if (y != 0.0) for (i = 0; i < p; i++) RTw[i + j * p] += Rc[i] * y;
        }
    }
    memcpy(Rt, d->r, p * sizeof(double));
    for (l = 0; l < m; l++) for (i = 0; i < p; i++) Rt[i] += d->R[i + P[l] * p] * s->z[l];
    /* R' = T_w' R T_w, S' = T_w' (R T_x + S), r' = T_w' (R t + r): axpys over the columns of Y' (Yt: nf x m) */
    {
        double *Yt = RTw + p * nf;
        for (l = 0; l < m; l++) for (i = 0; i < nf; i++) Yt[i + l * nf] = s->Y[l + i * m];
        for (j = 0; j < nf; j++) {
            double *Rj = s->R + j * nf;
            for (i = 0; i < nf; i++) Rj[i] = RTw[F[i] + j * p];
            for (l = 0; l < m; l++) {
                double a = RTw[P[l] + j * p];
                const double *yl = Yt + l * nf;
                for (i = 0; i < nf; i++) Rj[i] += yl[i] * a;
            }
        }
        for (j = 0; j < n; j++)  /* S' = (R T_x + S)_F, Y' (R T_x + S)_P added with Q' below */
            for (i = 0; i < nf; i++) s->S[i + j * nf] = RTx[F[i] + j * p];
        for (i = 0; i < nf; i++) s->r[i] = Rt[F[i]];
        for (l = 0; l < m; l++) {
            double a = Rt[P[l]];
            const double *yl = Yt + l * nf;
            for (i = 0; i < nf; i++) s->r[i] += yl[i] * a;
        }
    }
}

/* stage k's Q' = Q + X' (R T_x + S)_P + S_P' X = Q + [X; S_P]' [(R T_x + S)_P; X] (BLASFEO), S' += Y' (R T_x + S)_P,
 * q' = q + X' (R t + r)_P + S_P' z */
static void transform_states(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, int k) {
    eq_stage *s = &e->st[k];
    int n = r->rnx[k], p = r->rnu[k], m = s->m, nf = s->nf, j, l;
    const int *P = s->piv;
    double *RTx = e->work, *Rt = RTx + p * n;
    memcpy(s->q, d->q, n * sizeof(double));
    if (m > 0 && n > 0) {
        double *SP = e->gather, *RTxP = SP + m * n;
        for (j = 0; j < n; j++)
            for (l = 0; l < m; l++) { SP[l + j * m] = d->S[P[l] + j * p]; RTxP[l + j * m] = RTx[P[l] + j * p]; }
        blasfeo_pack_dmat(m, n, s->X, m, &e->sA2, 0, 0);
        blasfeo_pack_dmat(m, n, SP, m, &e->sA2, m, 0);
        blasfeo_pack_dmat(m, n, RTxP, m, &e->sB2, 0, 0);
        blasfeo_pack_dmat(m, n, s->X, m, &e->sB2, m, 0);
        blasfeo_pack_dmat(n, n, (double *) d->Q, n, &e->sQ, 0, 0);
        blasfeo_dgemm_tn(n, n, 2 * m, 1.0, &e->sA2, 0, 0, &e->sB2, 0, 0, 1.0, &e->sQ, 0, 0, &e->sQ, 0, 0);
        blasfeo_unpack_dmat(n, n, &e->sQ, 0, 0, s->Q, n);
        if (nf > 0) {  /* S' += Y' (R T_x + S)_P, (R T_x + S)_P in sB2's first m rows */
            blasfeo_pack_dmat(m, nf, s->Y, m, &e->sY, 0, 0);
            blasfeo_pack_dmat(nf, n, s->S, nf, &e->sSF, 0, 0);
            blasfeo_dgemm_tn(nf, n, m, 1.0, &e->sY, 0, 0, &e->sB2, 0, 0, 1.0, &e->sSF, 0, 0, &e->sSF, 0, 0);
            blasfeo_unpack_dmat(nf, n, &e->sSF, 0, 0, s->S, nf);
        }
        for (j = 0; j < n; j++) {
            double v = 0.0;
            for (l = 0; l < m; l++) v += s->X[l + j * m] * Rt[P[l]] + SP[l + j * m] * s->z[l];
            s->q[j] += v;
        }
    } else {
        memcpy(s->Q, d->Q, n * n * sizeof(double));
    }
}

/* stage k's A' = A + B_P X, B' = B_F + B_P Y, b' = b + B_P z (B_P's zeros skipped: B is mostly the integrator's) */
static void transform_dynamics(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, int k) {
    eq_stage *s = &e->st[k];
    int n = r->rnx[k], n1 = r->rnx[k + 1], m = s->m, nf = s->nf, i, j, l;
    const int *P = s->piv, *F = s->free;
    memcpy(s->A, d->A, n1 * n * sizeof(double));
    memcpy(s->b, d->b, n1 * sizeof(double));
    for (j = 0; j < nf; j++) memcpy(s->B + j * n1, d->B + F[j] * n1, n1 * sizeof(double));
    for (l = 0; l < m; l++) {
        const double *Bc = d->B + P[l] * n1;
        for (i = 0; i < n1; i++) {
            double bil = Bc[i];
            if (bil == 0.0) continue;
            for (j = 0; j < n; j++) s->A[i + j * n1] += bil * s->X[l + j * m];
            for (j = 0; j < nf; j++) s->B[i + j * n1] += bil * s->Y[l + j * m];
            s->b[i] += bil * s->z[l];
        }
    }
}

static void build(wbqp_eqelim *e, wbqp_inst *in) {
    int N = e->N, *zeros = calloc(N + 1, sizeof(int));  /* no bounds, rows or slacks: HPIPM's one factorisation */
    in->dims = malloc(2 * (N + 1) * sizeof(int)); memcpy(in->dims, e->key, 2 * (N + 1) * sizeof(int));
    wbqp_inst_dim(in, N);
    d_ocp_qp_dim_set_all(in->dims, in->dims + N + 1, zeros, zeros, zeros, zeros, &in->dim);
    wbqp_inst_memory(in);
    d_ocp_qp_ipm_arg_set_default(SPEED, &in->arg);
    wbqp_inst_workspace(in);
    free(zeros);
}

static wbqp_inst *instance(wbqp_eqelim *e) {
    int i, oldest = 0, n = 2 * (e->N + 1);
    for (i = 0; i < e->n_cached; i++) {
        wbqp_inst *c = &e->cache[i];
        if (!memcmp(c->dims, e->key, n * sizeof(int))) { c->used = ++e->clock; return c; }
        if (c->used < e->cache[oldest].used) oldest = i;
    }
    i = e->n_cached < EQ_CACHE ? e->n_cached++ : oldest;
    wbqp_inst_release(&e->cache[i]);
    build(e, &e->cache[i]);
    e->cache[i].used = ++e->clock;
    return &e->cache[i];
}

/* the largest violation of stage k's dropped inequalities and its equality rows' residual at (x, u) */
static void check(const wbqp_reduction *r, const wbqp_stage *d, int k, const double *x, const double *u,
                  double *viol, double *res) {
    int n = r->rnx[k], p = r->rnu[k], g = r->rng[k], i, j;
    for (i = 0; i < p; i++) {
        if (d->lbu[i] > -r->inf && d->lbu[i] - u[i] > *viol) *viol = d->lbu[i] - u[i];
        if (d->ubu[i] < r->inf && u[i] - d->ubu[i] > *viol) *viol = u[i] - d->ubu[i];
    }
    for (i = 0; i < n; i++) {
        if (d->lbx[i] > -r->inf && d->lbx[i] - x[i] > *viol) *viol = d->lbx[i] - x[i];
        if (d->ubx[i] < r->inf && x[i] - d->ubx[i] > *viol) *viol = x[i] - d->ubx[i];
    }
    for (i = 0; i < g; i++) {
        double v = 0.0;
        if (d->lg[i] <= -r->inf && d->ug[i] >= r->inf) continue;
        for (j = 0; j < n; j++) v += d->C[i + j * g] * x[j];
        for (j = 0; j < p; j++) v += d->D[i + j * g] * u[j];
        if (is_equality(r, d->lg[i], d->ug[i])) {
            if (fabs(v - d->lg[i]) > *res) *res = fabs(v - d->lg[i]);
        } else {
            if (d->lg[i] > -r->inf && d->lg[i] - v > *viol) *viol = d->lg[i] - v;
            if (d->ug[i] < r->inf && v - d->ug[i] > *viol) *viol = v - d->ug[i];
        }
    }
}

/* the equality rows' multipliers and pi, backwards (see the top) */
static void multipliers(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, wbqp_stage_sol *sol) {
    int N = r->N, k, i, j, l;
    double *known = e->pi_known, *rhs = e->work2;
    /* pi_known = Q x + S' u + q + C_mixed' lam_mixed + A' pi_k of stage k (pure rows' share added at stage k-1) */
    for (k = N; k >= 1; k--) {
        const wbqp_stage *dk = &d[k], *dp = &d[k - 1];
        eq_stage *s = &e->st[k - 1];
        int n = r->rnx[k], p = r->rnu[k], g = r->rng[k], p0 = r->rnu[k - 1], n0 = r->rnx[k - 1], g0 = r->rng[k - 1];
        int m = s->m;
        for (j = 0; j < n; j++) {
            double v = dk->q[j];
            for (i = 0; i < n; i++) v += dk->Q[i + j * n] * sol[k].x[i];
            for (i = 0; i < p; i++) v += dk->S[i + j * p] * sol[k].u[i];
            for (i = 0; i < g; i++) v += dk->C[i + j * g] * sol[k].lam_g[i];  /* pure rows' lam still 0 here */
            if (k < N) for (i = 0; i < r->rnx[k + 1]; i++) v += dk->A[i + j * r->rnx[k + 1]] * sol[k].pi[i];
            known[j] = v;
        }
        /* u_{k-1}: R u + S x + r + D' lam + B' (known + C_pure' lam_pure) = 0, on the pivot columns */
        for (i = 0; i < p0; i++) {
            double v = dp->r[i];
            for (j = 0; j < p0; j++) v += dp->R[i + j * p0] * sol[k - 1].u[j];
            for (j = 0; j < n0; j++) v += dp->S[i + j * p0] * sol[k - 1].x[j];
            for (j = 0; j < n; j++) v += dp->B[j + i * n] * known[j];
            rhs[i] = -v;
        }
        memset(sol[k - 1].lam_g, 0, g0 * sizeof(double));
        for (l = 0; l < m; l++) {  /* lam = G_P^{-T} rhs_P */
            double v = 0.0;
            for (i = 0; i < m; i++) v += s->Ginv[i + l * m] * rhs[s->piv[i]];
            if (s->rows[l] >= 0) sol[k - 1].lam_g[s->rows[l]] = v;
            else sol[k].lam_g[-1 - s->rows[l]] = v;
        }
        /* pi_{k-1} = known + C_pure' lam_pure */
        for (j = 0; j < n; j++) {
            double v = known[j];
            for (l = 0; l < m; l++)
                if (s->rows[l] < 0) v += dk->C[(-1 - s->rows[l]) + j * g] * sol[k].lam_g[-1 - s->rows[l]];
            sol[k - 1].pi[j] = v;
        }
    }
}

int wbqp_eqelim_solve(wbqp_eqelim *e, const wbqp_reduction *r, const wbqp_stage *d, wbqp_stage_sol *sol, double tol) {
    int N = r->N, k, i, j, status;
    double viol = 0.0, res = 0.0;
    wbqp_inst *in;
    for (k = 0; k <= N; k++) classify_rows(e, r, &d[k], k);
    if (r->rnx[0] > 0) {  /* x_0 in the QP: no rows on it alone (nothing before stage 0 moves them onto inputs) */
        const char *pure = pure_at(e, r, 0);
        for (i = 0; i < r->rng[0]; i++) if (pure[i]) return 2;
    }
    for (k = 0; k < N; k++) if (!eliminate(e, r, &d[k], &d[k + 1], k)) return 2;
    for (i = 0; i < r->rng[N]; i++)  /* the last stage's rows with no inputs must all be on its state */
        if (is_equality(r, d[N].lg[i], d[N].ug[i]) && !pure_at(e, r, N)[i]) return 2;
    for (k = 0; k <= N; k++) {
        e->key[k] = r->rnx[k];
        e->key[N + 1 + k] = k < N ? e->st[k].nf : 0;
        if (k < N) {
            transform_inputs(e, r, &d[k], k);
            transform_states(e, r, &d[k], k);
            transform_dynamics(e, r, &d[k], k);
        }
    }
    in = instance(e);
    for (k = 0; k <= N; k++) {
        eq_stage *s = &e->st[k];
        if (k < N) {
            d_ocp_qp_set_A(k, s->A, &in->qp); d_ocp_qp_set_B(k, s->B, &in->qp); d_ocp_qp_set_b(k, s->b, &in->qp);
            d_ocp_qp_set_Q(k, s->Q, &in->qp); d_ocp_qp_set_S(k, s->S, &in->qp); d_ocp_qp_set_R(k, s->R, &in->qp);
            d_ocp_qp_set_q(k, s->q, &in->qp); d_ocp_qp_set_r(k, s->r, &in->qp);
        } else {
            d_ocp_qp_set_Q(k, (double *) d[k].Q, &in->qp); d_ocp_qp_set_q(k, (double *) d[k].q, &in->qp);
        }
    }
    d_ocp_qp_ipm_solve(&in->qp, &in->sol, &in->arg, &in->ws);
    d_ocp_qp_ipm_get_status(&in->ws, &status);
    if (status != 0) return 3;
    for (k = 0; k <= N; k++) {  /* x, then u = T_x x + T_w w + t; inequalities inactive: their multipliers 0 */
        eq_stage *s = &e->st[k];
        int n = r->rnx[k], p = r->rnu[k];
        d_ocp_qp_sol_get_x(k, &in->sol, sol[k].x);
        memset(sol[k].lam_u, 0, p * sizeof(double));
        memset(sol[k].lam_x, 0, n * sizeof(double));
        if (k == N) continue;
        d_ocp_qp_sol_get_u(k, &in->sol, s->w);
        for (j = 0; j < s->nf; j++) sol[k].u[s->free[j]] = s->w[j];
        for (i = 0; i < s->m; i++) {
            double v = s->z[i];
            for (j = 0; j < n; j++) v += s->X[i + j * s->m] * sol[k].x[j];
            for (j = 0; j < s->nf; j++) v += s->Y[i + j * s->m] * s->w[j];
            sol[k].u[s->piv[i]] = v;
        }
    }
    memset(sol[N].lam_g, 0, r->rng[N] * sizeof(double));
    for (k = 0; k <= N; k++) check(r, &d[k], k, sol[k].x, sol[k].u, &viol, &res);
    if (viol > 0.0) return 1;  /* the guess was wrong: an inequality is active */
    if (res > tol) return 3;
    multipliers(e, r, d, sol);
    return 0;
}
