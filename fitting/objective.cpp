// The fitter's objective: prepared trials, residuals, the profiled clock
// shift and the Ceres costs (see detail/objective.h and fit.h).
#include "fitting/detail/objective.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <utility>

#include "core/cpu_dispatch.h"
#include "core/error.h"
#include "core/parallel.h"
#include "fitting/force_lowpass.h"
#include "fitting/model5_impl.h"

namespace dropfit::fitting::internal {

namespace {

double sample_spacing(const TrialData& tr) {
  std::vector<double> diffs;
  for (Eigen::Index i = 1; i < tr.t_s.size(); ++i) diffs.push_back(tr.t_s[i] - tr.t_s[i - 1]);
  std::nth_element(diffs.begin(), diffs.begin() + diffs.size() / 2, diffs.end());
  return diffs[diffs.size() / 2];
}

}  // namespace

// `cover_all`: the grid reaches the trial's last sample (predictions), not
// only the window.
Prepared prepare(const TrialData& tr, const FitOptions& o, bool cover_all) {
  const Eigen::Index n = tr.t_s.size();
  if (n < 3 || tr.grf_n.size() != n)
    throw Error(fmt::format("trial {}: needs at least 3 samples and one force per time", tr.id));
  if (tr.impactor_m.size() != 0 && tr.impactor_m.size() != n)
    throw Error(fmt::format("trial {}: impactor travel has {} samples, times {}", tr.id, tr.impactor_m.size(), n));
  if (tr.surface_m.size() != 0 && tr.surface_m.size() != n)
    throw Error(fmt::format("trial {}: surface travel has {} samples, times {}", tr.id, tr.surface_m.size(), n));
  if (!(tr.impact_velocity_m_s >= 0.0) || !(tr.impactor_mass_kg > 0.0))
    throw Error(fmt::format("trial {}: impact velocity and impactor mass must be positive", tr.id));
  Prepared p;
  p.data = &tr;
  const double dt = sample_spacing(tr);
  if (!(dt > 0.0)) throw Error(fmt::format("trial {}: sample times must increase", tr.id));
  p.dt = dt;
  for (Eigen::Index i = 1; i < n; ++i)
    if (std::abs(tr.t_s[i] - tr.t_s[i - 1] - dt) > 0.01 * dt)
      throw Error(fmt::format("trial {}: samples are not uniformly spaced (t = {} s)", tr.id, tr.t_s[i]));
  int i0 = 0;
  while (i0 < n && tr.t_s[i0] < -1e-9 * dt) ++i0;
  if (i0 >= n - 2) throw Error(fmt::format("trial {}: fewer than 3 samples after contact (t >= 0)", tr.id));
  p.fit_shift = o.fit_contact_time;
  if (p.fit_shift) {
    p.shift_lo_s = o.contact_shift_min_s;
    p.shift_hi_s = o.contact_shift_max_s;
  }

  // Measured peak and the contact's end.
  int ip = i0;
  for (Eigen::Index i = i0; i < n; ++i)
    if (std::isfinite(tr.grf_n[i]) && tr.grf_n[i] > tr.grf_n[ip]) ip = static_cast<int>(i);
  p.peak_n = tr.grf_n[ip];
  p.t_peak_s = tr.t_s[ip];
  double end;
  if (o.window_end_s > 0.0) {
    end = o.window_end_s;
  } else {
    // The contact ends where the force, averaged over 5 samples, first falls
    // below the threshold (at least 2 % of the peak, so plate noise does not
    // keep the contact open) after the peak.
    const double thr = std::max(o.contact_threshold_n, 0.02 * p.peak_n);
    int last = static_cast<int>(n) - 1;
    for (Eigen::Index i = ip; i < n; ++i) {
      double sum = 0.0;
      int cnt = 0;
      for (Eigen::Index j = std::max<Eigen::Index>(i - 2, 0); j <= std::min<Eigen::Index>(i + 2, n - 1); ++j)
        if (std::isfinite(tr.grf_n[j])) { sum += tr.grf_n[j]; ++cnt; }
      if (cnt > 0 && sum / cnt < thr) {
        last = static_cast<int>(i);
        break;
      }
    }
    end = tr.t_s[last] + o.window_margin_s;
  }
  end = std::min(end, tr.t_s[n - 1]);
  p.window_end_s = end;

  const double f_noise = std::max(std::isfinite(tr.force_noise_n) ? tr.force_noise_n : o.force_noise_n,
                                  o.min_force_noise_n);
  const double m_noise = std::max(std::isfinite(tr.marker_noise_m) ? tr.marker_noise_m : o.marker_noise_m,
                                  o.min_marker_noise_m);
  const double t_from = p.shifted() ? -o.contact_search_s : 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double t = tr.t_s[i];
    if (t < t_from - 1e-9 * dt || t > end + 1e-9 * dt || !std::isfinite(tr.grf_n[i])) continue;
    p.f_idx.push_back(static_cast<int>(i));
    p.f_w.push_back((t <= p.t_peak_s ? o.loading_weight : 1.0) / f_noise);
  }
  if (o.kinematics_weight > 0.0 && tr.impactor_m.size() == n)
    for (Eigen::Index i = i0; i < n && tr.t_s[i] <= end + 1e-9 * dt; ++i)
      if (std::isfinite(tr.impactor_m[i])) p.k_idx.push_back(static_cast<int>(i));
  p.k_w = o.kinematics_weight / m_noise;

