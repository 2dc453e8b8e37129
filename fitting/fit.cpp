// Fitting the mat models to drop-test trials: the objective, the
// parameterisation, the optimisers (Ceres multi-start, Corana annealing),
// the covariance and the validation. See fit.h for the method.
#include "fitting/fit.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <numeric>
#include <random>
#include <sstream>

#include "core/error.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kRk4Step = 1e-4;

inline bool finite_all(double x) { return std::isfinite(x); }
template <typename J>
bool finite_all(const J& x) {
  return ceres::isfinite(x);  // value and derivatives
}

// ---------------------------------------------------------------------------
// Parameter space: what the optimiser moves (u) and how it maps onto the
// model's parameters.
enum class Transform { Log, Fraction, Linear };

struct FreeParam {
  std::string name;       // MatParams field, or "m1_fraction"
  Transform transform = Transform::Log;
  double scale = 1.0;     // Linear: value = scale * u
  double lower = 0.0, upper = 0.0;            // bounds on u
  double start_lo = 0.0, start_hi = 0.0;      // start range on u
};

bool is_stiffness_or_damping(const std::string& name) {
  return name.size() >= 2 && (name[0] == 'k' || name[0] == 'r') && std::isdigit(static_cast<unsigned char>(name[1]));
}

struct ParamSpace {
  ModelKind model;
  MatParams base;  // fixed values (masses, effects), free ones overwritten
  std::vector<FreeParam> free;
  double total_mass = 0.0;

  int size() const { return static_cast<int>(free.size()); }

  double value_of(const FreeParam& f, double u) const {
    switch (f.transform) {
      case Transform::Log: return std::exp(u);
      case Transform::Fraction: return total_mass * u;
      default: return f.scale * u;
    }
  }

  MatParams to_mat(const double* u) const {
    MatParams p = base;
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      if (f.transform == Transform::Fraction) {
        p.m1_kg = total_mass * u[i];
        p.m2_kg = total_mass * (1.0 - u[i]);
      } else {
        set_parameter(p, f.name, value_of(f, u[i]));
      }
    }
    return p;
  }

  Eigen::VectorXd from_mat(const MatParams& p) const {
    Eigen::VectorXd u(size());
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      double v;
      if (f.transform == Transform::Fraction) v = p.m1_kg / total_mass;
      else if (f.transform == Transform::Log) v = std::log(std::max(get_parameter(p, f.name), 1e-300));
      else v = get_parameter(p, f.name) / f.scale;
      u[i] = std::clamp(v, f.lower, f.upper);
    }
    return u;
  }

  // The templated map for automatic differentiation.
  template <typename T>
  detail::ParamsT<T> to_params(const T* u) const {
    detail::ParamsT<T> p = detail::to_params_t<T>(model == ModelKind::Model5 ? ModelKind::Model4 : model, base);
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      const std::string& n = f.name;
      T v;
      if (f.transform == Transform::Log) {
        using std::exp;
        v = exp(u[i]);
      } else if (f.transform == Transform::Fraction) {
        p.m1 = T(total_mass) * u[i];
        p.m2 = T(total_mass) * (T(1.0) - u[i]);
        continue;
      } else {
        v = T(f.scale) * u[i];
      }
      if (n == "k1_n_m") p.k[0] = v;
      else if (n == "k2_n_m") p.k[1] = v;
      else if (n == "k3_n_m") p.k[2] = v;
      else if (n == "r1_n_s_m") p.r[0] = v;
      else if (n == "r2_n_s_m") p.r[1] = v;
      else if (n == "r3_n_s_m") p.r[2] = v;
      else if (n == "m_eff_kg") p.m1 = v;
      else if (n == "m1_kg") p.m1 = v;
      else if (n == "m2_kg") p.m2 = v;
      else if (n == "k1_cubic_n_m3") { p.k1_cubic = v; p.cubic = true; }
      else if (n == "r1_unload_n_s_m") { p.r1_unload = v; p.hysteresis = true; }
      else if (n == "maxwell_k_n_m") { p.maxwell_k = v; p.maxwell = true; }
      else if (n == "maxwell_tau_s") { p.maxwell_tau = v; p.maxwell = true; }
    }
    return p;
  }

  // Are effects (the nonlinear path) in play?
  bool nonlinear() const {
    if (base.has_effects()) return true;
    for (const auto& f : free)
      if (f.name == "k1_cubic_n_m3" || f.name == "r1_unload_n_s_m" || f.name == "maxwell_k_n_m" ||
          f.name == "maxwell_tau_s")
        return true;
    return false;
  }
};

FreeParam log_param(const std::string& name, double lo, double hi) {
  FreeParam f;
  f.name = name;
  f.transform = Transform::Log;
  f.start_lo = std::log(lo);
  f.start_hi = std::log(hi);
  f.lower = std::log(lo / 10.0);
  f.upper = std::log(hi * 10.0);
  return f;
}

ParamSpace make_space(const FitOptions& o) {
  ParamSpace s;
  s.model = o.model;
  s.total_mass = o.m1_kg + o.m2_kg;
  s.base = o.effects;
  s.base.k1_n_m = s.base.k2_n_m = s.base.k3_n_m = 0.0;
  s.base.r1_n_s_m = s.base.r2_n_s_m = s.base.r3_n_s_m = 0.0;
  s.base.m1_kg = o.m1_kg;
  s.base.m2_kg = o.m2_kg;
  s.base.m_eff_kg = o.m_eff_kg >= 0.0 ? o.m_eff_kg : 0.0;
  const ModelKind shape = o.model == ModelKind::Model5 ? ModelKind::Model4 : o.model;
  for (const auto& name : parameter_names(shape, false)) {
    if (name[0] == 'k') s.free.push_back(log_param(name, o.k_min_n_m, o.k_max_n_m));
    else s.free.push_back(log_param(name, o.r_min_n_s_m, o.r_max_n_s_m));
  }
  if (o.model == ModelKind::Model2 && o.m_eff_kg < 0.0) {
    FreeParam f;
    f.name = "m_eff_kg";
    f.transform = Transform::Linear;
    f.scale = 1.0;
    f.lower = 0.01;
    f.upper = std::max(s.total_mass, 0.02);
    f.start_lo = 0.1 * s.total_mass;
    f.start_hi = 0.6 * s.total_mass;
    s.free.push_back(f);
  }
  if (o.masses_free && (shape == ModelKind::Model3 || shape == ModelKind::Model4)) {
    FreeParam f;
    f.name = "m1_fraction";
    f.transform = Transform::Fraction;
    f.lower = 0.05;
    f.upper = 0.95;
    f.start_lo = 0.2;
    f.start_hi = 0.7;
    s.free.push_back(f);
  }
  for (const auto& name : o.free_effects) {
    if (name == "k1_cubic_n_m3") {
      FreeParam f;
      f.name = name;
      f.transform = Transform::Linear;
      f.scale = 1e7;
      f.lower = 0.0;
      f.upper = 1e3;
      f.start_lo = 0.0;
      f.start_hi = 5.0;
      s.free.push_back(f);
    } else if (name == "r1_unload_n_s_m") {
      s.free.push_back(log_param(name, o.r_min_n_s_m, o.r_max_n_s_m));
    } else if (name == "maxwell_k_n_m") {
      s.free.push_back(log_param(name, o.k_min_n_m, o.k_max_n_m));
    } else if (name == "maxwell_tau_s") {
      s.free.push_back(log_param(name, 1e-3, 0.3));
    } else {
      throw Error(fmt::format("fit: '{}' is not an effect parameter that can be fitted", name));
    }
  }
  return s;
}

