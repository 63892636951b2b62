/* One MPC step's data preparation and its plan's unpacking, each in one call (`control/compiled_step.py`): from the
 * measured state, the targets' few scalars, the gait clock and the last plan to the solver's inputs (p, bounds, initial
 * guess), and from the solver's x to the plan's trajectories. It chains the pieces of `MPC._step_data` the NumPy code
 * runs one by one (`References.targets`' targets and q (-) q_k, `MPC.schedule`, `_force_guess`, `_parameters`,
 * `OcpProblem.bounds`, `_initial_guess`), operation for operation and built without fused multiply-adds (the results
 * are the NumPy path's bit for bit, tests/control/test_compiled_step.py). The MPC's own CasADi functions (q (-) q over
 * the nodes, the plan) are called here through their generated C entry points. Why: right after the solver returns
 * the interpreter's caches are cold and each of a step's ~250 small NumPy calls costs 2-4 us. */
#include <math.h>
#include <stdint.h>
#include <string.h>

typedef long long wbsp_int; /* casadi_int */
typedef int (*wbsp_fn)(const double **arg, double **res, wbsp_int *iw, double *w, int mem);

int wbsp_shift(int n_groups, const int64_t *lengths, int n_old, const double *old_times, int n_new,
               const double *new_times, int n_vars, const int64_t *group_node, const int64_t *by_column,
               const int64_t *column_start, const int64_t *target, const double *old_x, int size, double *out,
               int64_t *pos, double *weight);
int wbsp_bounds_start(const double *template_, int n, const int64_t *entries, const int64_t *flags,
                      const double *stance, const double *swing, int n_entries, const uint8_t *contact,
                      const int64_t *slack_entries, int n_slack, int soft, double *out);
int wbsp_bounds_measured(double *buf, const int64_t *m, const int64_t *const *t, const double *const *c,
                         const double *const *s, const uint8_t *contact, int relax_ee, int relax_foot);
int wbsp_swing_vz(int n, const double *progress, double piece_s, double apex_m, double liftoff_t, double touchdown_t,
                  double *out);
void wbsp_swing_references(int64_t nodes, int64_t n_feet, const double *progress, const double *node_times,
                           const double *in, const double *c, const double *feet, double *start, double *vxy,
                           double *yaw);

/* the step's scalars (`wbsp_step.scalars`), written by Python each step */
enum { K_T, K_ANCHOR_X, K_ANCHOR_Y, K_VWORLD_X, K_VWORLD_Y, K_HEIGHT, K_SUPPORT, K_FORCE_X, K_FORCE_Y, K_FORCE_Z,
       K_SOFT, K_PIN_SLACK, K_WARM, K_PREVIOUS_T, K_RELAX_EE, K_RELAX_FOOT, K_DUTY, K_PIECE_S, K_APEX, K_LIFTOFF_T,
       K_TOUCHDOWN_T, K_ANCHOR_YAW, K_YAW_RATE, K_COUNT };

/* A problem's tables and buffers, laid out once by Python (ctypes.Structure `_Step` in control/compiled_step.py:
 * the same fields in the same order). */
typedef struct {
  int64_t nq, nv, nodes, n_feet, n_force, arm, n_x, n_g, n_p, n_state0, n_slack, n_anchors, n_stand, n_x0, soles;
  double *scalars;
  const double *q, *v, *rot, *v_des, *offsets;                                   /* step inputs */
  const double *node_times, *q_nominal, *phase_offsets, *anchors, *stand;          /* anchors (t0, c0, period) */
  wbsp_fn difference, plan, velocities; /* the MPC's compiled functions (`control/measured.py`'s velocities) */
  const double **arg; /* the functions' argument and result pointers and work (their `_work` sizes) */
  double **res;
  wbsp_int *iw;
  double *w;
  double *targets, *dq_des, *progress, *swing_vz, *x0_state, *velocities_out;      /* scratch */
  uint8_t *contact_flags;                                                          /* bounds' contact (bool) */
  const double *p_template;
  int64_t p_q, p_rot, p_dq, p_v, p_force;                                          /* offsets of p's blocks */
  /* `BoundsTemplate.start` and `CompiledMeasuredBounds.write`'s call */
  const double *bounds_template;
  const int64_t *bounds_entries, *bounds_flags, *slack_entries;
  const double *bounds_stance, *bounds_swing;
  int64_t n_bounds_entries;
  const int64_t *measured_meta;
  const int64_t *const *measured_tables;
  const double *const *measured_constants;
  double **measured_inputs; /* their step inputs: joint positions, v0 joints, arm force, x0, swing v_z, ... */
  /* `ShiftedGuess`'s call (`wbsp_shift`) and the guess's tables */
  int64_t shift_groups, shift_vars;
  const int64_t *shift_lengths, *shift_group_node, *shift_by_column, *shift_column_start, *shift_target;
  int64_t *shift_pos;
  double *shift_weight, *shift_times, *old_x;
  const double *previous_x, *previous_q, *previous_times, *x_scale;
  const int64_t *idx_dq, *state0, *x0_entries, *idx_force, *slack_index;
  /* the swing placement (csrc/step_feet.c; swing_inputs NULL: none or Python's): the step's inputs, the robot's
   * constants, the measured soles, scratch, the references (nodes, feet, 2) and the soles' yaw rates (or NULL) */
  const double *swing_inputs, *swing_constants, *swing_feet;
  double *swing_start, *swing_vxy, *swing_yaw;
} wbsp_step;