  const int os = std::max(1, o.oversample);
  p.h = dt / os;
  const double reach = (cover_all ? std::max(end, tr.t_s[n - 1]) : end) + std::max(-p.shift_lo_s, 0.0) + 3.0 * p.h;
  p.n_grid = static_cast<int>(std::ceil(reach / p.h)) + 1;
  p.impact.mass_kg = tr.impactor_mass_kg;
  p.impact.velocity_m_s = tr.impact_velocity_m_s;
  p.impact.gravity_m_s2 = tr.gravity_m_s2;
  p.impact.output_dt_s = p.h;
  p.impact.first_output_s = 0.0;
  p.impact.duration_s = (p.n_grid - 1) * p.h + 0.5 * p.h;
  return p;
}

namespace {

// Residuals of one trial from the simulated grid series and its clock shift.
template <typename T, typename D>
void fill_residuals(const Prepared& p, const std::vector<T>& grf, const std::vector<T>& imp, const D& shift, T* res) {
  const TrialData& tr = *p.data;
  int r = 0;
  for (size_t k = 0; k < p.f_idx.size(); ++k) {
    const int i = p.f_idx[k];
    const T f = T(on_grid(grf, tr.t_s[i] - shift, p.h, 0.0));
    res[r++] = (f - tr.grf_n[i]) * T(p.f_w[k]);
  }
  for (int i : p.k_idx) res[r++] = (T(on_grid(imp, tr.t_s[i], p.h, 0.0)) - tr.impactor_m[i]) * T(p.k_w);
}

}  // namespace

void residuals_at(const Prepared& p, const detail::Trace<double>& tr, double shift, double* out) {
  fill_residuals<double>(p, tr.grf, tr.impactor, shift, out);
}

// The clock shift that fits a simulated force best (doubles): a scan at a
// quarter grid step over the bound, then golden-section refinement.
double profile_shift(const Prepared& p, const std::vector<double>& grf) {
  if (!p.shifted()) return 0.0;
  const TrialData& tr = *p.data;
  auto sse = [&](double shift) {
    double s = 0.0;
    for (size_t k = 0; k < p.f_idx.size(); ++k) {
      const int i = p.f_idx[k];
      const double d = (on_grid(grf, tr.t_s[i] - shift, p.h, 0.0) - tr.grf_n[i]) * p.f_w[k];
      s += d * d;
    }
    return s;
  };
  const double step = 0.25 * p.h;
  double best = std::clamp(0.0, p.shift_lo_s, p.shift_hi_s), best_c = sse(best);
  for (double x = p.shift_lo_s; x <= p.shift_hi_s + 1e-12; x += step) {
    const double c = sse(x);
    if (c < best_c) { best_c = c; best = x; }
  }
  double lo = std::max(p.shift_lo_s, best - step), hi = std::min(p.shift_hi_s, best + step);
  const double g = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo), c1 = sse(x1), c2 = sse(x2);
  for (int it = 0; it < 30; ++it) {
    if (c1 < c2) { hi = x2; x2 = x1; c2 = c1; x1 = hi - g * (hi - lo); c1 = sse(x1); }
    else { lo = x1; x1 = x2; c1 = c2; x2 = lo + g * (hi - lo); c2 = sse(x2); }
  }
  const double x = 0.5 * (lo + hi);
  return sse(x) < best_c ? x : best;
}