// ---------------------------------------------------------------------------
// A trial prepared for the objective: the window, the sample mapping, the
// weights.
struct Prepared {
  const TrialData* data = nullptr;
  Impact impact;            // simulates exactly the window's samples
  int n_sim = 0;            // simulated samples
  int i0 = 0;               // first measured index in the window
  int k0 = 0;               // simulated index of measured index i0
  int n_win = 0;            // measured samples in the window
  double window_end_s = 0.0;
  double t_peak_s = 0.0, peak_n = 0.0;
  std::vector<double> force_w;                   // per window sample
  std::vector<int> kin_idx, surf_idx;            // window offsets with finite measurements
  int n_residuals() const {
    return n_win + static_cast<int>(kin_idx.size()) + static_cast<int>(surf_idx.size());
  }
};

Prepared prepare(const TrialData& tr, const FitOptions& o) {
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
  std::vector<double> diffs;
  for (Eigen::Index i = 1; i < n; ++i) diffs.push_back(tr.t_s[i] - tr.t_s[i - 1]);
  std::nth_element(diffs.begin(), diffs.begin() + diffs.size() / 2, diffs.end());
  const double dt = diffs[diffs.size() / 2];
  if (!(dt > 0.0)) throw Error(fmt::format("trial {}: sample times must increase", tr.id));
  int i0 = 0;
  while (i0 < n && tr.t_s[i0] < -1e-9 * dt) ++i0;
  if (i0 >= n - 2) throw Error(fmt::format("trial {}: fewer than 3 samples after contact (t >= 0)", tr.id));
  const double t0 = std::max(tr.t_s[i0], 0.0);
  for (Eigen::Index i = i0; i < n; ++i)
    if (std::abs(tr.t_s[i] - (t0 + (i - i0) * dt)) > 0.01 * dt)
      throw Error(fmt::format("trial {}: samples are not uniformly spaced (t = {} s)", tr.id, tr.t_s[i]));
  p.k0 = static_cast<int>(std::floor(t0 / dt + 1e-9));
  const double first = std::max(0.0, t0 - p.k0 * dt);
  p.i0 = i0;

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
  int i1 = i0;
  while (i1 + 1 < n && tr.t_s[i1 + 1] <= end + 1e-9 * dt) ++i1;
  p.n_win = i1 - i0 + 1;
  p.n_sim = p.k0 + p.n_win;
  p.impact.mass_kg = tr.impactor_mass_kg;
  p.impact.velocity_m_s = tr.impact_velocity_m_s;
  p.impact.gravity_m_s2 = tr.gravity_m_s2;
  p.impact.output_dt_s = dt;
  p.impact.first_output_s = first;
  p.impact.duration_s = first + (p.n_sim - 1) * dt + 0.5 * dt;

  p.force_w.resize(p.n_win);
  for (int w = 0; w < p.n_win; ++w) {
    const double t = tr.t_s[i0 + w];
    p.force_w[w] = (t <= p.t_peak_s ? o.loading_weight : 1.0) / o.force_noise_n;
  }
  if (o.kinematics_weight > 0.0 && tr.impactor_m.size() == n)
    for (int w = 0; w < p.n_win; ++w)
      if (std::isfinite(tr.impactor_m[i0 + w])) p.kin_idx.push_back(w);
  if (o.surface_weight > 0.0 && tr.surface_m.size() == n)
    for (int w = 0; w < p.n_win; ++w)
      if (std::isfinite(tr.surface_m[i0 + w])) p.surf_idx.push_back(w);
  return p;
}

// Residuals of one trial from simulated series (indexed by simulated sample).
template <typename T>
void fill_residuals(const Prepared& p, const FitOptions& o, const std::vector<T>& grf,
                    const std::vector<T>& imp, const std::vector<T>& surf, T* res) {
  const TrialData& tr = *p.data;
  int r = 0;
  for (int w = 0; w < p.n_win; ++w) {
    const double m = tr.grf_n[p.i0 + w];
    res[r++] = std::isfinite(m) ? (grf[p.k0 + w] - m) * T(p.force_w[w]) : T(0.0);
  }
  const double kin = o.kinematics_weight / o.marker_noise_m;
  for (int w : p.kin_idx) res[r++] = (imp[p.k0 + w] - tr.impactor_m[p.i0 + w]) * T(kin);
  const double sw = o.surface_weight / o.marker_noise_m;
  for (int w : p.surf_idx) {
    const T d = surf[p.k0 + w] - tr.surface_m[p.i0 + w];
    if (o.surface_as_residual) {
      res[r++] = d * T(sw);
    } else {
      const double ad = std::abs(detail::scalar_of(d));
      if (ad <= o.surface_tolerance_m) res[r++] = T(0.0);
      else if (detail::scalar_of(d) > 0.0) res[r++] = (d - T(o.surface_tolerance_m)) * T(sw);
      else res[r++] = (-d - T(o.surface_tolerance_m)) * T(sw);
    }
  }
}

