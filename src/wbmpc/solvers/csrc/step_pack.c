/* The per-step packing of an MPC step in C (`solvers/step_pack.py`): the warm start's re-sampling, the bounds, the
 * swing feet's v_z references. Each is the NumPy code it replaces, operation for
 * operation (built with -ffp-contract=off: no fused multiply-adds), so the results are the same bit for bit; the
 * NumPy code stays the fallback without a compiler and the tests' oracle. One call here replaces 5-20 NumPy calls,
 * each ~2-4 us right after the solver has evicted the interpreter's caches. */
#include <math.h>
#include <stdint.h>
#include <string.h>

/* np.maximum / np.minimum: a NaN in either gives NaN */
static double wb_max(double a, double b) { return a != a ? a : (b != b ? b : (a >= b ? a : b)); }
static double wb_min(double a, double b) { return a != a ? a : (b != b ? b : (a <= b ? a : b)); }

/* np.searchsorted(sorted, value) (side "left"): the first index with sorted[i] >= value */
static long wb_search_left(const double *sorted, long n, double value) {
  long lo = 0, hi = n;
  while (lo < hi) {
    long mid = lo + (hi - lo) / 2;
    if (sorted[mid] < value) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

/* `ShiftedGuess.__call__`: each part's nodes (its group's node count lengths[g]) interpolated at new_times among
 * old_times (held beyond them); pos/weight scratch of n_groups * n_new; out (size entries) zeroed, then
 * out[target[i]] = (1 - w) * old_x[before] + w * old_x[after]. */
int wbsp_shift(int n_groups, const int64_t *lengths, int n_old, const double *old_times, int n_new,
               const double *new_times, int n_vars, const int64_t *group_node, const int64_t *by_column,
               const int64_t *column_start, const int64_t *target, const double *old_x, int size, double *out,
               int64_t *pos, double *weight) {
  int g, k, i;
  for (k = 0; k < n_new; ++k) {
    long after = wb_search_left(old_times, n_old, new_times[k]);
    for (g = 0; g < n_groups; ++g) {
      long cap = lengths[g] - 2 > 0 ? lengths[g] - 2 : 0;
      long p = after - 1 > 0 ? after - 1 : 0;
      double t0, t1, w;
      p = p < cap ? p : cap;
      t0 = old_times[p];
      t1 = old_times[p + 1 < n_old - 1 ? p + 1 : n_old - 1];
      w = wb_min(wb_max((new_times[k] - t0) / wb_max(t1 - t0, 1e-12), 0.0), 1.0);
      pos[g * n_new + k] = p;
      weight[g * n_new + k] = lengths[g] < 2 ? 0.0 : w;
    }
  }
  memset(out, 0, sizeof(double) * (size_t)size);
  for (i = 0; i < n_vars; ++i) {
    int64_t p = pos[group_node[i]];
    double w = weight[group_node[i]];
    double before = old_x[by_column[column_start[i] + p]], next = old_x[by_column[column_start[i] + 1 + p]];
    double a = (1.0 - w) * before, b = w * next;
    out[target[i]] = a + b;
  }
  return 0;
}

/* `BoundsTemplate.start`: the template copied into out, each contact-dependent entry its stance or swing value
 * (contact[flags[i]] != 0), the slacks free (+inf) with `soft`. */
int wbsp_bounds_start(const double *template_, int n, const int64_t *entries, const int64_t *flags,
                      const double *stance, const double *swing, int n_entries, const uint8_t *contact,
                      const int64_t *slack_entries, int n_slack, int soft, double *out) {
  int i;
  memcpy(out, template_, sizeof(double) * (size_t)n);
  for (i = 0; i < n_entries; ++i) out[entries[i]] = contact[flags[i]] ? stance[i] : swing[i];
  if (soft)
    for (i = 0; i < n_slack; ++i) out[slack_entries[i]] = INFINITY;
  return 0;
}

/* ---- `OcpProblem.bounds`' measured entries (`BoundsTemplate.measured`), in its order. The buffer is
 * [lbx | ubx | lbg | ubg]; a table's entries are x or g indices (n_x, n_g added for the upper / g parts). */
enum { M_NX, M_NG, M_NJ, M_DQ_ROWS, M_EARLY_ROWS, M_OVERSPEED_ROWS, M_V0_ROWS, M_ARM_ROWS, M_X0, M_FOOT_NODES,
       M_NF, M_EE_ROWS, M_ANG_NODES, M_NS, M_COUNT };
enum { T_DQ, T_EARLY, T_OVERSPEED, T_V0, T_ARM, T_X0, T_FOOT_ROWS, T_FOOT_NODES, T_EE, T_ANG_ROWS, T_ANG_NODES,
       T_SURFACE, T_COUNT };
enum { C_QMIN, C_QMAX, C_EARLY_TIMES, C_VMAX, C_FOOT_DECAY, C_EE_DECAY, C_X_SCALE, C_ANG_DECAY, C_YAW_BAND, C_COUNT };
enum { S_QJ, S_V0J, S_FORCE, S_X0, S_SWING_VZ, S_SWING_VXY, S_FOOT_MEASURED, S_EE_VEL, S_EE_MEASURED, S_SWING_YAW,
       S_FOOT_ANG_MEASURED, S_COUNT };

static void wb_pin(double *buf, long n_upper, int64_t entry, double value) {
  buf[entry] = value;
  buf[entry + n_upper] = value;
}

/* eq. (8) on nodes 1..N (widened to the coasting measurement over the first nodes), the measured overspeed, the
 * velocity-level formulations' first joint velocities, eq. (7)'s arm force */
static void wb_joint_bounds(double *buf, const int64_t *m, const int64_t *const *t, const double *const *c,
                            const double *const *s) {
  long nx = m[M_NX], nj = m[M_NJ], r, j;
  for (r = 0; r < m[M_DQ_ROWS]; ++r)
    for (j = 0; j < nj; ++j) {
      buf[t[T_DQ][r * nj + j]] = c[C_QMIN][j] - s[S_QJ][j];
      buf[t[T_DQ][r * nj + j] + nx] = c[C_QMAX][j] - s[S_QJ][j];
    }
  for (r = 0; r < m[M_EARLY_ROWS]; ++r)
    for (j = 0; j < nj; ++j) {
      double coasting = c[C_EARLY_TIMES][r] * s[S_V0J][j];
      int64_t e = t[T_EARLY][r * nj + j];
      buf[e] = wb_min(buf[e], wb_min(coasting, 0.0) - 1e-6);
      buf[e + nx] = wb_max(buf[e + nx], wb_max(coasting, 0.0) + 1e-6);
    }
  for (r = 0; r < m[M_OVERSPEED_ROWS]; ++r)
    for (j = 0; j < nj; ++j) {
      double overspeed = wb_max(c[C_VMAX][j], fabs(s[S_V0J][j]));
      buf[t[T_OVERSPEED][r * nj + j]] = -overspeed;
      buf[t[T_OVERSPEED][r * nj + j] + nx] = overspeed;
    }
  for (r = 0; r < m[M_V0_ROWS]; ++r)
    for (j = 0; j < nj; ++j) wb_pin(buf, nx, t[T_V0][r * nj + j], s[S_V0J][j]);
  for (r = 0; r < m[M_ARM_ROWS]; ++r)
    for (j = 0; j < 3; ++j) wb_pin(buf, nx, t[T_ARM][r * 3 + j], s[S_FORCE][j]);
}

/* eq. (6): swing feet's v_z reference (stance 0), swing v_xy carried to a placement, stance feet measured moving
 * blended from the measurement (`OcpProblem._foot_bounds`) */
static void wb_foot_bounds(double *buf, const int64_t *m, const int64_t *const *t, const double *const *c,
                           const double *const *s, const uint8_t *contact, int relax) {
  long lbg = 2 * m[M_NX], ng = m[M_NG], nf = m[M_NF], r, f, k;
  for (r = 0; r < m[M_FOOT_NODES]; ++r)
    for (f = 0; f < nf; ++f) {
      long node = t[T_FOOT_NODES][r], at = node * nf + f;
      const int64_t *rows = t[T_FOOT_ROWS] + (r * nf + f) * 3;
      int swing = !contact[at];
      wb_pin(buf, ng, lbg + rows[2], swing ? s[S_SWING_VZ][at] : 0.0);
      if (s[S_SWING_VXY] && swing)
        for (k = 0; k < 2; ++k)
          if (isfinite(s[S_SWING_VXY][at * 2 + k])) wb_pin(buf, ng, lbg + rows[k], s[S_SWING_VXY][at * 2 + k]);
      if (s[S_FOOT_MEASURED] && !swing)
        for (k = 0; k < 3; ++k) {
          double target = 0.0, measured = s[S_FOOT_MEASURED][f * 3 + k];
          wb_pin(buf, ng, lbg + rows[k], target + c[C_FOOT_DECAY][r] * (measured - target));
        }
      if (relax)
        for (k = 0; k < 3; ++k) {
          buf[lbg + rows[k]] = -INFINITY;
          buf[lbg + rows[k] + ng] = INFINITY;
        }
    }
}

/* flat feet's angular velocity rows (eq. 6 for soles): a swing sole's yaw rate within the band about its reference
 * where it has one, a stance sole measured rotating blended from the measurement (`OcpProblem._foot_bounds`) */
static void wb_sole_bounds(double *buf, const int64_t *m, const int64_t *const *t, const double *const *c,
                           const double *const *s, const uint8_t *contact) {
  long lbg = 2 * m[M_NX], ng = m[M_NG], nf = m[M_NF], ns = m[M_NS], r, f, k;
  for (r = 0; r < m[M_ANG_NODES]; ++r)
    for (f = 0; f < ns; ++f) {
      long foot = t[T_SURFACE][f], at = t[T_ANG_NODES][r] * nf + foot;
      const int64_t *rows = t[T_ANG_ROWS] + (r * ns + f) * 3;
      int swing = !contact[at];
      if (s[S_SWING_YAW] && swing && isfinite(s[S_SWING_YAW][at])) {
        buf[lbg + rows[2]] = s[S_SWING_YAW][at] - c[C_YAW_BAND][0];
        buf[lbg + rows[2] + ng] = s[S_SWING_YAW][at] + c[C_YAW_BAND][0];
      }
      if (s[S_FOOT_ANG_MEASURED] && !swing)
        for (k = 0; k < 3; ++k) {
          double target = 0.0, measured = s[S_FOOT_ANG_MEASURED][foot * 3 + k];
          wb_pin(buf, ng, lbg + rows[k], target + c[C_ANG_DECAY][r] * (measured - target));
        }
    }
}

/* x_0 rows = the measured state, the end effector's velocity rows of eq. (7) (blended from the measurement) or
 * free when relaxed, then lbx, ubx divided by the variables' scales (`BoundsTemplate.finish`) */
int wbsp_bounds_measured(double *buf, const int64_t *m, const int64_t *const *t, const double *const *c,
                         const double *const *s, const uint8_t *contact, int relax_ee, int relax_foot) {
  long lbg = 2 * m[M_NX], ng = m[M_NG], r, k;
  wb_joint_bounds(buf, m, t, c, s);
  for (r = 0; r < m[M_X0]; ++r) wb_pin(buf, ng, lbg + t[T_X0][r], s[S_X0][r]);
  wb_foot_bounds(buf, m, t, c, s, contact, relax_foot);
  wb_sole_bounds(buf, m, t, c, s, contact);
  for (r = 0; r < m[M_EE_ROWS]; ++r)
    for (k = 0; k < 3; ++k) {
      long row = lbg + t[T_EE][r * 3 + k];
      double target = s[S_EE_VEL][k];
      if (relax_ee) {
        buf[row] = -INFINITY;
        buf[row + ng] = INFINITY;
      } else {
        wb_pin(buf, ng, row, s[S_EE_MEASURED] ? target + c[C_EE_DECAY][r] * (s[S_EE_MEASURED][k] - target) : target);
      }
    }
  for (r = 0; r < 2 * m[M_NX]; ++r) buf[r] /= c[C_X_SCALE][r];
  return 0;
}

/* `SwingProfile.vertical_velocity` (gait.py): v_z^ref at swing progress s (< 0: stance, 0), two cubic pieces of
 * duration T each (liftoff_t, touchdown_t: the lift-off and touch-down velocities times T) */
int wbsp_swing_vz(int n, const double *progress, double piece_s, double apex_m, double liftoff_t, double touchdown_t,
                  double *out) {
  int i;
  for (i = 0; i < n; ++i) {
    double s = progress[i];
    int down = s >= 0.5;
    double x = down ? (s - 0.5) / 0.5 : s / 0.5;
    double x2 = x * x;
    double up = (3.0 * x2 - 4.0 * x + 1.0) * liftoff_t + (-6.0 * x2 + 6.0 * x) * apex_m;
    double descent = (6.0 * x2 - 6.0 * x) * apex_m + (3.0 * x2 - 2.0 * x) * touchdown_t;
    out[i] = s >= 0 ? (down ? descent : up) / piece_s : 0.0;
  }
  return 0;
}

/* `MultiplierShift.shift`'s sources (ocp/multipliers.py): for each of n items (rows or variables), the old items
 * src0, src1 it is re-sampled from and the weight w of src1, found by identity (group, node, place:
 * table[group][node][place] the item there or -1) between the old nodes (old_times) around its new node's time
 * new_times[k] + dt_s on the old plan's clock (plans with their own node times: `TimeGrid.follow_contact_switches`).
 * Which of them count (their bound kinds) stays the NumPy code's. before, weight: n_times scratch. */
int wbsp_dual_sources_at(int n, const double *new_times, const double *old_times, int n_times, double dt_s,
                         const int64_t *group, const int64_t *node, const int64_t *place, const int64_t *first,
                         const int64_t *last, const int64_t *table, int n_table_nodes, int n_places, int64_t *src0,
                         int64_t *src1, double *w, int64_t *before, double *weight) {
  int k, i;
  for (k = 0; k < n_times; ++k) { /* `MultiplierShift._sources` */
    double shifted = wb_min(new_times[k] + dt_s, old_times[n_times - 1]);
    long b, lo = 0, hi = n_times; /* np.searchsorted(side="right"): the first index with times[i] > shifted */
    while (lo < hi) {
      long mid = lo + (hi - lo) / 2;
      if (old_times[mid] <= shifted) lo = mid + 1;
      else hi = mid;
    }
    b = lo - 1;
    b = b < 0 ? 0 : (b > n_times - 2 ? n_times - 2 : b);
    before[k] = b;
    weight[k] = wb_min(wb_max((shifted - old_times[b]) / (old_times[b + 1] - old_times[b]), 0.0), 1.0);
  }
  for (i = 0; i < n; ++i) {
    int64_t nd = node[i], lo_node = first[i], hi_node = last[i];
    int64_t node0 = before[nd] < lo_node ? lo_node : (before[nd] > hi_node ? hi_node : before[nd]);
    int64_t node1 = node0 + 1 < hi_node ? node0 + 1 : hi_node;
    const int64_t *column = table + group[i] * (int64_t)n_table_nodes * n_places + place[i];
    int64_t s0 = column[node0 * n_places], s1 = column[node1 * n_places];
    double wi = node0 < hi_node ? weight[nd] : 0.0;
    w[i] = s1 < 0 ? 0.0 : (s0 < 0 ? 1.0 : wi);
    src0[i] = s0 < 0 ? s1 : s0;
    src1[i] = s1 < 0 ? s0 : s1;
  }
  return 0;
}

/* `wbsp_dual_sources_at` on one fixed grid (node_times, the plans' own and the last plan's alike). */
int wbsp_dual_sources(int n, const double *node_times, int n_times, double dt_s, const int64_t *group,
                      const int64_t *node, const int64_t *place, const int64_t *first, const int64_t *last,
                      const int64_t *table, int n_table_nodes, int n_places, int64_t *src0, int64_t *src1, double *w,
                      int64_t *before, double *weight) {
  return wbsp_dual_sources_at(n, node_times, node_times, n_times, dt_s, group, node, place, first, last, table,
                              n_table_nodes, n_places, src0, src1, w, before, weight);
}

/* `ocp/multipliers.bound_kind`: per row 0 free, 1 lower bound only, 2 upper only, 3 both, 4 equality */
int wbsp_bound_kind(int n, const double *lower, const double *upper, int64_t *kind) {
  int i;
  for (i = 0; i < n; ++i) kind[i] = lower[i] == upper[i] ? 4 : (isfinite(lower[i]) ? 1 : 0) + (isfinite(upper[i]) ? 2 : 0);
  return 0;
}

/* `MultiplierShift.shift` from its sources (`wbsp_dual_sources`): each multiplier re-sampled from the old ones of
 * its row's bound kind now (both: interpolated; one: its value), 0 where neither has it or the row has no identity */
int wbsp_dual_shift(int n, const double *lam, const int64_t *kind_old, const int64_t *kind_new, const int64_t *src0,
                    const int64_t *src1, const double *w, const uint8_t *covered, double *out) {
  int i;
  for (i = 0; i < n; ++i) {
    int64_t s0 = src0[i], s1 = src1[i];
    int same0, same1;
    double wi;
    if (s0 < 0 || !covered[i]) {
      out[i] = 0.0;
      continue;
    }
    same0 = kind_old[s0] == kind_new[i];
    same1 = kind_old[s1] == kind_new[i];
    wi = same0 && same1 ? w[i] : (same0 ? 0.0 : 1.0);
    out[i] = same0 || same1 ? (1 - wi) * lam[s0] + wi * lam[s1] : 0.0;
  }
  return 0;
}
