/* Flat feet's and swing feet's parts of an MPC step in C (`control/compiled_step.py`): the swing feet's xy velocity
 * references and swing soles' yaw rates (`SwingPlacement.velocities`, `yaw_rates` over `swings_in_horizon`,
 * control/foot_placement.py) and the last plan's sole wrenches re-sampled by contact pattern
 * (`warm_start.shifted_sole_wrenches`). Operation for operation the Python code's, built without fused multiply-adds
 * (the results are the NumPy path's bit for bit, tests/control/test_compiled_step.py). Why: right after the solve the
 * interpreter's caches are cold and these Python loops over the horizon's swings and nodes took ~0.3 ms of g1's
 * real-time step. */
#include <math.h>
#include <stdint.h>

/* the swing inputs of a step (`wbsp_swing_references`' `in`, written by Python) */
enum { S_T, S_QX, S_QY, S_VX, S_VY, S_CX, S_CY, S_YAW, S_YAW_RATE, S_STANCE_S, S_SWING_S, S_COUNT };
/* the robot's constants (`c`): nominal height, reach, capture gain, then foot offsets (feet, 2), sole headings (feet) */
enum { C_HEIGHT, C_REACH, C_GAIN, C_END_SHARE, C_COUNT };

/* Python's float remainder (`_wrap`'s `%` by 2 pi): the sign of the divisor */
static double wb_wrap(double angle) {
  const double pi = 3.141592653589793, two_pi = 2 * 3.141592653589793;
  double mod = fmod(angle + pi, two_pi);
  if (mod) {
    if (mod < 0) mod += two_pi;
  } else {
    mod = copysign(0.0, two_pi);
  }
  return mod - pi;
}

/* One swing of foot f over nodes [first, last): its placement velocities into vxy and its sole's yaw rates into yaw
 * (NULL: no soles); the swing's start position (start_xy) and heading (start_yaw) move to its landing. */
static void wb_swing(int64_t f, int64_t first, int64_t last, int64_t n_feet, const double *progress,
                     const double *node_times, const double *in, const double *c, double s_now, double *start_xy,
                     double *start_yaw, double *vxy, double *yaw) {
  const double *offset = c + C_COUNT + 2 * f, swing_s = in[S_SWING_S], t = in[S_T], rate = in[S_YAW_RATE];
  double s_first = progress[first * n_feet + f], lift_off_t = (t + node_times[first]) - s_first * swing_s;
  double touch_down_t = lift_off_t + swing_s, ahead_s = touch_down_t - t;
  double s0 = lift_off_t <= t ? s_now : 0.0, left = 1 - 3 * (s0 * s0) + 2 * (s0 * s0 * s0);
  int has_shape = left > c[C_END_SHARE];
  double angle = in[S_YAW] + rate * ahead_s, cos_a = cos(angle), sin_a = sin(angle);
  double lever_x = cos_a * offset[0] - sin_a * offset[1], lever_y = sin_a * offset[0] + cos_a * offset[1];
  double hip_x = (in[S_QX] + ahead_s * in[S_CX]) + lever_x, hip_y = (in[S_QY] + ahead_s * in[S_CY]) + lever_y;
  double root = sqrt(c[C_HEIGHT] / 9.81);
  double capture_x = c[C_GAIN] * (in[S_VX] - in[S_CX]) * root, capture_y = c[C_GAIN] * (in[S_VY] - in[S_CY]) * root;
  double step_x = (in[S_CX] + rate * -lever_y) * in[S_STANCE_S] / 2 + capture_x;
  double step_y = (in[S_CY] + rate * lever_x) * in[S_STANCE_S] / 2 + capture_y;
  double reach = sqrt(step_x * step_x + step_y * step_y), target_x, target_y, turn;
  int64_t k;
  if (reach > c[C_REACH]) {
    double scale = c[C_REACH] / reach;
    step_x = step_x * scale;
    step_y = step_y * scale;
  }
  target_x = hip_x + step_x;
  target_y = hip_y + step_y;
  turn = wb_wrap(((in[S_YAW] + rate * (ahead_s + in[S_STANCE_S] / 2)) + c[C_COUNT + 2 * n_feet + f]) - start_yaw[f]);
  if (has_shape)
    for (k = first; k < last; ++k) {
      double s = progress[k * n_feet + f], shape = 6 * s * (1 - s) / (swing_s * left);
      vxy[2 * (k * n_feet + f)] = shape * (target_x - start_xy[2 * f]);
      vxy[2 * (k * n_feet + f) + 1] = shape * (target_y - start_xy[2 * f + 1]);
      if (yaw) yaw[k * n_feet + f] = shape * turn;
    }
  start_xy[2 * f] = target_x;
  start_xy[2 * f + 1] = target_y;
  start_yaw[f] = start_yaw[f] + turn;
}