// The Ceres cost of one trial with automatic differentiation.
struct AutoTrialCost {
  const Prepared* p;
  const ParamSpace* space;
  const FitOptions* o;
  detail::Layout layout;
  bool exact;
  long* evals;

  template <typename T>
  bool operator()(T const* const* u, T* res) const {
    const detail::ParamsT<T> pt = space->to_params(u[0]);
    detail::Trace<T> tr;
    detail::run_model<T>(layout, pt, p->impact, exact, kRk4Step, p->n_sim, tr);
    ++*evals;
    fill_residuals<T>(*p, *o, tr.grf, tr.impactor, tr.surface, res);
    for (int i = 0; i < p->n_residuals(); ++i)
      if (!finite_all(res[i])) return false;
    return true;
  }
};

// Simulates a trial's window in doubles (the callback if given).
detail::Trace<double> simulate_window(const Prepared& p, const ParamSpace& space, const FitOptions& o,
                                      const MatParams& mp, long* evals) {
  detail::Trace<double> tr;
  if (o.simulator) {
    const Simulation s = o.simulator(mp, p.impact);
    if (s.grf_n.size() < p.n_sim - 1 || s.grf_n.size() < 2)
      throw Error(fmt::format("custom simulator returned {} samples, the fit needs {}", s.grf_n.size(), p.n_sim));
    // A simulator that samples elsewhere than asked (e.g. ignores
    // first_output_s) is interpolated linearly onto the requested times.
    const double dt = p.impact.output_dt_s, first = p.impact.first_output_s;
    const bool aligned = s.t_s.size() == 0 || std::abs(s.t_s[0] - first) < 1e-9 * std::max(dt, 1e-12) + 1e-12;
    auto vec = [&](const Eigen::VectorXd& v) {
      std::vector<double> out(p.n_sim, kNaN);
      if (aligned || s.t_s.size() != v.size() || v.size() < 2) {
        for (int i = 0; i < p.n_sim && i < v.size(); ++i) out[i] = v[i];
        return out;
      }
      Eigen::Index j = 0;
      for (int i = 0; i < p.n_sim; ++i) {
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
  } else {
    const ModelKind shape = space.model;
    const detail::Layout layout = detail::layout_for(shape, shape == ModelKind::Model2 && mp.m_eff_kg <= 0.0);
    detail::run_model<double>(layout, detail::to_params_t<double>(shape, mp), p.impact, !space.nonlinear() && !mp.has_effects(),
                              kRk4Step, p.n_sim, tr);
  }
  if (evals) ++*evals;
  return tr;
}

// The Ceres cost of one trial with central numeric differences (callback).
struct NumericTrialCost {
  const Prepared* p;
  const ParamSpace* space;
  const FitOptions* o;
  long* evals;
  bool operator()(double const* const* u, double* res) const {
    const MatParams mp = space->to_mat(u[0]);
    try {
      const detail::Trace<double> tr = simulate_window(*p, *space, *o, mp, evals);
      fill_residuals<double>(*p, *o, tr.grf, tr.impactor, tr.surface, res);
    } catch (const Error&) {
      return false;
    }
    for (int i = 0; i < p->n_residuals(); ++i)
      if (!std::isfinite(res[i])) return false;
    return true;
  }
};

// Residual vector (doubles) over the prepared trials.
Eigen::VectorXd residual_vector(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                                const MatParams& mp, long* evals) {
  int m = 0;
  for (const auto& p : preps) m += p.n_residuals();
  Eigen::VectorXd r(m);
  int off = 0;
  for (const auto& p : preps) {
    const detail::Trace<double> tr = simulate_window(p, space, o, mp, evals);
    fill_residuals<double>(p, o, tr.grf, tr.impactor, tr.surface, r.data() + off);
    off += p.n_residuals();
  }
  return r;
}

double cost_of(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
               const MatParams& mp, long* evals) {
  try {
    const Eigen::VectorXd r = residual_vector(preps, space, o, mp, evals);
    const double c = 0.5 * r.squaredNorm();
    return std::isfinite(c) ? c : std::numeric_limits<double>::infinity();
  } catch (const Error&) {
    return std::numeric_limits<double>::infinity();
  }
}

// A start from the data: effective stiffness from peak force and travel.
MatParams data_guess(const std::vector<Prepared>& preps, const FitOptions& o) {
  const Prepared& p = preps.front();
  const TrialData& tr = *p.data;
  double x_max = kNaN;
  if (tr.impactor_m.size() == tr.t_s.size()) {
    double mx = -1.0;
    for (Eigen::Index i = 0; i < tr.impactor_m.size(); ++i)
      if (std::isfinite(tr.impactor_m[i])) mx = std::max(mx, tr.impactor_m[i]);
    if (mx > 0.0) x_max = mx;
  }
  const double M = tr.impactor_mass_kg, v = std::max(tr.impact_velocity_m_s, 0.5);
  const double F = std::max(p.peak_n, 100.0);
  if (!std::isfinite(x_max)) x_max = M * v * v / F;  // energy: F x / 2 ~ M v^2 / 2
  const double k = std::clamp(F / x_max, o.k_min_n_m, o.k_max_n_m);
  const double rc = 2.0 * std::sqrt(k * M);  // critical damping on the impactor
  MatParams g;
  g.m1_kg = o.m1_kg;
  g.m2_kg = o.m2_kg;
  g.m_eff_kg = o.m_eff_kg >= 0.0 ? o.m_eff_kg : 0.3 * (o.m1_kg + o.m2_kg);
  switch (o.model) {
    case ModelKind::Model1:
    case ModelKind::Model2:
      g.k1_n_m = k; g.r1_n_s_m = 0.2 * rc;
      break;
    case ModelKind::Model3:
      g.k1_n_m = 1.1 * k; g.k2_n_m = 11.0 * k; g.r1_n_s_m = 0.1 * rc; g.r2_n_s_m = 0.2 * rc;
      break;
    default:
      g.k1_n_m = 1.2 * k; g.k2_n_m = 15.0 * k; g.k3_n_m = 10.0 * k;
      g.r1_n_s_m = 0.05 * rc; g.r2_n_s_m = 0.2 * rc; g.r3_n_s_m = 0.2 * rc;
      break;
  }
  return g;
}

double halton(int index, int base) {
  double f = 1.0, r = 0.0;
  while (index > 0) {
    f /= base;
    r += f * (index % base);
    index /= base;
  }
  return r;
}

struct Optimum {
  Eigen::VectorXd u;
  double cost = std::numeric_limits<double>::infinity();
  Eigen::MatrixXd jacobian;  // at u, residuals x parameters (u space)
  Eigen::VectorXd residuals;
};

// Builds the Ceres problem over the prepared trials.
std::unique_ptr<ceres::Problem> make_problem(const std::vector<Prepared>& preps, const ParamSpace& space,
                                             const FitOptions& o, double* u, long* evals) {
  ceres::Problem::Options po;
  auto problem = std::make_unique<ceres::Problem>(po);
  const bool numeric = static_cast<bool>(o.simulator) || o.model == ModelKind::Model5;
  const ModelKind shape = space.model;
  const detail::Layout layout =
      detail::layout_for(shape, shape == ModelKind::Model2 && o.m_eff_kg == 0.0);
  for (const auto& p : preps) {
    ceres::CostFunction* cf;
    if (numeric) {
      ceres::NumericDiffOptions nd;
      nd.relative_step_size = 1e-5;
      auto* c = new ceres::DynamicNumericDiffCostFunction<NumericTrialCost, ceres::CENTRAL>(
          new NumericTrialCost{&p, &space, &o, evals}, ceres::TAKE_OWNERSHIP, nd);
      c->AddParameterBlock(space.size());
      c->SetNumResiduals(p.n_residuals());
      cf = c;
    } else {
      auto* c = new ceres::DynamicAutoDiffCostFunction<AutoTrialCost, 8>(
          new AutoTrialCost{&p, &space, &o, layout, !space.nonlinear(), evals});
      c->AddParameterBlock(space.size());
      c->SetNumResiduals(p.n_residuals());
      cf = c;
    }
    problem->AddResidualBlock(cf, nullptr, u);
  }
  for (int i = 0; i < space.size(); ++i) {
    problem->SetParameterLowerBound(u, i, space.free[i].lower);
    problem->SetParameterUpperBound(u, i, space.free[i].upper);
  }
  return problem;
}

Optimum run_ceres(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                  const Eigen::VectorXd& u0, long* evals, bool want_jacobian) {
  Optimum best;
  std::vector<double> u(u0.data(), u0.data() + u0.size());
  auto problem = make_problem(preps, space, o, u.data(), evals);
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = o.max_iterations;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  so.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(so, problem.get(), &summary);
  best.u = Eigen::Map<Eigen::VectorXd>(u.data(), u.size());
  best.cost = summary.IsSolutionUsable() ? summary.final_cost : std::numeric_limits<double>::infinity();
  if (want_jacobian) {
    double cost = 0.0;
    std::vector<double> res;
    ceres::CRSMatrix crs;
    ceres::Problem::EvaluateOptions eo;
    if (problem->Evaluate(eo, &cost, &res, nullptr, &crs)) {
      best.residuals = Eigen::Map<Eigen::VectorXd>(res.data(), res.size());
      best.jacobian = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
      for (int r = 0; r < crs.num_rows; ++r)
        for (int k = crs.rows[r]; k < crs.rows[r + 1]; ++k) best.jacobian(r, crs.cols[k]) = crs.values[k];
    }
  }
  return best;
}

// Multi-start: candidate points (the given start, the data guess, Halton
// points in the start ranges), ranked by cost; Ceres from the best.
Optimum optimise(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o, long* evals,
                 std::vector<std::string>* warnings, std::string* used) {
  const int n = space.size();
  std::vector<Eigen::VectorXd> cands;
  if (o.initial.k1_n_m > 0.0) cands.push_back(space.from_mat(o.initial));
  cands.push_back(space.from_mat(data_guess(preps, o)));
  const int n_random = std::max(4 * o.starts, 8);
  const int primes[] = {2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43};
  const int skip = static_cast<int>(o.seed % 1000) + 1;
  for (int i = 0; i < n_random; ++i) {
    Eigen::VectorXd u(n);
    for (int j = 0; j < n; ++j) {
      const FreeParam& f = space.free[j];
      u[j] = f.start_lo + halton(i + skip, primes[j % 14]) * (f.start_hi - f.start_lo);
    }
    cands.push_back(u);
  }

  if (o.optimizer == Optimizer::Annealing) {
    *used = "annealing (Corana et al. 1987)";
    Eigen::VectorXd lo(n), hi(n);
    for (int j = 0; j < n; ++j) {
      lo[j] = space.free[j].lower;
      hi[j] = space.free[j].upper;
    }
    auto f = [&](const Eigen::VectorXd& u) { return cost_of(preps, space, o, space.to_mat(u.data()), evals); };
    // Start from the best candidate, as the paper's runs started from a guess.
    Eigen::VectorXd x0 = cands.front();
    double f0 = f(x0);
    for (const auto& c : cands) {
      const double fc = f(c);
      if (fc < f0) { f0 = fc; x0 = c; }
    }
    const AnnealResult ar = anneal(f, x0, lo, hi, o.anneal);
    if (!ar.converged) warnings->push_back("annealing stopped at its evaluation limit before converging");
    Optimum best;
    best.u = ar.x;
    best.cost = ar.f;
    if (o.polish_annealing) {
      *used += " + Ceres polish";
      Optimum pol = run_ceres(preps, space, o, ar.x, evals, true);
      if (pol.cost <= best.cost) return pol;
    }
    // Jacobian at the annealing optimum, for the covariance.
    FitOptions one = o;
    one.max_iterations = 0;
    Optimum jac = run_ceres(preps, space, one, best.u, evals, true);
    jac.u = best.u;
    jac.cost = best.cost;
    return jac;
  }

  *used = "ceres (Levenberg-Marquardt, multi-start)";
  std::vector<std::pair<double, int>> ranked;
  for (size_t i = 0; i < cands.size(); ++i)
    ranked.push_back({cost_of(preps, space, o, space.to_mat(cands[i].data()), evals), static_cast<int>(i)});
  // The explicit and data-driven starts always run; the rest by rank.
  std::vector<int> order;
  // A given start with starts == 1 (a warm start, e.g. Model 5 from Model 4's
  // optimum) runs alone; otherwise the data guess runs too.
  const int fixed_starts = o.initial.k1_n_m > 0.0 && o.starts > 1 ? 2 : 1;
  for (int i = 0; i < fixed_starts; ++i) order.push_back(i);
  std::sort(ranked.begin(), ranked.end());
  for (const auto& [c, i] : ranked) {
    if (static_cast<int>(order.size()) >= std::max(o.starts, fixed_starts)) break;
    if (i >= fixed_starts && std::isfinite(c)) order.push_back(i);
  }
  Optimum best;
  int failed = 0;
  for (int i : order) {
    Optimum cur = run_ceres(preps, space, o, cands[i], evals, false);
    if (!std::isfinite(cur.cost)) {
      ++failed;
      continue;
    }
    if (cur.cost < best.cost) best = cur;
  }
  if (!std::isfinite(best.cost)) throw Error("fit: every start failed (the simulation did not run)");
  if (failed > 0) warnings->push_back(fmt::format("{} of {} starts failed", failed, order.size()));
  FitOptions one = o;
  one.max_iterations = 0;
  Optimum jac = run_ceres(preps, space, one, best.u, evals, true);
  jac.u = best.u;
  jac.cost = best.cost;
  return jac;
}

std::string param_display(const FreeParam& f) { return f.transform == Transform::Fraction ? "m1_kg" : f.name; }

// Covariance from the Jacobian: standard errors and identifiability.
void covariance(const Optimum& opt, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                std::vector<ParameterEstimate>* est, std::vector<std::string>* warnings) {
  const int n = space.size();
  const Eigen::MatrixXd& J = opt.jacobian;
  if (J.rows() <= n || J.cols() != n) {
    warnings->push_back("covariance not available (too few residuals)");
    return;
  }
  const double dof = static_cast<double>(J.rows() - n);
  const double s2 = opt.residuals.squaredNorm() / dof;
  // Scale columns to unit norm so the conditioning reflects correlation.
  Eigen::VectorXd colnorm = J.colwise().norm().transpose();
  for (int j = 0; j < n; ++j)
    if (!(colnorm[j] > 0.0)) colnorm[j] = 1.0;
  const Eigen::MatrixXd Js = J * colnorm.cwiseInverse().asDiagonal();
  const Eigen::MatrixXd JtJ = Js.transpose() * Js;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(JtJ);
  const Eigen::VectorXd ev = es.eigenvalues();
  const double evmax = ev.maxCoeff();
  Eigen::MatrixXd inv = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    const double lam = ev[i];
    if (lam > 1e-14 * evmax) inv += es.eigenvectors().col(i) * es.eigenvectors().col(i).transpose() / lam;
  }
  Eigen::MatrixXd cov = s2 * colnorm.cwiseInverse().asDiagonal() * inv * colnorm.cwiseInverse().asDiagonal();
  for (int i = 0; i < n; ++i) {
    const double lam = ev[i];
    if (lam < 1e-8 * evmax) {
      const Eigen::VectorXd v = es.eigenvectors().col(i);
      std::string dir;
      for (int j = 0; j < n; ++j)
        if (std::abs(v[j]) > 0.3) dir += fmt::format("{}{:+.2f} {}", dir.empty() ? "" : " ", v[j], param_display(space.free[j]));
      warnings->push_back(fmt::format("near-singular direction (eigenvalue ratio {:.1e}): {}", lam / evmax, dir));
    }
  }
  for (int j = 0; j < n; ++j) {
    const FreeParam& f = space.free[j];
    ParameterEstimate& e = (*est)[j];
    double se_u = std::sqrt(std::max(cov(j, j), 0.0));
    // A direction dropped from the inverse: the parameter is unconstrained.
    bool lost = false;
    for (int i = 0; i < n; ++i)
      if (ev[i] <= 1e-14 * evmax && std::abs(es.eigenvectors()(j, i)) > 0.1) lost = true;
    if (lost) se_u = std::numeric_limits<double>::infinity();
    if (f.transform == Transform::Log) {
      e.se = e.value * se_u;
      e.rel_se = se_u;
    } else if (f.transform == Transform::Fraction) {
      e.se = space.total_mass * se_u;
      e.rel_se = e.se / std::max(mp.m1_kg, 1e-12);
    } else {
      e.se = f.scale * se_u;
      e.rel_se = e.se / std::max(std::abs(e.value), 1e-300);
    }
    if (!(e.rel_se <= o.identifiability_rel_se)) {
      e.identifiable = false;
      warnings->push_back(fmt::format("{} is not pinned down by the data (relative SE {:.2g})", e.name, e.rel_se));
    }
    const double margin = 1e-3 * (f.upper - f.lower);
    if (opt.u[j] <= f.lower + margin || opt.u[j] >= f.upper - margin) {
      // The data push it out of the physically sensible box: the box, not
      // the data, sets its value.
      if (e.identifiable)
        warnings->push_back(fmt::format("{} is not pinned down by the data: it sits at its bound ({:.6g})",
                                        e.name, e.value));
      else
        warnings->push_back(fmt::format("{} sits at its bound ({:.6g})", e.name, e.value));
      e.identifiable = false;
    }
  }
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      const double c = cov(a, b) / std::sqrt(std::max(cov(a, a) * cov(b, b), 1e-300));
      if (std::abs(c) > 0.995)
        warnings->push_back(fmt::format("{} and {} are correlated (r = {:.3f})", param_display(space.free[a]),
                                        param_display(space.free[b]), c));
    }
}