/* np.mod(a, 1.0) (npy_divmod's remainder for a positive divisor) */
static double wb_mod1(double a) {
  double mod = fmod(a, 1.0);
  if (mod) {
    if (mod < 0) mod += 1.0;
  } else {
    mod = copysign(0.0, 1.0);
  }
  return mod;
}

/* `GaitClock.swing_phase` at times t + node_times (its anchors and standing intervals), into s->progress, and the
 * contact flags (progress < 0) as float (into contact) and as bool (the bounds') */
static void wb_schedule(const wbsp_step *s, double *contact) {
  const double *k = s->scalars, duty = k[K_DUTY];
  int64_t i, f, a;
  for (i = 0; i < s->nodes; ++i) {
    double time = k[K_T] + s->node_times[i], cycles;
    int standing = 0;
    if (s->n_anchors == 1) {
      cycles = s->anchors[1] + (time - s->anchors[0]) / s->anchors[2];
    } else { /* np.clip(np.searchsorted(starts, times, side="right") - 1, 0, n - 1) */
      for (a = 0; a < s->n_anchors && s->anchors[3 * a] <= time; ++a) {}
      a = a - 1 < 0 ? 0 : a - 1;
      cycles = s->anchors[3 * a + 1] + (time - s->anchors[3 * a]) / s->anchors[3 * a + 2];
    }
    for (a = 0; a < s->n_stand; ++a)
      if (time >= s->stand[2 * a] - 1e-9 && time < s->stand[2 * a + 1] - 1e-9) standing = 1;
    for (f = 0; f < s->n_feet; ++f) {
      double phase = wb_mod1(cycles + s->phase_offsets[f]), progress;
      if (standing) phase = 0.5 * (duty < 1.0 ? duty : 1.0);
      progress = duty >= 1 ? -1.0 : (phase < duty ? -1.0 : (phase - duty) / (1 - duty));
      s->progress[i * s->n_feet + f] = progress;
      contact[i * s->n_feet + f] = progress < 0 ? 1.0 : 0.0;
      s->contact_flags[i * s->n_feet + f] = progress < 0;
    }
  }
}

/* `References.targets`' targets (q_nominal with the stance offsets, the anchor moved at the commanded velocity, the
 * height command, the yaw's quaternion) and dq_des = q (-) targets over the nodes (the MPC's compiled `difference`) */
static int wb_targets(const wbsp_step *s) {
  const double *k = s->scalars;
  int64_t i, j, nq = s->nq;
  for (i = 0; i < s->nodes; ++i) {
    double *row = s->targets + i * nq;
    for (j = 0; j < nq; ++j) row[j] = s->q_nominal[j];
    if (s->offsets)
      for (j = 7; j < nq; ++j) row[j] += s->offsets[i * (nq - 7) + j - 7];
    row[0] = k[K_ANCHOR_X] + s->node_times[i] * k[K_VWORLD_X];
    row[1] = k[K_ANCHOR_Y] + s->node_times[i] * k[K_VWORLD_Y];
    if (!isnan(k[K_HEIGHT])) row[2] = k[K_HEIGHT];
    row[3] = 0.0;
    row[4] = 0.0;
    {
      double yaw = k[K_ANCHOR_YAW] + k[K_YAW_RATE] * s->node_times[i], half = yaw / 2;
      row[5] = sin(half);
      row[6] = cos(half);
    }
  }
  s->arg[0] = s->q;
  s->arg[1] = s->targets;
  s->res[0] = s->dq_des;
  return s->difference(s->arg, s->res, s->iw, s->w, 0);
}

