/* The C++ driver of wbmpc's Fatrop shim: what Fatrop's own C interface (fatrop_ocp_c_create / _solve) does, built
 * from the same exported pieces (FatropOcpCMapping on our callbacks, IpAlgBuilder<OcpType>), plus two things its
 * C interface lacks:
 * - a primal-dual warm start: the builder's equality-multiplier initializer (a least-squares solve, one KKT
 *   factorisation per solve) is replaced by one that, when asked, starts the slacks, bound and equality
 *   multipliers from this instance's last converged solution (IpIterate's setters are defined in the shipped
 *   ip_iterate.hpp) and else delegates; the builder keeps that initializer in a private member, reached by the
 *   standard explicit-instantiation access rule;
 * - an exit by exception: a callback past the deadline (or seeing non-finite values at the start point) throws
 *   (wb_throw), the solve catches it and returns -1 with the last accepted iterate in place (the C files are
 *   compiled with -fexceptions so the exception unwinds through their frames too). */
#include <algorithm>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <fatrop/common/options.hpp>
#include <fatrop/common/printing.hpp>
#include <fatrop/ip_algorithm/ip_alg_builder.hpp>
#include <fatrop/ip_algorithm/ip_algorithm.hpp>
#include <fatrop/ocp/hessian.hpp>
#include <fatrop/ocp/jacobian.hpp>
#include <fatrop/ip_algorithm/ip_data.hpp>
#include <fatrop/ip_algorithm/ip_eq_mult_initializer.hpp>
#include <fatrop/ip_algorithm/ip_iterate.hpp>
#include <fatrop/ocp/pd_solver_orig.hpp>
#include <fatrop/ocp/OCPCInterfaceInternal.hpp>
#include <fatrop/ocp/problem_info.hpp>
#include <fatrop/ocp/type.hpp>

using namespace fatrop;

extern "C" void wb_throw(const char* what) { throw std::runtime_error(what); }