std::vector<const TrialData*> choose_train(const std::vector<TrialData>& trials, const std::vector<std::string>& ids) {
  std::vector<const TrialData*> out;
  if (!ids.empty()) {
    for (const auto& id : ids) {
      auto it = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == id; });
      if (it == trials.end()) throw Error(fmt::format("fit: training trial '{}' not found", id));
      out.push_back(&*it);
    }
    return out;
  }
  std::vector<const TrialData*> acc;
  for (const auto& t : trials)
    if (t.accepted) acc.push_back(&t);
  if (acc.empty()) throw Error("fit: no accepted trial to train on");
  std::sort(acc.begin(), acc.end(), [](const TrialData* a, const TrialData* b) {
    return a->impact_velocity_m_s < b->impact_velocity_m_s;
  });
  out.push_back(acc[(acc.size() - 1) / 2]);
  return out;
}

void check_options(const FitOptions& o) {
  if (o.model == ModelKind::Model5 && !o.simulator)
    throw Error("fit: Model 5 needs a simulator callback (fitting/model5.h)");
  if (!(o.force_noise_n > 0.0) || !(o.marker_noise_m > 0.0))
    throw Error("fit: force_noise_n and marker_noise_m must be positive");
  if (!(o.m1_kg >= 0.0) || !(o.m2_kg >= 0.0)) throw Error("fit: layer masses must be >= 0");
  if (o.starts < 1) throw Error("fit: starts must be at least 1");
}