// Simulates a trial's grid in doubles (the callback if given).
detail::Trace<double> simulate_window(const Prepared& p, const ParamSpace& space, const FitOptions& o,
                                      const MatParams& mp, std::atomic<long>* evals) {
  detail::Trace<double> tr;
  if (o.simulator) {
    const Simulation s = o.simulator(mp, p.impact);
    if (s.grf_n.size() < p.n_grid - 1 || s.grf_n.size() < 2)
      throw Error(fmt::format("custom simulator returned {} samples, the fit needs {}", s.grf_n.size(), p.n_grid));
    // A simulator that samples elsewhere than asked is interpolated linearly
    // onto the requested times.
    const double dt = p.impact.output_dt_s, first = p.impact.first_output_s;
    const double tol = 1e-9 * std::max(dt, 1e-12) + 1e-12;
    const bool aligned = s.t_s.size() == 0 || (std::abs(s.t_s[0] - first) < tol &&
                                               (s.t_s.size() < 2 || std::abs(s.t_s[1] - s.t_s[0] - dt) < 1e3 * tol));
    auto vec = [&](const Eigen::VectorXd& v) {
      std::vector<double> out(p.n_grid, kNaN);
      if (aligned || s.t_s.size() != v.size() || v.size() < 2) {
        for (int i = 0; i < p.n_grid; ++i) out[i] = v.size() > 0 ? v[std::min<Eigen::Index>(i, v.size() - 1)] : kNaN;
        return out;
      }
      Eigen::Index j = 0;
      for (int i = 0; i < p.n_grid; ++i) {
        const double t = first + i * dt;
        while (j + 2 < v.size() && s.t_s[j + 1] < t) ++j;
        const double a = std::clamp((t - s.t_s[j]) / (s.t_s[j + 1] - s.t_s[j]), 0.0, 1.0);
        out[i] = (1.0 - a) * v[j] + a * v[j + 1];
      }
      return out;
    };
    tr.grf = vec(s.grf_n);
    tr.impactor = vec(s.impactor_m);
    tr.surface = vec(s.surface_m);
    tr.layer1 = vec(s.layer1_m);
    tr.layer2 = vec(s.layer2_m);
  } else if (space.model == ModelKind::Model5) {
    const Simulation s = simulate_model5(mp, o.model5_geometry, p.impact);
    auto vec = [](const Eigen::VectorXd& v) { return std::vector<double>(v.data(), v.data() + v.size()); };
    tr.grf = vec(s.grf_n);
    tr.impactor = vec(s.impactor_m);
    tr.surface = vec(s.surface_m);
    tr.layer1 = vec(s.layer1_m);
    tr.layer2 = vec(s.layer2_m);
  } else {
    const ModelKind shape = space.model;
    const detail::Layout layout = detail::layout_for(shape, shape == ModelKind::Model2 && mp.m_eff_kg <= 0.0);
    detail::run_model<double>(layout, detail::to_params_t<double>(shape, mp), p.impact,
                              !space.nonlinear() && !mp.has_effects(), kRk4Step, p.n_grid, tr);
  }
  force_lowpass(tr.grf, p.h, o.force_lowpass_hz);
  if (evals) ++*evals;
  return tr;
}