/* `References.swing_references` from the schedule's swing progress (nodes, feet; -1 in stance, node 0 at t): vxy
 * (nodes, feet, 2) and, with soles, yaw (nodes, feet), NaN where a foot stands or in a swing's free end. `feet`: the
 * measured soles' positions (feet, 3) then headings (feet); `start`: scratch of 3 per foot. */
void wbsp_swing_references(int64_t nodes, int64_t n_feet, const double *progress, const double *node_times,
                           const double *in, const double *c, const double *feet, double *start, double *vxy,
                           double *yaw) {
  int64_t f, k, first, last;
  double *start_xy = start, *start_yaw = start + 2 * n_feet;
  for (k = 0; k < 2 * nodes * n_feet; ++k) vxy[k] = NAN;
  if (yaw)
    for (k = 0; k < nodes * n_feet; ++k) yaw[k] = NAN;
  for (f = 0; f < n_feet; ++f) {
    start_xy[2 * f] = feet[3 * f];
    start_xy[2 * f + 1] = feet[3 * f + 1];
    start_yaw[f] = feet[3 * n_feet + f];
  }
  for (f = 0; f < n_feet; ++f) {
    double s_now = progress[f] >= 0 ? progress[f] : 0.0;
    for (first = 0; first < nodes; first = last) {
      double s = progress[first * n_feet + f];
      last = first + 1;
      if (s < 0) continue; /* a swing starts after a stance node or where its progress drops */
      while (last < nodes && progress[last * n_feet + f] >= 0 &&
             !(progress[last * n_feet + f] < progress[(last - 1) * n_feet + f]))
        ++last;
      wb_swing(f, first, last, n_feet, progress, node_times, in, c, s_now, start_xy, start_yaw, vxy, yaw);
    }
  }
}

/* Per new time: the old nodes before and after it among n_old (the last old node alone past them), `_sources` */
static void wb_sources(double time, const double *old_times, int64_t n_old, int64_t *first, int64_t *second) {
  int64_t after = 0, low = n_old - 2 > 0 ? n_old - 2 : 0;
  while (after < n_old && old_times[after] < time) ++after; /* np.searchsorted(side="left") */
  *first = after - 1 > 0 ? after - 1 : 0;
  *first = *first < low ? *first : low;
  *second = *first + 1 < n_old - 1 ? *first + 1 : n_old - 1;
  if (time > old_times[n_old - 1]) *first = *second = n_old - 1;
}

/* `shifted_sole_wrenches` written into the scaled initial guess x: each new input node's stance soles' columns
 * (`columns`: `starts[i]..starts[i + 1]` for sole `feet[i]`) from the last plan's wrenches at the old nodes around its
 * time with the same stance pattern, divided by x's scale (the other force entries are already the guess's). */
void wbsp_sole_wrenches(int64_t n_new, const double *new_times, int64_t n_old, const double *old_times,
                        int64_t torque_nodes, int64_t n_feet, const double *contact, const double *previous_contact,
                        const double *previous_forces, int64_t n_force, int64_t n_soles, const int64_t *feet,
                        const int64_t *starts, const int64_t *columns, const int64_t *idx_force, const double *x_scale,
                        double *x) {
  int64_t k, f, j, first, second, head = torque_nodes;
  head = head < n_new ? head : n_new;
  head = head < n_old ? head : n_old;
  for (k = 0; k < n_new; ++k) {
    double span, weight;
    int same_first = 1, same_second = 1;
    if (k < head)
      wb_sources(new_times[k], old_times, head, &first, &second);
    else
      wb_sources(new_times[k], old_times, n_old, &first, &second);
    span = old_times[second] - old_times[first];
    weight = 0.0;
    if (span > 0) {
      weight = (new_times[k] - old_times[first]) / span;
      weight = weight > 0.0 ? weight : 0.0;
      weight = weight < 1.0 ? weight : 1.0;
    }
    for (f = 0; f < n_feet; ++f) {
      int stance = contact[k * n_feet + f] > 0.5;
      same_first &= (previous_contact[first * n_feet + f] > 0.5) == stance;
      same_second &= (previous_contact[second * n_feet + f] > 0.5) == stance;
    }
    if (!(same_first || same_second)) continue;
    if (!(same_first && same_second)) weight = same_first ? 0.0 : 1.0;
    for (f = 0; f < n_soles; ++f) {
      if (!(contact[k * n_feet + feet[f]] > 0.5)) continue;
      for (j = starts[f]; j < starts[f + 1]; ++j) {
        int64_t col = columns[j], entry = idx_force[k * n_force + col];
        double value = (1 - weight) * previous_forces[first * n_force + col] +
                       weight * previous_forces[second * n_force + col];
        x[entry] = value / x_scale[entry];
      }
    }
  }
}