/* `MPC._force_guess` (N, n_force): the support shared over each node's stance feet, the arm's force the command's */
static void wb_forces(const wbsp_step *s, const double *contact, double *forces) {
  const double *k = s->scalars;
  int64_t i, f, n_in = s->nodes - 1;
  memset(forces, 0, sizeof(double) * (size_t)(n_in * s->n_force));
  for (i = 0; i < n_in; ++i) {
    double n_stance = 0.0;
    for (f = 0; f < s->n_feet; ++f) n_stance += contact[i * s->n_feet + f];
    n_stance = n_stance > 1 ? n_stance : 1;
    for (f = 0; f < s->n_feet; ++f)
      forces[i * s->n_force + 3 * f + 2] = contact[i * s->n_feet + f] * k[K_SUPPORT] / n_stance;
    if (s->arm)
      for (f = 0; f < 3; ++f) forces[i * s->n_force + 3 * s->n_feet + f] = k[K_FORCE_X + f];
  }
}

/* `MPC._parameters`: the template with the step's reference configuration, rotation, targets, v_des and forces */
static void wb_parameters(const wbsp_step *s, const double *forces, double *p) {
  int64_t n_in = s->nodes - 1;
  memcpy(p, s->p_template, sizeof(double) * (size_t)s->n_p);
  memcpy(p + s->p_q, s->q, sizeof(double) * (size_t)s->nq);
  memcpy(p + s->p_v, s->v_des, sizeof(double) * (size_t)s->nv);
  memcpy(p + s->p_rot, s->rot, sizeof(double) * 9);
  memcpy(p + s->p_dq, s->dq_des, sizeof(double) * (size_t)(s->nv * s->nodes));
  memcpy(p + s->p_force, forces, sizeof(double) * (size_t)(n_in * s->n_force));
}

/* `OcpProblem.bounds` (template, then the measured entries) into the buffer [lbx | ubx | lbg | ubg], with the
 * measured frame velocities (`MPC`'s compiled `measured_velocities`); 1 if that evaluation failed */
static int wb_bounds(const wbsp_step *s, double *bounds) {
  const double *k = s->scalars;
  int64_t j, nj = s->nq - 7;
  double **in = s->measured_inputs;
  wbsp_bounds_start(s->bounds_template, (int)(2 * s->n_x + 2 * s->n_g), s->bounds_entries, s->bounds_flags,
                    s->bounds_stance, s->bounds_swing, (int)s->n_bounds_entries, s->contact_flags, s->slack_entries,
                    (int)s->n_slack, k[K_SOFT] != 0, bounds);
  for (j = 0; j < nj; ++j) in[0][j] = s->q[7 + j]; /* the joint positions (one coordinate per joint) */
  for (j = 0; j < s->nv - 6; ++j) in[1][j] = s->v[6 + j];
  for (j = 0; j < 3; ++j) in[2][j] = k[K_FORCE_X + j];
  /* the measured feet's (and end effector's, flat feet's angular) velocities */
  s->arg[0] = s->q;
  s->arg[1] = s->v;
  s->res[0] = s->velocities_out;
  if (s->velocities(s->arg, s->res, s->iw, s->w, 0)) return 1;
  memcpy(in[6], s->velocities_out, sizeof(double) * (size_t)(3 * s->n_feet));
  if (s->arm) memcpy(in[8], s->velocities_out + 3 * s->n_feet, sizeof(double) * 3);
  if (s->soles) memcpy(in[10], s->velocities_out + 3 * (s->n_feet + s->arm), sizeof(double) * (size_t)(3 * s->n_feet));
  memcpy(in[3], s->x0_state, sizeof(double) * (size_t)s->n_x0);
  memcpy(in[4], s->swing_vz, sizeof(double) * (size_t)(s->nodes * s->n_feet));
  wbsp_bounds_measured(bounds, s->measured_meta, s->measured_tables, s->measured_constants,
                       (const double *const *)in, s->contact_flags, k[K_RELAX_EE] != 0, k[K_RELAX_FOOT] != 0);
  return 0;
}

/* `MPC._initial_guess` warm: the last plan's x re-sampled at the new node times, dq re-expressed on q, node 0 the
 * measurement, forces re-initialised, scaled, the slacks pinned (the hard OCP). Cold (the first step): Python's. */
