/* The delay prediction's tick inputs in one call (control/delay_ticks.py's `CompiledTicks.predict`): the joint loop's
 * ticks over the delay, the feet the plan holds at each and eq. (9) sampled there (`DelayPredictor.predict`'s
 * `np.arange`, `np.searchsorted` and `joint_references`, operation for operation, built without fused
 * multiply-adds), written straight into the compiled ticks' input columns (one column per tick, zero-padded). Why:
 * right after the solve the interpreter's caches are cold and those ~25 small NumPy calls took ~0.1 ms of g1's step. */
#include <math.h>
#include <stdint.h>
#include <string.h>

/* The joint loop's tick count over the delay: len(np.arange(t, t + delay - 1e-12, hold)) */
int64_t wbsp_tick_count(double t, double delay_s, double hold) {
  double length = ceil(((t + delay_s) - 1e-12 - t) / hold);
  return length > 0 ? (int64_t)length : 0;
}

/* Ticks [start, start + ticks) of the `n_ticks` over the delay into the columns tau_ff, q_des, v_des (nj, ticks),
 * held (n_feet, ticks) and h (ticks); ticks past n_ticks zero (h = 0: no motion). The plan: its time plan_t, node
 * times (nodes), contact (nodes, n_feet), torques (n_tau, nj), joint angles q_joints (row stride q_stride), v and a
 * (nodes and nodes - 1 rows of nv; their joints after the base's 6). `lead`: eq. (9) sampled that much after a tick. */
void wbsp_tick_inputs(double t, double delay_s, double hold, double lead, int64_t n_ticks, int64_t start,
                      int64_t ticks, double plan_t, const double *node_times, int64_t nodes, const double *contact,
                      int64_t n_feet, const double *tau, int64_t n_tau, const double *q_joints, int64_t q_stride,
                      const double *v, const double *a, int64_t nv, double *tau_ff, double *q_des, double *v_des,
                      double *held, double *h) {
  int64_t nj = nv - 6, i, j, f;
  double first = t, delta = (t + hold) - t, end = t + delay_s;
  memset(tau_ff, 0, sizeof(double) * (size_t)(nj * ticks));
  memset(q_des, 0, sizeof(double) * (size_t)(nj * ticks));
  memset(v_des, 0, sizeof(double) * (size_t)(nj * ticks));
  memset(held, 0, sizeof(double) * (size_t)(n_feet * ticks));
  memset(h, 0, sizeof(double) * (size_t)ticks);
  for (i = 0; i < ticks && start + i < n_ticks; ++i) {
    int64_t tick = start + i, node = 0, k;
    /* np.arange's values: start, start + step, then start + i * (second - first) */
    double time = tick == 0 ? first : (tick == 1 ? t + hold : first + (double)tick * delta), next, sample, t0, t1;
    double t_local, dt_k;
    const double *tau_k, *tau_next, *v_k, *a_k, *q_k;
    next = tick + 1 >= n_ticks ? end : (tick + 1 == 1 ? t + hold : first + (double)(tick + 1) * delta);
    h[i] = next - time;
    while (node < nodes && plan_t + node_times[node] <= time) ++node; /* searchsorted(side="right") */
    node = node - 1 < 0 ? 0 : (node - 1 > nodes - 1 ? nodes - 1 : node - 1);
    for (f = 0; f < n_feet; ++f) held[i * n_feet + f] = contact[node * n_feet + f] != 0 ? 1.0 : 0.0;
    sample = time + lead; /* `joint_references` */
    k = sample >= plan_t + node_times[1] ? 1 : 0;
    t0 = plan_t + node_times[k];
    t1 = plan_t + node_times[k + 1];
    t_local = sample - t0;
    t_local = t_local > 0.0 ? t_local : 0.0;
    t_local = t_local < t1 - t0 ? t_local : t1 - t0;
    dt_k = t1 - t0;
    tau_k = tau + nj * (k < n_tau - 1 ? k : n_tau - 1);
    tau_next = tau + nj * (k + 1 < n_tau - 1 ? k + 1 : n_tau - 1);
    q_k = q_joints + q_stride * k;
    v_k = v + nv * k + 6;
    a_k = a + nv * k + 6;
    for (j = 0; j < nj; ++j) {
      tau_ff[i * nj + j] = tau_k[j] + (tau_next[j] - tau_k[j]) * (t_local / dt_k);
      q_des[i * nj + j] = q_k[j] + v_k[j] * t_local;
      v_des[i * nj + j] = v_k[j] + a_k[j] * t_local;
    }
  }
}

typedef int (*wbdt_fn)(const double **arg, double **res, long long *iw, double *w, int mem);

/* `count` ticks of the compiled one-tick function `tick` (control/delay_ticks.py's `tick_function`: its generated C
 * entry point, work arrays of its `_work` sizes) on the columns `wbsp_tick_inputs` wrote, from (q, v) (updated in
 * place; next_q, next_v scratch): the ticks the delay has, no padding ticks of zero length. 1 if an evaluation failed. */
int wbsp_ticks_run(void *tick, int64_t count, int64_t nq, int64_t nv, int64_t n_feet, double *q, double *v,
                   const double *tau_ff, const double *q_des, const double *v_des, const double *held, const double *h,
                   const double *kp, const double *kd, const double *baumgarte, const double **arg, double **res,
                   long long *iw, double *w, double *next_q, double *next_v) {
  wbdt_fn f = (wbdt_fn)tick;
  int64_t i, nj = nv - 6;
  for (i = 0; i < count; ++i) {
    arg[0] = q;
    arg[1] = v;
    arg[2] = tau_ff + i * nj;
    arg[3] = q_des + i * nj;
    arg[4] = v_des + i * nj;
    arg[5] = held + i * n_feet;
    arg[6] = h + i;
    arg[7] = kp;
    arg[8] = kd;
    arg[9] = baumgarte;
    res[0] = next_q;
    res[1] = next_v;
    if (f(arg, res, iw, w, 0)) return 1;
    memcpy(q, next_q, sizeof(double) * (size_t)nq);
    memcpy(v, next_v, sizeof(double) * (size_t)nv);
  }
  return 0;
}