namespace {

void shift_jacobian(const Prepared& p, const std::vector<double>& grf, double shift, double* out);

// The Ceres cost of one trial through a simulate callback (a user's model): model
// parameters by central differences, the clock shift analytically (the
// simulation does not depend on it).
// What the hand-written trial costs share: the blocks (parameters, then the
// trial's clock shift when fitted) and the residual count.
class TrialCostBase : public ceres::CostFunction {
 public:
  TrialCostBase(const Prepared* p, const ParamSpace* space, const FitOptions* o, std::atomic<long>* evals)
      : p_(p), space_(space), o_(o), evals_(evals) {
    mutable_parameter_block_sizes()->push_back(space->size());
    if (p->shifted()) mutable_parameter_block_sizes()->push_back(1);
    set_num_residuals(p->n_residuals());
  }

 protected:
  const Prepared* p_;
  const ParamSpace* space_;
  const FitOptions* o_;
  std::atomic<long>* evals_;
};

class NumericTrialCost : public TrialCostBase {
 public:
  using TrialCostBase::TrialCostBase;

  bool Evaluate(double const* const* u, double* res, double** jac) const override {
    const int n = space_->size(), m = p_->n_residuals();
    const double shift = p_->shifted() ? u[1][0] : 0.0;
    auto eval = [&](const double* uu, double* out) {
      try {
        const detail::Trace<double> tr = simulate_window(*p_, *space_, *o_, space_->to_mat(uu), evals_);
        fill_residuals<double>(*p_, tr.grf, tr.impactor, shift, out);
        // d res / d shift from the interpolant's derivative.
        if (jac && p_->shifted() && jac[1] && out == res) shift_jacobian(*p_, tr.grf, shift, jac[1]);
      } catch (const Error&) {
        return false;
      }
      for (int i = 0; i < m; ++i)
        if (!std::isfinite(out[i])) return false;
      return true;
    };
    if (!eval(u[0], res)) return false;
    if (jac && jac[0]) {
      std::vector<double> up(u[0], u[0] + n), rp(m), rm(m);
      for (int j = 0; j < n; ++j) {
        const double step = 1e-5 * std::max(std::abs(u[0][j]), 1.0);
        up[j] = u[0][j] + step;
        if (!eval(up.data(), rp.data())) return false;
        up[j] = u[0][j] - step;
        if (!eval(up.data(), rm.data())) return false;
        up[j] = u[0][j];
        for (int i = 0; i < m; ++i) jac[0][i * n + j] = (rp[i] - rm[i]) / (2.0 * step);
      }
    }
    return true;
  }

};

// d residual / d shift of one trial's force residuals (the simulation does
// not depend on the shift: the interpolant's time derivative); 0 for the
// impactor's.
void shift_jacobian(const Prepared& p, const std::vector<double>& grf, double shift, double* out) {
  using J1 = ceres::Jet<double, 1>;
  const TrialData& td = *p.data;
  for (size_t k = 0; k < p.f_idx.size(); ++k) {
    const int i = p.f_idx[k];
    const J1 f = on_grid(grf, J1(td.t_s[i]) - J1(shift, 0), p.h, 0.0);
    out[k] = f.v[0] * p.f_w[k];
  }
  for (int k = static_cast<int>(p.f_idx.size()); k < p.n_residuals(); ++k) out[k] = 0.0;
}

// The simulations the dual-number cost below runs: Model 5 (fitting/
// model5_impl.h) or Models 1-4 (fitting/models_impl.h), in doubles or in
// ceres::Jet.
struct Model5Sim {
  static constexpr bool kModel5 = true;
  template <typename T>
  DROPFIT_CPU_CLONES static void run(const Prepared& p, const ParamSpace& space, const FitOptions& o, const T* u, std::vector<T>* grf,
                  std::vector<T>* imp) {
    simulate_model5_t<T>(model5_params_t(space.to_params<T>(u)), o.model5_geometry, p.impact, p.n_grid, grf,
                         p.k_idx.empty() ? nullptr : imp, nullptr);
    force_lowpass(*grf, p.h, o.force_lowpass_hz);
  }
};

struct ChainSim {
  static constexpr bool kModel5 = false;
  template <typename T>
  DROPFIT_CPU_CLONES static void run(const Prepared& p, const ParamSpace& space, const FitOptions& o, const T* u, std::vector<T>* grf,
                  std::vector<T>* imp) {
    const ModelKind shape = space.model;
    const detail::Layout layout = detail::layout_for(shape, shape == ModelKind::Model2 && o.m_eff_kg == 0.0);
    detail::Trace<T> tr;
    detail::run_model<T>(layout, space.to_params(u), p.impact, !space.nonlinear(), kRk4Step, p.n_grid, tr);
    *grf = std::move(tr.grf);
    *imp = std::move(tr.impactor);
    force_lowpass(*grf, p.h, o.force_lowpass_hz);
  }
};

// The cost of one trial with exact derivatives: the simulation in dual
// numbers over the model's free parameters only (a Jet as wide as the
// chunk, not a fixed 8: Model 1's two parameters cost three doubles a
// value, not nine), the directions in chunks of at most 8 run on up to
// `threads` threads (a single Levenberg-Marquardt run, e.g. Model 5 from
// its warm start, would leave the other core idle); the clock shift's
// column analytic from the interpolant (the simulation does not depend on
// it), so it never costs a dual direction.
template <class Sim>
class DualTrialCost : public TrialCostBase {
 public:
  using TrialCostBase::TrialCostBase;