struct FitCore {
  MatParams params;
  Optimum opt;
  ParamSpace space;
  std::string used;
};

FitCore fit_core(const std::vector<const TrialData*>& train, const FitOptions& o, long* evals,
                 std::vector<std::string>* warnings) {
  FitCore fc;
  fc.space = make_space(o);
  std::vector<Prepared> preps;
  for (const TrialData* t : train) preps.push_back(prepare(*t, o));
  fc.opt = optimise(preps, fc.space, o, evals, warnings, &fc.used);
  fc.params = fc.space.to_mat(fc.opt.u.data());
  return fc;
}

double sim_peak(const FitOptions& o, const MatParams& mp, const Impact& imp) {
  const Simulation s = o.simulator ? o.simulator(mp, imp) : simulate(o.model, mp, imp);
  return s.grf_n.maxCoeff();
}

}  // namespace

// ---------------------------------------------------------------------------

TrialReport predict(const TrialData& trial, const MatParams& params, const FitOptions& options) {
  const Prepared p = prepare(trial, options);
  TrialReport rep;
  rep.id = trial.id;
  rep.impact_velocity_m_s = trial.impact_velocity_m_s;
  rep.window_end_s = p.window_end_s;
  Impact imp = p.impact;
  rep.simulation = options.simulator ? options.simulator(params, imp) : simulate(options.model, params, imp);
  // The series on the trial's own samples (a custom simulator interpolated).
  const ParamSpace space = make_space(options);
  const detail::Trace<double> s = simulate_window(p, space, options, params, nullptr);
  const int n = p.n_win;
  Eigen::VectorXd t(n), fm(n), fs(n);
  for (int w = 0; w < n; ++w) {
    t[w] = trial.t_s[p.i0 + w];
    fm[w] = trial.grf_n[p.i0 + w];
    fs[w] = s.grf[p.k0 + w];
  }
  rep.comparison = compare_forces(t, fm, fs);
  Eigen::VectorXd fm_clean = fm;
  for (int w = 0; w < n; ++w)
    if (!std::isfinite(fm_clean[w])) fm_clean[w] = w > 0 ? fm_clean[w - 1] : 0.0;
  if (n >= 3) {
    rep.measured = characteristics(t, fm_clean, options.characteristics);
    rep.simulated = characteristics(t, fs, options.characteristics);
  }
  if (trial.impactor_m.size() == trial.t_s.size()) {
    double mm = -1e300, ms = -1e300, ss = 0.0;
    int cnt = 0;
    for (int w = 0; w < n; ++w) {
      const double y = trial.impactor_m[p.i0 + w];
      if (!std::isfinite(y)) continue;
      mm = std::max(mm, y);
      const double d = s.impactor[p.k0 + w] - y;
      ss += d * d;
      ++cnt;
    }
    for (int w = 0; w < n; ++w) ms = std::max(ms, s.impactor[p.k0 + w]);
    if (cnt > 0) {
      rep.max_deformation_mm_diff = 1000.0 * (ms - mm);
      rep.rms_impactor_mm = 1000.0 * std::sqrt(ss / cnt);
    }
  }
  return rep;
}