namespace {
template <typename Tag, typename Tag::type Member> struct Reach {
  friend typename Tag::type reach(Tag) { return Member; }
};
struct EqMultSlot {
  typedef std::shared_ptr<IpEqMultInitializerBase> IpAlgBuilder<OcpType>::*type;
  friend type reach(EqMultSlot);
};
template struct Reach<EqMultSlot, &IpAlgBuilder<OcpType>::eq_mult_initializer_>;

class WarmEqMult : public IpEqMultInitializerBase {
 public:
  WarmEqMult(const std::shared_ptr<IpData<OcpType>>& data, const std::shared_ptr<IpEqMultInitializer<OcpType>>& base)
      : data_(data), base_(base), duals_(data->current_iterate().dual_eq().m()),
        slacks_(data->current_iterate().primal_s().m()), z_l_(slacks_.m()), z_u_(slacks_.m()),
        s_(slacks_.m()), zl_(slacks_.m()), zu_(slacks_.m()) {}
  /* runs last in Fatrop's initializer: the warm start replaces its slacks, bound multipliers (z = 1) and
     equality multipliers (least squares) by the last converged solution's, slacks kept inside the bounds */
  void initialize_eq_mult(bool trial_it) override {
    if (trial_it || !(use_ || given_)) { base_->initialize_eq_mult(trial_it); return; }
    IpIterate<OcpType>& it = data_->current_iterate();
    const Index m = slacks_.m();
    if (given_) { start_from_given(it); return; }
    const double *lower = it.lower_bounds().data(), *upper = it.upper_bounds().data();
    for (Index i = 0; i < m; ++i) {
      const bool has_l = it.lower_bounded()[i], has_u = it.upper_bounded()[i];
      double value = slacks_(i);
      const double l_gap = has_l ? 1e-8 * std::max(1.0, std::abs(lower[i])) : 0.0;
      const double u_gap = has_u ? 1e-8 * std::max(1.0, std::abs(upper[i])) : 0.0;
      if (has_l && has_u && upper[i] - lower[i] <= l_gap + u_gap) value = 0.5 * (lower[i] + upper[i]);
      else {
        if (has_l) value = std::max(value, lower[i] + l_gap);
        if (has_u) value = std::min(value, upper[i] - u_gap);
      }
      s_(i) = value;
      zl_(i) = has_l ? (z_l_(i) > 0 ? z_l_(i) : 1.0) : 0.0;
      zu_(i) = has_u ? (z_u_(i) > 0 ? z_u_(i) : 1.0) : 0.0;
    }
    it.set_primal_s(s_);
    it.set_dual_bounds_l(zl_);
    it.set_dual_bounds_u(zu_);
    it.set_dual_eq(duals_);
  }
  /* multipliers given by the caller (the last solution's, mapped row by row to this call, wb_solve): the slacks stay
     Fatrop's (g(x0) pushed inside the bounds), each bound multiplier at least z_floor_ / its slack's distance to
     the bound (complementarity z s >= z_floor_, the barrier parameter the solve starts from) */
  void start_from_given(IpIterate<OcpType>& it) {
    const Index m = slacks_.m();
    const double *lower = it.lower_bounds().data(), *upper = it.upper_bounds().data();
    for (Index i = 0; i < m; ++i) {
      const double s = it.primal_s()(i);
      const bool has_l = it.lower_bounded()[i], has_u = it.upper_bounded()[i];
      zl_(i) = has_l ? std::max(given_zl_(i), z_floor_ / std::max(s - lower[i], 1e-12)) : 0.0;
      zu_(i) = has_u ? std::max(given_zu_(i), z_floor_ / std::max(upper[i] - s, 1e-12)) : 0.0;
    }
    it.set_dual_bounds_l(zl_);
    it.set_dual_bounds_u(zu_);
    it.set_dual_eq(given_duals_);
  }
  /* the converged solution's multipliers and slacks, copied as memory (VecRealView's element-wise assignment took
     ~220k instructions per b1_z1 solve, outside Fatrop's timers) */
  void store(const IpIterate<OcpType>& it) {
    copy(duals_, it.dual_eq());
    copy(slacks_, it.primal_s());
    copy(z_l_, it.dual_bounds_l());
    copy(z_u_, it.dual_bounds_u());
    valid_ = true;
  }
  template <typename Vector> static void copy(VecRealAllocated& to, const Vector& from) {
    if (to.m() == from.m() && from.m() > 0) std::memcpy(to.data(), from.data(), sizeof(double) * from.m());
  }
  void register_options(OptionRegistry& registry) override { base_->register_options(registry); }
  void reset() override { base_->reset(); }
  std::shared_ptr<IpData<OcpType>> data_;
  std::shared_ptr<IpEqMultInitializer<OcpType>> base_;
  VecRealAllocated duals_, slacks_, z_l_, z_u_, s_, zl_, zu_;
  VecRealAllocated given_duals_{duals_.m()}, given_zl_{slacks_.m()}, given_zu_{slacks_.m()};
  double z_floor_ = 0.0;
  bool use_ = false, valid_ = false, given_ = false;
};

struct Driver {
  explicit Driver(FatropOcpCInterface* ocp) : m(std::make_shared<FatropOcpCMapping>(ocp)) {
    IpAlgBuilder<OcpType> builder(m);
    builder.with_options_registry(&options);
    builder.create_ipdata();
    builder.create_pdsolver();
    auto base = std::make_shared<IpEqMultInitializer<OcpType>>(builder.get_ipdata(), builder.get_pd_solver());
    warm = std::make_shared<WarmEqMult>(builder.get_ipdata(), base);
    options.register_options(*warm);
    builder.*reach(EqMultSlot()) = warm;
    pd_solver = builder.get_pd_solver();
    Banner::set_suppress(true);
    algo = builder.build();
    data = builder.get_ipdata();
    const ProblemInfo<OcpType>& info = algo->info();
    FatropOcpCDims& s = m->s;
    s.nx = info.dims.number_of_states.data();
    s.nu = info.dims.number_of_controls.data();
    s.ng = info.dims.number_of_eq_constraints.data();
    s.ng_ineq = info.dims.number_of_ineq_constraints.data();
    s.K = info.dims.K;
    s.ux_offs = info.offsets_primal_u.data();
    s.g_offs = info.offsets_g_eq_path.data();
    s.dyn_offs = info.offsets_dyn.data();
    s.dyn_eq_offs = info.offsets_g_eq_dyn.data();
    s.g_ineq_offs = info.offsets_g_eq_slack.data();
    s.n_ineqs = info.number_of_g_eq_slack;
  }
  std::shared_ptr<FatropOcpCMapping> m;
  OptionRegistry options;
  std::shared_ptr<WarmEqMult> warm;
  std::shared_ptr<PdSolverOrig<OcpType>> pd_solver;
  std::shared_ptr<IpAlgorithm<OcpType>> algo;
  std::shared_ptr<IpData<OcpType>> data;
  IpSolverReturnFlag flag = IpSolverReturnFlag::Unknown;
  FatropOcpCStats stats{};
};
}  // namespace