  bool Evaluate(double const* const* u, double* res, double** jac) const override {
    const int n = space_->size(), m = p_->n_residuals();
    const double shift = p_->shifted() ? u[1][0] : 0.0;
    std::vector<double> grf;
    try {
      if (jac && jac[0]) {
        // Chunks of at most 8 directions, at least one per thread.
        const int threads = std::max(1, o_->threads);
        const int n_chunks = std::max((n + 7) / 8, std::min(threads, n));
        const int per = (n + n_chunks - 1) / n_chunks;
        std::vector<std::vector<double>> grfs(n_chunks);
        std::vector<char> ok(n_chunks, 0);
        auto run = [&](int c) {
          const int first = c * per, count = std::min(per, n - first);
          if (count <= 0) { ok[c] = 1; return; }
          try {
            double* r = c == 0 ? res : nullptr;
            if constexpr (Sim::kModel5) {
              if (per <= 3) chunk<3>(u[0], first, count, shift, r, jac[0], &grfs[c]);
              else if (per <= 4) chunk<4>(u[0], first, count, shift, r, jac[0], &grfs[c]);
              else chunk<8>(u[0], first, count, shift, r, jac[0], &grfs[c]);
            } else {
              if (per <= 2) chunk<2>(u[0], first, count, shift, r, jac[0], &grfs[c]);
              else if (per <= 4) chunk<4>(u[0], first, count, shift, r, jac[0], &grfs[c]);
              else if (per <= 6) chunk<6>(u[0], first, count, shift, r, jac[0], &grfs[c]);
              else chunk<8>(u[0], first, count, shift, r, jac[0], &grfs[c]);
            }
            ok[c] = 1;
          } catch (const Error&) {
          }
        };
        parallel_for(static_cast<size_t>(n_chunks), n_chunks, [&](size_t c) { run(static_cast<int>(c)); });
        if (evals_) ++*evals_;
        for (char k : ok)
          if (!k) return false;
        grf = std::move(grfs[0]);
      } else {
        // Ceres evaluates a bounded problem's candidate point twice (its
        // projected line search tries the full step, then the trust region
        // evaluates the step it took): the same point is answered once.
        std::vector<double> key(u[0], u[0] + n);
        key.push_back(shift);
        if (key == last_key_ && !last_res_.empty()) {
          std::copy(last_res_.begin(), last_res_.end(), res);
        } else {
          std::vector<double> imp;
          Sim::template run<double>(*p_, *space_, *o_, u[0], &grf, &imp);
          if (evals_) ++*evals_;
          fill_residuals<double>(*p_, grf, imp, shift, res);
          last_key_ = std::move(key);
          last_res_.assign(res, res + m);
        }
      }
    } catch (const Error&) {
      return false;
    }
    if (jac && p_->shifted() && jac[1]) shift_jacobian(*p_, grf, shift, jac[1]);
    for (int i = 0; i < m; ++i)
      if (!std::isfinite(res[i])) return false;
    if (jac && jac[0])
      for (int i = 0; i < m * n; ++i)
        if (!std::isfinite(jac[0][i])) return false;
    return true;
  }