Eigen::VectorXd residuals(const std::vector<TrialData>& trials, const MatParams& params, const FitOptions& options) {
  check_options(options);
  const ParamSpace space = make_space(options);
  std::vector<Prepared> preps;
  for (const auto& t : trials) preps.push_back(prepare(t, options));
  return residual_vector(preps, space, options, params, nullptr);
}

FitResult fit(const std::vector<TrialData>& trials, const FitOptions& options) {
  const auto t_start = std::chrono::steady_clock::now();
  check_options(options);
  if (trials.empty()) throw Error("fit: no trials");
  FitResult res;
  res.model = options.model;
  const auto train = choose_train(trials, options.train_ids);
  for (const TrialData* t : train) res.train_ids.push_back(t->id);

  FitCore fc = fit_core(train, options, &res.evaluations, &res.warnings);
  res.params = fc.params;
  res.optimizer = fc.used;
  res.cost = fc.opt.cost;
  res.n_residuals = static_cast<int>(fc.opt.residuals.size());

  // Estimates (free parameters, then the fixed ones for completeness).
  for (const auto& f : fc.space.free) {
    ParameterEstimate e;
    e.name = param_display(f);
    e.value = f.transform == Transform::Fraction ? res.params.m1_kg : get_parameter(res.params, f.name);
    res.estimates.push_back(e);
  }
  covariance(fc.opt, fc.space, options, res.params, &res.estimates, &res.warnings);
  {
    const ModelKind shape = options.model == ModelKind::Model5 ? ModelKind::Model4 : options.model;
    for (const auto& name : parameter_names(shape, true)) {
      const bool is_free = std::any_of(res.estimates.begin(), res.estimates.end(),
                                       [&](const ParameterEstimate& e) { return e.name == name; });
      if (is_free) continue;
      ParameterEstimate e;
      e.name = name;
      e.value = get_parameter(res.params, name);
      e.free = false;
      e.se = 0.0;
      e.rel_se = 0.0;
      res.estimates.push_back(e);
    }
    if (options.masses_free && (shape == ModelKind::Model3 || shape == ModelKind::Model4)) {
      for (auto& e : res.estimates)
        if (e.name == "m2_kg") {
          e.free = true;  // follows m1 (total fixed)
          for (const auto& f : res.estimates)
            if (f.name == "m1_kg") { e.se = f.se; e.rel_se = f.se / std::max(e.value, 1e-12); }
        }
    }
  }

  for (const auto& t : trials) {
    TrialReport rep = predict(t, res.params, options);
    rep.train = std::find(res.train_ids.begin(), res.train_ids.end(), t.id) != res.train_ids.end();
    res.trials.push_back(std::move(rep));
  }

  if (options.sensitivity) {
    const Prepared p = prepare(*train.front(), options);
    Impact imp = p.impact;
    imp.duration_s = std::max(imp.duration_s, 0.3);
    const double base = sim_peak(options, res.params, imp);
    const ModelKind shape = options.model == ModelKind::Model5 ? ModelKind::Model4 : options.model;
    for (const auto& name : parameter_names(shape, false)) {
      if (!is_stiffness_or_damping(name)) continue;
      SensitivityEntry s;
      s.name = name;
      MatParams lo = res.params, hi = res.params;
      set_parameter(lo, name, 0.9 * get_parameter(res.params, name));
      set_parameter(hi, name, 1.1 * get_parameter(res.params, name));
      s.peak_pct_minus10 = 100.0 * (sim_peak(options, lo, imp) - base) / base;
      s.peak_pct_plus10 = 100.0 * (sim_peak(options, hi, imp) - base) / base;
      res.sensitivity.push_back(s);
    }
  }

  if (options.leave_one_out) {
    std::vector<const TrialData*> acc;
    for (const auto& t : trials)
      if (t.accepted) acc.push_back(&t);
    if (acc.size() < 2) {
      res.warnings.push_back("leave-one-trial-out needs at least two accepted trials");
    } else {
      for (const TrialData* held : acc) {
        std::vector<const TrialData*> tr;
        for (const TrialData* t : acc)
          if (t != held) tr.push_back(t);
        FitOptions o = options;
        o.initial = res.params;  // start near the full fit; multi-start still runs
        std::vector<std::string> w;
        FitCore c = fit_core(tr, o, &res.evaluations, &w);
        LeaveOneOutEntry e;
        e.held_out = held->id;
        e.params = c.params;
        e.comparison = predict(*held, c.params, options).comparison;
        res.leave_one_out.push_back(e);
      }
    }
  }
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return res;
}