extern "C" {
void* wbd_create(void* ocp) {
  try { return new Driver(static_cast<FatropOcpCInterface*>(ocp)); } catch (const std::exception&) { return nullptr; }
}
void wbd_destroy(void* d) { delete static_cast<Driver*>(d); }
int wbd_option_double(void* d, const char* name, double value) {
  try { static_cast<Driver*>(d)->options.set_option<double>(name, value); return 0; } catch (const std::exception&) { return 1; }
}
/* Fatrop's options, and one its registry lacks: "max_iterative_refinement", at most that many refinement solves after
   each search direction (Fatrop's default 5; 0 also skips the KKT residual that decides whether to refine) */
int wbd_option_int(void* d, const char* name, int value) {
  Driver* driver = static_cast<Driver*>(d);
  if (std::strcmp(name, "max_iterative_refinement") == 0) {
    if (value < 0) return 1;
    driver->pd_solver->set_max_it_ref(value);
    return 0;
  }
  try { driver->options.set_option<int>(name, value); return 0; } catch (const std::exception&) { return 1; }
}
int wbd_option_bool(void* d, const char* name, int value) {
  try { static_cast<Driver*>(d)->options.set_option<bool>(name, value != 0); return 0; } catch (const std::exception&) { return 1; }
}
/* the buffers wb_solve fills with given multipliers in Fatrop's order: equality rows (dual_eq), then the lower and
   upper bound multipliers of the slacks; sizes[0] = number of equality rows, sizes[1] = number of slacks */
double* wbd_given(void* handle, int which, int* sizes) {
  WarmEqMult& w = *static_cast<Driver*>(handle)->warm;
  sizes[0] = w.given_duals_.m(); sizes[1] = w.given_zl_.m();
  return which == 0 ? w.given_duals_.data() : which == 1 ? w.given_zl_.data() : w.given_zu_.data();
}
/* warm: 1 start the equality multipliers from this instance's last converged solution (if it has one); 2 from the
   given ones (wbd_given), bound multipliers at least z_floor / distance */
int wbd_solve(void* handle, int warm, double z_floor) {
  Driver* d = static_cast<Driver*>(handle);
  d->warm->use_ = warm == 1 && d->warm->valid_;
  d->warm->given_ = warm == 2;
  d->warm->z_floor_ = z_floor;
  int ret;
  d->flag = IpSolverReturnFlag::Unknown;
  try {
    d->flag = d->algo->optimize();
    ret = d->flag == IpSolverReturnFlag::Success ? 0 : 1;
  } catch (const std::exception&) {
    ret = -1;
  }
  if (ret == 0 || d->flag == IpSolverReturnFlag::StopAtAcceptablePoint) d->warm->store(d->data->current_iterate());
  return ret;
}
/* the instance forgets its last converged solution: the next warm start (1) falls back to Fatrop's own */
void wbd_forget(void* d) { static_cast<Driver*>(d)->warm->valid_ = false; }
const double* wbd_primal(void* d) { return static_cast<Driver*>(d)->algo->solution_primal().data(); }
const double* wbd_dual(void* d) { return static_cast<Driver*>(d)->algo->solution_dual().data(); }
const void* wbd_dims(void* d) { return &static_cast<Driver*>(d)->m->s; }
const void* wbd_stats(void* handle) {
  Driver* d = static_cast<Driver*>(handle);
  IpTimingStatistics& t = d->data->timing_statistics();
  FatropOcpCStats& s = d->stats;
  s.compute_sd_time = t.compute_search_dir.elapsed();
  s.eval_hess_time = t.eval_hessian.elapsed();
  s.eval_jac_time = t.eval_jacobian.elapsed();
  s.eval_cv_time = t.eval_constraint_violation.elapsed();
  s.eval_grad_time = t.eval_gradient.elapsed();
  s.eval_obj_time = t.eval_objective.elapsed();
  s.initialization_time = t.initialization.elapsed();
  s.time_total = t.full_algorithm.elapsed();
  s.iterations_count = d->data->iteration_number();
  s.return_flag = int(d->flag);
  return &s;
}
}