static int wb_guess(const wbsp_step *s, const double *forces, double *x) {
  const double *k = s->scalars;
  int64_t i, n_in = s->nodes - 1, nodes = s->nodes;
  int rc = 0;
  if (k[K_WARM] == 0) return 0;
  {
    for (i = 0; i < s->n_x; ++i) s->old_x[i] = s->previous_x[i] * s->x_scale[i];
    s->arg[0] = s->q;
    s->arg[1] = s->previous_q;
    s->res[0] = s->dq_des; /* (scratch: the targets' dq_des is already in p) */
    rc = s->difference(s->arg, s->res, s->iw, s->w, 0);
    for (i = 0; i < nodes * s->nv; ++i) s->old_x[s->idx_dq[i]] = s->dq_des[i];
    for (i = 0; i < nodes; ++i) {
      s->shift_times[i] = k[K_T] + s->node_times[i];
      s->shift_times[nodes + i] = k[K_PREVIOUS_T] + s->previous_times[i];
    }
    wbsp_shift((int)s->shift_groups, s->shift_lengths, (int)nodes, s->shift_times + nodes, (int)nodes, s->shift_times,
               (int)s->shift_vars, s->shift_group_node, s->shift_by_column, s->shift_column_start, s->shift_target,
               s->old_x, (int)s->n_x, x, s->shift_pos, s->shift_weight);
    for (i = 0; i < s->n_state0; ++i) x[s->state0[i]] = s->x0_state[s->x0_entries[i]];
  }
  for (i = 0; i < n_in * s->n_force; ++i) x[s->idx_force[i]] = forces[i];
  for (i = 0; i < s->n_x; ++i) x[i] = x[i] / s->x_scale[i];
  if (k[K_PIN_SLACK] != 0)
    for (i = 0; i < s->n_slack; ++i) x[s->slack_index[i]] = 0.0;
  return rc;
}

/* The step's solver inputs into out = [p | lbx | ubx | lbg | ubg | x | contact (nodes, feet) | forces (N, n_force)]
 * (a fresh buffer per step: the solution and the recovery keep them). Returns the compiled functions' code (0: ok). */
int wbsp_prepare(const wbsp_step *s, double *out) {
  double *p = out, *bounds = p + s->n_p, *x = bounds + 2 * (s->n_x + s->n_g), *contact = x + s->n_x;
  double *forces = contact + s->nodes * s->n_feet;
  const double *k = s->scalars;
  int64_t j;
  int rc;
  wb_schedule(s, contact);
  wbsp_swing_vz((int)(s->nodes * s->n_feet), s->progress, k[K_PIECE_S], k[K_APEX], k[K_LIFTOFF_T],
                k[K_TOUCHDOWN_T], s->swing_vz);
  if (s->swing_inputs) { /* `References.swing_references`, into the measured bounds' inputs (`stage_inputs`) */
    wbsp_swing_references(s->nodes, s->n_feet, s->progress, s->node_times, s->swing_inputs, s->swing_constants,
                          s->swing_feet, s->swing_start, s->swing_vxy, s->swing_yaw);
    if (s->measured_inputs[5])
      memcpy(s->measured_inputs[5], s->swing_vxy, sizeof(double) * (size_t)(2 * s->nodes * s->n_feet));
    if (s->swing_yaw && s->measured_inputs[9])
      memcpy(s->measured_inputs[9], s->swing_yaw, sizeof(double) * (size_t)(s->nodes * s->n_feet));
  }
  rc = wb_targets(s);
  for (j = 0; j < s->n_x0; ++j) s->x0_state[j] = j < s->nv ? 0.0 : s->v[j - s->nv]; /* x_0 = [dq = 0, v] */
  wb_forces(s, contact, forces);
  wb_parameters(s, forces, p);
  rc |= wb_bounds(s, bounds);
  return rc | wb_guess(s, forces, x);
}

/* `MPC._unpack`: the plan's trajectories (q, v, a, F, tau node by node) from x and p by the compiled `plan` into
 * out; returns 1 where x and tau are finite (no NaN or inf), 0 otherwise, -1 if the evaluation failed. */
int wbsp_unpack(const wbsp_step *s, const double *x, const double *p, double *out, int64_t tau_start, int64_t n_tau) {
  double sum_x = 0.0, sum_tau = 0.0;
  int64_t i;
  s->arg[0] = x;
  s->arg[1] = p;
  s->res[0] = out;
  if (s->plan(s->arg, s->res, s->iw, s->w, 0)) return -1;
  for (i = 0; i < s->n_x; ++i) sum_x += x[i] * x[i];
  for (i = 0; i < n_tau; ++i) sum_tau += out[tau_start + i] * out[tau_start + i];
  return isfinite(sum_x + sum_tau) ? 1 : 0;
}