std::string FitResult::report() const {
  std::ostringstream os;
  os << fmt::format("{} fitted to {} by {}: cost {:.6g} over {} residuals, {} simulations, {:.2f} s\n",
                    model_name(model), fmt::join(train_ids, ", "), optimizer, cost, n_residuals, evaluations, seconds);
  os << "parameters:\n";
  for (const auto& e : estimates)
    os << fmt::format("  {:<16} {:>12.6g}  {}\n", e.name, e.value,
                      !e.free ? "(fixed)"
                              : (std::isfinite(e.rel_se) ? fmt::format("SE {:.3g} ({:.2g} %){}", e.se, 100.0 * e.rel_se,
                                                                       e.identifiable ? "" : "  NOT IDENTIFIED")
                                                         : std::string("SE n/a  NOT IDENTIFIED")));
  os << "trials (rms % peak, peak % diff, time to peak ms diff, max deformation mm diff):\n";
  for (const auto& t : trials)
    os << fmt::format("  {:<10} v {:.2f} m/s{} {:7.2f} {:+7.2f} {:+6.1f} {:+6.1f}\n", t.id, t.impact_velocity_m_s,
                      t.train ? " (train)" : "        ", t.comparison.rms_force_pct_peak,
                      t.comparison.peak_force_pct_diff, t.comparison.time_to_peak_ms_diff, t.max_deformation_mm_diff);
  if (!sensitivity.empty()) {
    os << "sensitivity of peak force to -10 % / +10 %:\n";
    for (const auto& s : sensitivity)
      os << fmt::format("  {:<10} {:+6.2f} % / {:+6.2f} %\n", s.name, s.peak_pct_minus10, s.peak_pct_plus10);
  }
  if (!leave_one_out.empty()) {
    os << "leave-one-trial-out (peak % diff of the held-out trial):\n";
    for (const auto& l : leave_one_out)
      os << fmt::format("  {:<10} {:+7.2f} %  rms {:.2f} % peak\n", l.held_out, l.comparison.peak_force_pct_diff,
                        l.comparison.rms_force_pct_peak);
  }
  for (const auto& w : warnings) os << "warning: " << w << "\n";
  return os.str();
}

// ---------------------------------------------------------------------------
// Table mode.

namespace {

struct TableCost {
  const TableFitOptions* o;
  const TableTrial* t;
  std::vector<int> idx;  // free parameter -> field
  detail::Layout layout;