 private:
  // Derivatives along parameters first .. first + count - 1 (K >= count
  // dual slots), into their columns of jac (row-major, residuals x n); the
  // residuals into res when given, the simulated force into grf.
  template <int K>
  void chunk(const double* u, int first, int count, double shift, double* res, double* jac,
             std::vector<double>* grf) const {
    using J = ceres::Jet<double, K>;
    const int n = space_->size(), m = p_->n_residuals();
    std::vector<J> uj(n);
    for (int j = 0; j < n; ++j) {
      uj[j] = J(u[j]);
      if (j >= first && j < first + count) uj[j].v[j - first] = 1.0;
    }
    std::vector<J> g, z;
    Sim::template run<J>(*p_, *space_, *o_, uj.data(), &g, &z);
    std::vector<J> r(m);
    fill_residuals<J>(*p_, g, z, shift, r.data());
    for (int i = 0; i < m; ++i) {
      if (res) res[i] = r[i].a;
      for (int c = 0; c < count; ++c) jac[i * n + first + c] = r[i].v[c];
    }
    grf->resize(g.size());
    for (size_t k = 0; k < g.size(); ++k) (*grf)[k] = g[k].a;
  }

  // The last residual-only evaluation (parameters and shift, residuals);
  // one cost object belongs to one Levenberg-Marquardt run on one thread.
  mutable std::vector<double> last_key_, last_res_;
};

// One trial's residuals (doubles) with its clock shift profiled out; the
// shift is returned through `shift`.
void trial_residuals(const Prepared& p, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                     std::atomic<long>* evals, double* out, double* shift) {
  const detail::Trace<double> tr = simulate_window(p, space, o, mp, evals);
  const double s = profile_shift(p, tr.grf);
  fill_residuals<double>(p, tr.grf, tr.impactor, s, out);
  if (shift) *shift = s;
}

}  // namespace

// Residual vector (doubles) over the prepared trials, shifts profiled.
Eigen::VectorXd residual_vector(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                                const MatParams& mp, std::atomic<long>* evals, std::vector<double>* shifts) {
  int m = 0;
  for (const auto& p : preps) m += p.n_residuals();
  Eigen::VectorXd r(m);
  int off = 0;
  if (shifts) shifts->clear();
  for (const auto& p : preps) {
    double s = 0.0;
    trial_residuals(p, space, o, mp, evals, r.data() + off, &s);
    if (shifts) shifts->push_back(s);
    off += p.n_residuals();
  }
  return r;
}

double cost_of(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
               const MatParams& mp, std::atomic<long>* evals) {
  try {
    const Eigen::VectorXd r = residual_vector(preps, space, o, mp, evals);
    const double c = 0.5 * r.squaredNorm();
    return std::isfinite(c) ? c : std::numeric_limits<double>::infinity();
  } catch (const Error&) {
    return std::numeric_limits<double>::infinity();
  }
}

// The effective stiffness the training data show: peak force over the
// largest measured travel (energy balance when travel was not measured).
double effective_stiffness(const std::vector<Prepared>& preps) {
  std::vector<double> ks;
  for (const auto& p : preps) {
    const TrialData& tr = *p.data;
    double x_max = -1.0;
    for (int i : p.k_idx) x_max = std::max(x_max, tr.impactor_m[i]);
    const double F = p.peak_n;
    if (!(F > 0.0)) continue;
    if (!(x_max > 1e-4)) {
      const double v = std::max(tr.impact_velocity_m_s, 0.5);
      x_max = tr.impactor_mass_kg * v * v / F;
    }
    ks.push_back(F / x_max);
  }
  if (ks.empty()) return kNaN;
  std::sort(ks.begin(), ks.end());
  return ks[ks.size() / 2];
}

