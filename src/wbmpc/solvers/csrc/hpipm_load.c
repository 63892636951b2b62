/* The NLP's QP (nonzeros of H and J, gradient, bounds in the NLP's order) into HPIPM's stage blocks, and the solution
 * back into the NLP's order (solvers/hpipm_direct.py computes the index maps once; this replaces ~25 NumPy fancy-index
 * operations a call).
 *
 * Gap rows I x_{k+1} + A_k x_k + B_k u_k = rhs become HPIPM's x_{k+1} = -(A_k x_k + B_k u_k - rhs) / I: A and B
 * scaled by -1 / I of their row, b = -rhs / I; casadi's multipliers of the gap rows are HPIPM's pi / -I.
 */
#include <stdlib.h>

/* in hpipm_shim.c */
int wbqp_solve(void *handle, const double *A, const double *B, const double *b, const double *Q, const double *S,
               const double *R, const double *q, const double *r, const double *C, const double *D,
               const double *lbu, const double *ubu, const double *lbx, const double *ubx,
               const double *lg, const double *ug, double *u, double *x, double *pi, double *lam_u, double *lam_x,
               double *lam_g);

enum { N_J, N_H, N_GAP, N_X, N_U, N_PATH, N_COUNTS };
enum { J_SRC, J_DST, J_ROW, H_SRC, H_DST, EYE_SRC, GAP, X_INDEX, U_INDEX, PATH, N_MAPS };
/* buffers: the block store (A, B, Q, S, R, C, D at their offsets), then b, q, r, lbu, ubu, lbx, ubx, lg, ug, u, x, pi,
 * lam_u, lam_x, lam_g, scale */
enum { A_, B_, Q_, S_, R_, C_, D_, b_, q_, r_, lbu_, ubu_, lbx_, ubx_, lg_, ug_, u_, x_, pi_, lam_u_, lam_x_, lam_g_,
       scale_, N_BUFFERS };

typedef struct {
    int counts[N_COUNTS];
    const int *map[N_MAPS];
    double *buffer[N_BUFFERS];
} wbqp_nlp;

/* the maps and buffers (owned by the caller, alive while the returned handle is used) */
void *wbqp_nlp_new(const int *counts, const int *const *maps, double *const *buffers) {
    wbqp_nlp *m = calloc(1, sizeof(wbqp_nlp));
    int i;
    if (!m) return NULL;
    for (i = 0; i < N_COUNTS; i++) m->counts[i] = counts[i];
    for (i = 0; i < N_MAPS; i++) m->map[i] = maps[i];
    for (i = 0; i < N_BUFFERS; i++) m->buffer[i] = buffers[i];
    return m;
}

void wbqp_nlp_free(void *maps) { free(maps); }

static void gather(int n, const int *index, const double *src, double *dst) {
    int i;
    for (i = 0; i < n; i++) dst[i] = src[index[i]];
}

static void scatter(int n, const int *index, const double *src, double *dst) {
    int i;
    for (i = 0; i < n; i++) dst[index[i]] = src[i];
}

/* the blocks from h, g, j and the bounds; -10 where a gap row is no equality */
static int load(wbqp_nlp *m, const double *h, const double *g, const double *j, const double *lbg, const double *ubg,
                const double *lbx, const double *ubx) {
    const int *const *map = m->map;
    double *const *buf = m->buffer, *store = buf[A_], *scale = buf[scale_];
    int i;
    for (i = 0; i < m->counts[N_GAP]; i++) {
        int row = map[GAP][i], eye = map[EYE_SRC][i];
        if (lbg[row] != ubg[row]) return -10;
        scale[i] = -1.0 / (eye >= 0 ? j[eye] : 1.0);
        buf[b_][i] = -lbg[row] * scale[i];
    }
    for (i = 0; i < m->counts[N_J]; i++) {
        int row = map[J_ROW][i];
        store[map[J_DST][i]] = row >= 0 ? j[map[J_SRC][i]] * scale[row] : j[map[J_SRC][i]];
    }
    for (i = 0; i < m->counts[N_H]; i++) store[map[H_DST][i]] = h[map[H_SRC][i]];
    gather(m->counts[N_X], map[X_INDEX], g, buf[q_]);
    gather(m->counts[N_U], map[U_INDEX], g, buf[r_]);
    gather(m->counts[N_U], map[U_INDEX], lbx, buf[lbu_]);
    gather(m->counts[N_U], map[U_INDEX], ubx, buf[ubu_]);
    gather(m->counts[N_X], map[X_INDEX], lbx, buf[lbx_]);
    gather(m->counts[N_X], map[X_INDEX], ubx, buf[ubx_]);
    gather(m->counts[N_PATH], map[PATH], lbg, buf[lg_]);
    gather(m->counts[N_PATH], map[PATH], ubg, buf[ug_]);
    return 0;
}

/* Solve the QP given in the NLP's order (h, j: nonzeros of H and J; g: gradient; bounds on the step); the step and
 * casadi's multipliers into step (n_var), lam_g (n_row), lam_x (n_var). Returns HPIPM's status, -10 where a gap row is
 * no equality (nothing solved). */
int wbqp_nlp_solve(void *handle, void *maps, const double *h, const double *g, const double *j, const double *lbg,
                   const double *ubg, const double *lbx, const double *ubx, double *step, double *lam_g,
                   double *lam_x) {
    wbqp_nlp *m = maps;
    double *const *buf = m->buffer;
    int status, i;
    if (load(m, h, g, j, lbg, ubg, lbx, ubx) != 0) return -10;
    status = wbqp_solve(handle, buf[A_], buf[B_], buf[b_], buf[Q_], buf[S_], buf[R_], buf[q_], buf[r_], buf[C_],
                        buf[D_], buf[lbu_], buf[ubu_], buf[lbx_], buf[ubx_], buf[lg_], buf[ug_], buf[u_], buf[x_],
                        buf[pi_], buf[lam_u_], buf[lam_x_], buf[lam_g_]);
    scatter(m->counts[N_U], m->map[U_INDEX], buf[u_], step);
    scatter(m->counts[N_X], m->map[X_INDEX], buf[x_], step);
    scatter(m->counts[N_U], m->map[U_INDEX], buf[lam_u_], lam_x);
    scatter(m->counts[N_X], m->map[X_INDEX], buf[lam_x_], lam_x);
    scatter(m->counts[N_PATH], m->map[PATH], buf[lam_g_], lam_g);
    for (i = 0; i < m->counts[N_GAP]; i++) lam_g[m->map[GAP][i]] = buf[pi_][i] * buf[scale_][i];
    return status;
}