  template <typename T>
  bool operator()(T const* const* u, T* res) const {
    detail::ParamsT<T> p = detail::to_params_t<T>(o->model, o->base);
    for (size_t i = 0; i < idx.size(); ++i) {
      using std::exp;
      const T v = exp(u[0][i]);
      switch (idx[i]) {
        case 0: p.k[0] = v; break;
        case 1: p.k[1] = v; break;
        case 2: p.k[2] = v; break;
        case 3: p.r[0] = v; break;
        case 4: p.r[1] = v; break;
        case 5: p.r[2] = v; break;
        case 6: p.m1 = v; break;  // m_eff
        default: break;
      }
    }
    Impact imp;
    imp.mass_kg = o->impactor_mass_kg;
    imp.gravity_m_s2 = o->gravity_m_s2;
    imp.velocity_m_s = t->impact_velocity_m_s;
    imp.output_dt_s = 5e-4;
    imp.duration_s = 0.25;
    const int n = static_cast<int>(std::floor(imp.duration_s / imp.output_dt_s)) + 1;
    detail::Trace<T> tr;
    detail::run_model<T>(layout, p, imp, true, kRk4Step, n, tr);
    T pk = tr.grf[0], dm = tr.impactor[0];
    for (int i = 1; i < n; ++i) {
      if (detail::scalar_of(tr.grf[i]) > detail::scalar_of(pk)) pk = tr.grf[i];
      if (detail::scalar_of(tr.impactor[i]) > detail::scalar_of(dm)) dm = tr.impactor[i];
    }
    res[0] = (pk - t->peak_force_n) / o->peak_noise_n;
    res[1] = std::isfinite(t->max_deformation_m) ? T((dm - t->max_deformation_m) / o->deformation_noise_m) : T(0.0);
    return finite_all(res[0]) && finite_all(res[1]);
  }
};

int table_index(const std::string& name) {
  static const char* names[] = {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m", "m_eff_kg"};
  for (int i = 0; i < 7; ++i)
    if (name == names[i]) return i;
  throw Error(fmt::format("fit_table: '{}' cannot be fitted in table mode", name));
}

Simulation table_sim(const TableFitOptions& o, const MatParams& p, double v) {
  Impact imp;
  imp.mass_kg = o.impactor_mass_kg;
  imp.gravity_m_s2 = o.gravity_m_s2;
  imp.velocity_m_s = v;
  imp.output_dt_s = 5e-4;
  imp.duration_s = 0.25;
  return simulate(o.model, p, imp);
}

}  // namespace

TableFitResult fit_table(const std::vector<TableTrial>& trials, const TableFitOptions& options) {
  if (trials.empty()) throw Error("fit_table: no trials");
  if (options.model == ModelKind::Model5) throw Error("fit_table: Model 5 is not supported in table mode");
  if (options.free.empty()) throw Error("fit_table: nothing to fit");
  std::vector<const TableTrial*> train;
  if (options.train_ids.empty()) {
    std::vector<const TableTrial*> all;
    for (const auto& t : trials) all.push_back(&t);
    std::sort(all.begin(), all.end(), [](auto* a, auto* b) { return a->impact_velocity_m_s < b->impact_velocity_m_s; });
    train.push_back(all[(all.size() - 1) / 2]);
  } else {
    for (const auto& id : options.train_ids) {
      auto it = std::find_if(trials.begin(), trials.end(), [&](const TableTrial& t) { return t.id == id; });
      if (it == trials.end()) throw Error(fmt::format("fit_table: training trial '{}' not found", id));
      train.push_back(&*it);
    }
  }
  std::vector<int> idx;
  for (const auto& n : options.free) idx.push_back(table_index(n));
  const int n = static_cast<int>(idx.size());
  const detail::Layout layout =
      detail::layout_for(options.model, options.model == ModelKind::Model2 && options.base.m_eff_kg <= 0.0 &&
                                            std::find(idx.begin(), idx.end(), 6) == idx.end());

  TableFitResult res;
  double best_cost = std::numeric_limits<double>::infinity();
  std::vector<double> best_u;
  std::vector<std::pair<double, std::vector<double>>> optima;
  std::mt19937_64 rng(options.seed);
  for (int s = 0; s < options.starts; ++s) {
    std::vector<double> u(n);
    for (int i = 0; i < n; ++i) {
      double v = get_parameter(options.base, options.free[i]);
      if (!(v > 0.0)) v = idx[i] < 3 ? 1e5 : (idx[i] < 6 ? 500.0 : 1.0);
      const double jitter = s == 0 ? 0.0 : std::uniform_real_distribution<double>(-1.5, 1.5)(rng);
      u[i] = std::log(v) + jitter;
    }
    ceres::Problem problem;
    for (const TableTrial* t : train) {
      auto* c = new ceres::DynamicAutoDiffCostFunction<TableCost, 8>(new TableCost{&options, t, idx, layout});
      c->AddParameterBlock(n);
      c->SetNumResiduals(2);
      problem.AddResidualBlock(c, nullptr, u.data());
    }
    for (int i = 0; i < n; ++i) {
      const bool k = idx[i] < 3, r = idx[i] >= 3 && idx[i] < 6;
      problem.SetParameterLowerBound(u.data(), i, std::log(k ? 1e3 : (r ? 0.1 : 1e-3)));
      problem.SetParameterUpperBound(u.data(), i, std::log(k ? 1e8 : (r ? 1e5 : 100.0)));
      u[i] = std::clamp(u[i], std::log(k ? 1e3 : (r ? 0.1 : 1e-3)), std::log(k ? 1e8 : (r ? 1e5 : 100.0)));
    }
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = 200;
    so.function_tolerance = 1e-14;
    so.parameter_tolerance = 1e-12;
    so.logging_type = ceres::SILENT;
    ceres::Solver::Summary sum;
    ceres::Solve(so, &problem, &sum);
    if (!sum.IsSolutionUsable()) continue;
    optima.push_back({sum.final_cost, u});
    if (sum.final_cost < best_cost) {
      best_cost = sum.final_cost;
      best_u = u;
    }
  }
  if (best_u.empty()) throw Error("fit_table: every start failed");
  res.cost = best_cost;
  auto params_of = [&](const std::vector<double>& u) {
    MatParams p = options.base;
    for (int i = 0; i < n; ++i) set_parameter(p, options.free[i], std::exp(u[i]));
    return p;
  };
  res.params = params_of(best_u);
  // Other optima that fit as well (within half a unit of chi-square):
  // summaries rarely pin a model down uniquely.
  std::vector<std::vector<double>> distinct = {best_u};
  std::sort(optima.begin(), optima.end());
  for (const auto& [c, u] : optima) {
    if (c > best_cost + 0.5) break;
    bool seen = false;
    for (const auto& d : distinct) {
      double dmax = 0.0;
      for (int i = 0; i < n; ++i) dmax = std::max(dmax, std::abs(u[i] - d[i]));
      if (dmax < 0.01) seen = true;
    }
    if (seen) continue;
    distinct.push_back(u);
    res.alternatives.push_back(params_of(u));
  }
  if (!res.alternatives.empty())
    res.warnings.push_back(fmt::format("{} other parameter sets fit the training summaries as well (see alternatives)",
                                       res.alternatives.size()));
  if (2 * static_cast<int>(train.size()) < n)
    res.warnings.push_back(fmt::format("{} parameters from {} numbers: not all are identifiable", n, 2 * train.size()));
  for (const auto& t : trials) {
    const Simulation s = table_sim(options, res.params, t.impact_velocity_m_s);
    TableTrialReport r;
    r.id = t.id;
    r.train = std::find(train.begin(), train.end(), &t) != train.end();
    r.impact_velocity_m_s = t.impact_velocity_m_s;
    r.peak_force_n = t.peak_force_n;
    r.simulated_peak_force_n = s.grf_n.maxCoeff();
    r.peak_force_pct_diff = 100.0 * (r.simulated_peak_force_n - t.peak_force_n) / t.peak_force_n;
    r.max_deformation_m = t.max_deformation_m;
    r.simulated_max_deformation_m = s.impactor_m.maxCoeff();
    res.trials.push_back(r);
  }
  return res;
}

}  // namespace dropfit::fitting