// Builds the Ceres problem over the prepared trials; `shifts` holds one
// value per trial (used only where the trial's clock is fitted).
std::unique_ptr<ceres::Problem> make_problem(const std::vector<Prepared>& preps, const ParamSpace& space,
                                             const FitOptions& o, double* u, std::vector<double>& shifts,
                                             std::atomic<long>* evals, std::vector<double*>* blocks) {
  ceres::Problem::Options po;
  auto problem = std::make_unique<ceres::Problem>(po);
  const bool numeric = static_cast<bool>(o.simulator);
  blocks->assign(1, u);
  problem->AddParameterBlock(u, space.size());
  for (size_t t = 0; t < preps.size(); ++t) {
    const Prepared& p = preps[t];
    std::vector<double*> params = {u};
    if (p.shifted()) {
      problem->AddParameterBlock(&shifts[t], 1);
      shifts[t] = std::clamp(shifts[t], p.shift_lo_s, p.shift_hi_s);
      problem->SetParameterLowerBound(&shifts[t], 0, p.shift_lo_s);
      problem->SetParameterUpperBound(&shifts[t], 0, p.shift_hi_s);
      params.push_back(&shifts[t]);
      blocks->push_back(&shifts[t]);
    }
    ceres::CostFunction* cf;
    if (numeric) {
      cf = new NumericTrialCost(&p, &space, &o, evals);
    } else if (o.model == ModelKind::Model5) {
      cf = new DualTrialCost<Model5Sim>(&p, &space, &o, evals);
    } else {
      cf = new DualTrialCost<ChainSim>(&p, &space, &o, evals);
    }
    problem->AddResidualBlock(cf, nullptr, params);
  }
  for (int i = 0; i < space.size(); ++i) {
    problem->SetParameterLowerBound(u, i, space.free[i].lower);
    problem->SetParameterUpperBound(u, i, space.free[i].upper);
  }
  return problem;
}

// Each channel's share of the cost at the optimum.
std::vector<ChannelShare> channel_shares(const std::vector<Prepared>& preps, const Eigen::VectorXd& r,
                                         std::vector<std::string>* warnings) {
  ChannelShare ch[2];
  ch[0].name = "force";
  ch[1].name = "impactor";
  double ss[2] = {0, 0}, lag[2] = {0, 0}, lag_n[2] = {0, 0};
  int off = 0;
  for (const auto& p : preps) {
    const int nf = static_cast<int>(p.f_idx.size()), nk = static_cast<int>(p.k_idx.size());
    for (int c = 0; c < 2; ++c) {
      const int a = off + (c == 0 ? 0 : nf), len = c == 0 ? nf : nk;
      for (int i = 0; i < len && a + i < r.size(); ++i) {
        ss[c] += r[a + i] * r[a + i];
        ++ch[c].n;
        if (i > 0) { lag[c] += r[a + i] * r[a + i - 1]; lag_n[c] += 1; }
      }
    }
    off += nf + nk;
  }
  const double total = ss[0] + ss[1];
  std::vector<ChannelShare> out;
  for (int c = 0; c < 2; ++c) {
    if (ch[c].n == 0) continue;
    ch[c].share = total > 0.0 ? ss[c] / total : 0.0;
    ch[c].rms_sigma = std::sqrt(ss[c] / ch[c].n);
    ch[c].lag1_autocorrelation = ss[c] > 0.0 && lag_n[c] > 0 ? (lag[c] / lag_n[c]) / (ss[c] / ch[c].n) : 0.0;
    ch[c].structured = ch[c].rms_sigma > 2.0 && ch[c].lag1_autocorrelation > 0.5;
    out.push_back(ch[c]);
  }
  if (out.size() == 2 && out[0].structured != out[1].structured) {
    const ChannelShare& s = out[0].structured ? out[0] : out[1];
    const ChannelShare& q = out[0].structured ? out[1] : out[0];
    warnings->push_back(fmt::format(
        "{} carries structured residual ({:.1f} noise SDs RMS, lag-1 autocorrelation {:.2f}) that {} does not "
        "({:.1f} SDs): the model misses something that channel sees",
        s.name, s.rms_sigma, s.lag1_autocorrelation, q.name, q.rms_sigma));
  }
  return out;
}

}  // namespace dropfit::fitting::internal
