// Fitting Model 6, the foam column (fitting/model6_fit.h).
#include "fitting/model6_fit.h"

#include <Eigen/Eigenvalues>
#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "core/error.h"
#include "core/parallel.h"
#include "fitting/model6_impl.h"

namespace dropfit::fitting {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The free parameters, in order (all fitted as logarithms; the
// densification exponent as that of n - 1).
const std::vector<std::string>& free_names() {
  static const std::vector<std::string> names{
      "top_plateau_pa",  "top_modulus_pa",  "top_hardening_pa",  "top_densification_pa", "densification_strain",
      "base_plateau_pa", "base_modulus_pa", "base_hardening_pa", "base_densification_pa", "prony_g1",
      "prony_tau1_s",    "prony_g2",        "prony_tau2_s",      "viscosity_pa_s",       "densification_exponent"};
  return names;
}
constexpr int kFree = 15;
constexpr int kExponent = 14;  // the index of log(n - 1)
// The column's law and its ten elements are not the foam's, so a parameter
// is the column's effective value, and an interval from the fit's
// curvature does not hold the foam's own; the predictions carry the
// intervals, with the column's discrepancy.
constexpr const char* kEffectiveNote =
    "the column's effective value, not the foam's: no interval (its predictions carry them)";

// The parameters at u; the densification exponent is options'
// densification_exponent unless `free_exponent` (then 1 + exp(u[14])).
template <typename T>
Model6ParamsT<T> params_of(const T* u, const Model6FitOptions& o, bool free_exponent) {
  using std::exp;
  Model6ParamsT<T> p;
  const T n = free_exponent ? T(1.0) + exp(u[kExponent]) : T(o.densification_exponent), ed = exp(u[4]);
  p.top = {exp(u[0]), exp(u[1]), exp(u[2]), exp(u[3]), ed, n};
  p.base = {exp(u[5]), exp(u[6]), exp(u[7]), exp(u[8]), ed, n};
  p.prony_g1 = exp(u[9]);
  p.prony_tau1_s = exp(u[10]);
  p.prony_g2 = exp(u[11]);
  p.prony_tau2_s = exp(u[12]);
  p.viscosity_pa_s = exp(u[13]);
  p.top_mass_kg = T(o.top_mass_kg);
  p.base_mass_kg = T(o.base_mass_kg);
  return p;
}

Model6Params to_params(const double* u, const Model6FitOptions& o, bool free_exponent) {
  const Model6ParamsT<double> t = params_of(u, o, free_exponent);
  auto law = [](const FoamLawT<double>& l) {
    return FoamLaw{l.plateau_pa, l.modulus_pa, l.hardening_pa, l.densification_pa, l.densification_strain,
                   l.densification_exponent};
  };
  Model6Params p;
  p.top = law(t.top);
  p.base = law(t.base);
  p.prony_g1 = t.prony_g1;
  p.prony_tau1_s = t.prony_tau1_s;
  p.prony_g2 = t.prony_g2;
  p.prony_tau2_s = t.prony_tau2_s;
  p.viscosity_pa_s = t.viscosity_pa_s;
  p.top_mass_kg = o.top_mass_kg;
  p.base_mass_kg = o.base_mass_kg;
  return p;
}

// A trial's window: which samples enter the objective, with their weights,
// and the simulation grid.
struct Window {
  const TrialData* data = nullptr;
  Impact impact;
  double h = 0.0, dt = 0.0, end_s = 0.0, peak_n = 0.0;
  int n_grid = 0;
  std::vector<int> f_idx, k_idx;
  double f_w = 0.0, k_w = 0.0;
  int n_residuals() const { return static_cast<int>(f_idx.size() + k_idx.size()); }
};

Window window_of(const TrialData& tr, const Model6FitOptions& o) {
  const Eigen::Index n = tr.t_s.size();
  if (n < 3 || tr.grf_n.size() != n) throw Error(fmt::format("trial {}: needs samples with one force each", tr.id));
  Window w;
  w.data = &tr;
  w.dt = (tr.t_s[n - 1] - tr.t_s[0]) / static_cast<double>(n - 1);
  if (!(w.dt > 0.0)) throw Error(fmt::format("trial {}: sample times must increase", tr.id));
  Eigen::Index i0 = 0;
  while (i0 < n && tr.t_s[i0] < 0.0) ++i0;
  if (i0 >= n - 2) throw Error(fmt::format("trial {}: fewer than 3 samples after contact", tr.id));
  Eigen::Index ip = i0;
  for (Eigen::Index i = i0; i < n; ++i)
    if (std::isfinite(tr.grf_n[i]) && tr.grf_n[i] > tr.grf_n[ip]) ip = i;
  w.peak_n = tr.grf_n[ip];
  // The contact ends where the force, averaged over 5 samples, falls below
  // the threshold (at least 2 % of the peak) after the peak.
  const double thr = std::max(o.contact_threshold_n, 0.02 * w.peak_n);
  Eigen::Index last = n - 1;
  for (Eigen::Index i = ip; i < n; ++i) {
    double sum = 0.0;
    int cnt = 0;
    for (Eigen::Index j = std::max<Eigen::Index>(i - 2, 0); j <= std::min<Eigen::Index>(i + 2, n - 1); ++j)
      if (std::isfinite(tr.grf_n[j])) sum += tr.grf_n[j], ++cnt;
    if (cnt > 0 && sum / cnt < thr) {
      last = i;
      break;
    }
  }
  w.end_s = std::min(tr.t_s[last] + o.window_margin_s, tr.t_s[n - 1]);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double t = tr.t_s[i];
    if (t >= -o.contact_search_s - 1e-9 && t <= w.end_s + 1e-9 && std::isfinite(tr.grf_n[i]))
      w.f_idx.push_back(static_cast<int>(i));
    if (t >= 0.0 && t <= w.end_s + 1e-9 && tr.impactor_m.size() == n && std::isfinite(tr.impactor_m[i]))
      w.k_idx.push_back(static_cast<int>(i));
  }
  w.f_w = 1.0 / std::max(std::isfinite(tr.force_noise_n) ? tr.force_noise_n : o.force_noise_n, o.min_force_noise_n);
  w.k_w = 1.0 / std::max(std::isfinite(tr.marker_noise_m) ? tr.marker_noise_m : o.marker_noise_m,
                         o.min_marker_noise_m);
  w.h = w.dt / std::max(1, o.oversample);
  w.n_grid = static_cast<int>(std::ceil((w.end_s + std::max(-o.contact_shift_min_s, 0.0) + 3.0 * w.h) / w.h)) + 1;
  w.impact.mass_kg = tr.impactor_mass_kg;
  w.impact.velocity_m_s = tr.impact_velocity_m_s;
  w.impact.gravity_m_s2 = tr.gravity_m_s2;
  w.impact.output_dt_s = w.h;
  w.impact.first_output_s = 0.0;
  w.impact.duration_s = (w.n_grid - 1) * w.h + 0.5 * w.h;
  return w;
}

// A series on the grid (step h from contact) at model time tau, Catmull-Rom
// cubic so that a Jet time carries its derivative; zero before contact.
template <typename T, typename S>
T at(const std::vector<T>& y, const S& tau, double h) {
  using std::floor;
  if (!(model6_detail::val(tau) >= 0.0)) return T(0.0);
  const S x = tau / h;
  const int i = std::min(static_cast<int>(floor(model6_detail::val(x))), static_cast<int>(y.size()) - 2);
  const S s = x - S(double(i));
  auto Y = [&](int k) { return k < 0 ? T(0.0) : y[std::min<size_t>(k, y.size() - 1)]; };
  const T p0 = Y(i - 1), p1 = Y(i), p2 = Y(i + 1), p3 = Y(i + 2);
  return p1 + T(0.5) * s * (p2 - p0 + s * (T(2.0) * p0 - T(5.0) * p1 + T(4.0) * p2 - p3 + s * (T(3.0) * (p1 - p2) + p3 - p0)));
}

struct TrialCost {
  const Window* w;
  const Model6FitOptions* o;
  const bool* free_exponent;  // the fitter's stage: held, the exponent's column is zero and LM leaves it
  template <typename T>
  bool operator()(T const* const* u, T* r) const {
    std::vector<T> grf, imp;
    try {
      simulate_model6_t<T>(params_of(u[0], *o, *free_exponent), o->geometry, w->impact, w->n_grid, &grf, &imp);
    } catch (const Error&) {
      return false;
    }
    const TrialData& tr = *w->data;
    const T shift = u[1][0];
    int k = 0;
    for (int i : w->f_idx) r[k++] = (at(grf, T(tr.t_s[i]) - shift, w->h) - T(tr.grf_n[i])) * w->f_w;
    for (int i : w->k_idx) r[k++] = (at(imp, tr.t_s[i], w->h) - T(tr.impactor_m[i])) * w->k_w;
    return true;
  }
};

// TrialCost with its derivatives: the 16 columns (15 parameters, the clock
// shift) in two passes of 8-wide Jets through the simulation, run on two
// threads (each pass is a whole simulation; the residuals alone are one
// simulation in doubles).
class TrialCostFunction : public ceres::CostFunction {
 public:
  TrialCostFunction(const Window* w, const Model6FitOptions* o, const bool* free_exponent)
      : cost_{w, o, free_exponent} {
    mutable_parameter_block_sizes()->push_back(kFree);
    mutable_parameter_block_sizes()->push_back(1);
    set_num_residuals(w->n_residuals());
  }
  bool Evaluate(double const* const* p, double* r, double** jac) const override {
    if (!jac) {
      // Ceres' projected line search and its trust region may ask for the
      // same point twice in a row: answered once.
      std::vector<double> key(p[0], p[0] + kFree);
      key.push_back(p[1][0]);
      key.push_back(*cost_.free_exponent ? 1.0 : 0.0);
      if (key == last_key_ && !last_res_.empty()) {
        std::copy(last_res_.begin(), last_res_.end(), r);
        return true;
      }
      if (!cost_(p, r)) return false;
      last_key_ = std::move(key);
      last_res_.assign(r, r + num_residuals());
      return true;
    }
    using J = ceres::Jet<double, 8>;
    const int nr = num_residuals();
    bool ok[2] = {false, false};
    auto pass = [&](int k) {
      J u[kFree], shift(p[1][0]);
      for (int i = 0; i < kFree; ++i) {
        u[i] = J(p[0][i]);
        if (i / 8 == k) u[i].v[i % 8] = 1.0;
      }
      if (k == 1) shift.v[kFree - 8] = 1.0;
      std::vector<J> out(nr);
      const J* blocks[2] = {u, &shift};
      ok[k] = cost_(blocks, out.data());
      if (!ok[k]) return;
      for (int i = 0; i < nr; ++i) {
        if (k == 0 && r) r[i] = out[i].a;
        for (int d = 0; d < 8; ++d) {
          const int col = 8 * k + d;
          if (col < kFree && jac[0]) jac[0][i * kFree + col] = out[i].v[d];
          if (col == kFree && jac[1]) jac[1][i] = out[i].v[d];
        }
      }
    };
    parallel_for(2, 2, [&](std::size_t k) { pass(static_cast<int>(k)); });
    return ok[0] && ok[1];
  }

 private:
  TrialCost cost_;
  mutable std::vector<double> last_key_, last_res_;
};

}  // namespace

// The fastest impact (one impactor mass) drives both foams furthest, so
// every other trial's strains lie inside what training showed of each law.
const TrialData* deepest_trial(const std::vector<TrialData>& trials) {
  const TrialData* out = nullptr;
  for (const TrialData& t : trials)
    if (t.accepted && (!out || t.impact_velocity_m_s > out->impact_velocity_m_s)) out = &t;
  return out;
}

namespace {

std::vector<const TrialData*> training(const std::vector<TrialData>& trials, const std::vector<std::string>& ids) {
  std::vector<const TrialData*> out;
  if (ids.empty()) {
    const TrialData* deepest = deepest_trial(trials);
    if (!deepest) throw Error("fit_model6: no accepted trial");
    out.push_back(deepest);
    return out;
  }
  for (const auto& id : ids) {
    const auto it = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == id; });
    if (it == trials.end()) throw Error(fmt::format("fit_model6: unknown training trial '{}'", id));
    out.push_back(&*it);
  }
  return out;
}

// Start and bounds (log space): a generic landing-mat foam pair, stresses
// scaled by the training trials' peak stress (120 kPa for the generic pair).
void start_and_bounds(double peak_stress_pa, double* u, double* lo, double* hi) {
  const double s = peak_stress_pa / 1.2e5;
  const double start[kFree] = {3e3 * s, 6e4 * s, 5e4 * s, 500.0 * s, 0.85, 4e4 * s, 8e5 * s,
                               1e5 * s, 5e3 * s, 0.5,       2e-3,     0.3,  0.04,    150.0, 1.0};
  for (int i = 0; i < kFree; ++i) {
    u[i] = std::log(start[i]);
    lo[i] = u[i] - std::log(30.0);
    hi[i] = u[i] + std::log(30.0);
  }
  lo[4] = std::log(0.5), hi[4] = 0.0;                        // densification strain
  lo[9] = lo[11] = std::log(0.01), hi[9] = hi[11] = std::log(5.0);  // g_i
  lo[10] = std::log(5e-4), hi[10] = std::log(1e-2);          // tau_1
  lo[12] = std::log(1e-2), hi[12] = std::log(0.3);           // tau_2
  lo[13] = std::log(1.0), hi[13] = std::log(5e3);            // eta
  lo[14] = std::log(0.3), hi[14] = std::log(3.0);            // n in [1.3, 4]
}

// The force residual's sum of squares for clock shift `shift`.
double force_ss(const Window& w, const std::vector<double>& grf, double shift) {
  double ss = 0.0;
  for (int i : w.f_idx) {
    const double d = (at(grf, w.data->t_s[i] - shift, w.h) - w.data->grf_n[i]) * w.f_w;
    ss += d * d;
  }
  return ss;
}

// The best shift in [min_s, max_s]: a 0.05 ms grid, then golden section.
double profile_shift(const Window& w, const std::vector<double>& grf, double min_s, double max_s) {
  double best = 0.0, best_ss = force_ss(w, grf, 0.0);
  for (double s = min_s; s <= max_s + 1e-12; s += 5e-5) {
    const double v = force_ss(w, grf, s);
    if (v < best_ss) best_ss = v, best = s;
  }
  double a = std::max(min_s, best - 5e-5), b = std::min(max_s, best + 5e-5);
  const double r = 0.5 * (std::sqrt(5.0) - 1.0);
  for (int it = 0; it < 30; ++it) {
    const double c = b - r * (b - a), d = a + r * (b - a);
    if (force_ss(w, grf, c) < force_ss(w, grf, d))
      b = d;
    else
      a = c;
  }
  return 0.5 * (a + b);
}

// The shift's standard error from the curvature of the force residual's
// sum of squares (noise units) at the optimum, with the residual's RMS
// over the noise as its scale when it exceeds 1 (a misfit of the trial
// counts as noise, so a model short of the noise gives a wider interval)
// and the AR(1) factor sqrt((1 + rho) / (1 - rho)) of its lag-1
// autocorrelation rho (a smooth misfit is fewer independent samples).
double shift_se(const Window& w, const std::vector<double>& grf, double shift) {
  const double d = 2e-5;
  const double s0 = force_ss(w, grf, shift);
  const double curv = (force_ss(w, grf, shift + d) - 2.0 * s0 + force_ss(w, grf, shift - d)) / (d * d);
  if (!(curv > 0.0) || w.f_idx.size() < 3) return kNaN;
  std::vector<double> r;
  for (int i : w.f_idx) r.push_back((at(grf, w.data->t_s[i] - shift, w.h) - w.data->grf_n[i]) * w.f_w);
  double lag = 0.0;
  for (size_t i = 0; i + 1 < r.size(); ++i) lag += r[i] * r[i + 1];
  const double rho = std::clamp(lag / std::max(s0, 1e-300), 0.0, 0.98);
  const double rms = std::sqrt(s0 / static_cast<double>(r.size()));
  return std::sqrt(2.0 / curv) * std::max(1.0, rms) * std::sqrt((1.0 + rho) / (1.0 - rho));
}

// The model's discrepancy in the shift: the shift that fits the loading
// part alone (the samples up to the measured peak) less the whole window's.
// A column of the right shape fits both with one contact instant (they
// differ by the noise); a misfit of the force's shape pulls them apart, and
// by about what it biases the whole window's shift.
double shift_discrepancy_s(const Window& w, const std::vector<double>& grf, double shift, double min_s,
                           double max_s) {
  Window rise = w;
  const TrialData& tr = *w.data;
  double t_peak = 0.0, peak = -1e300;
  for (int i : w.f_idx)
    if (tr.grf_n[i] > peak) peak = tr.grf_n[i], t_peak = tr.t_s[i];
  std::erase_if(rise.f_idx, [&](int i) { return tr.t_s[i] > t_peak; });
  if (rise.f_idx.size() < 5) return 0.0;
  return std::abs(profile_shift(rise, grf, min_s, max_s) - shift);
}

// The standard errors of the first kFree parameters (the logarithms) from
// (J^T J)^-1 over every parameter block (the clock shifts included), scaled
// by the residual variance when the fit is short of the noise (2 cost /
// (n - p) above 1). NaN where J^T J is singular in that direction. *cov:
// their covariance, the pseudo-inverse over the directions above that
// floor (a held coordinate's column of J is zero: its row and column 0).
Eigen::VectorXd log_standard_errors(ceres::Problem& problem, double cost, int n_residuals, Eigen::MatrixXd* cov) {
  Eigen::VectorXd se = Eigen::VectorXd::Constant(kFree, kNaN);
  *cov = Eigen::MatrixXd::Zero(kFree, kFree);
  ceres::CRSMatrix crs;
  double c = 0.0;
  if (!problem.Evaluate(ceres::Problem::EvaluateOptions{}, &c, nullptr, nullptr, &crs)) return se;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int r = 0; r < crs.num_rows; ++r)
    for (int k = crs.rows[r]; k < crs.rows[r + 1]; ++k) J(r, crs.cols[k]) = crs.values[k];
  const Eigen::MatrixXd JtJ = J.transpose() * J;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(JtJ);
  const Eigen::VectorXd& lam = eig.eigenvalues();
  const double floor = 1e-12 * std::max(lam.maxCoeff(), 1e-300);
  const int p = static_cast<int>(JtJ.rows());
  const double s2 = std::max(1.0, 2.0 * cost / std::max(1, n_residuals - p));
  for (int i = 0; i < kFree && i < p; ++i) {
    double v = 0.0;
    bool ok = true;
    for (int k = 0; k < p; ++k) {
      const double q = eig.eigenvectors()(i, k);
      if (lam[k] <= floor) {
        if (std::abs(q) > 1e-6) ok = false;
        continue;
      }
      v += q * q / lam[k];
    }
    if (ok) se[i] = std::sqrt(s2 * v);
  }
  for (int k = 0; k < p; ++k)
    if (lam[k] > floor) {
      const Eigen::VectorXd q = eig.eigenvectors().col(k).head(std::min(kFree, p));
      cov->topLeftCorner(q.size(), q.size()) += (s2 / lam[k]) * q * q.transpose();
    }
  return se;
}

}  // namespace

TrialReport predict_model6(const TrialData& trial, const Model6Params& params, const Model6FitOptions& options) {
  Window w = window_of(trial, options);
  const Eigen::Index n = trial.t_s.size();
  w.n_grid = std::max(w.n_grid,
                      static_cast<int>(std::ceil((trial.t_s[n - 1] - options.contact_shift_min_s) / w.h)) + 2);
  w.impact.duration_s = (w.n_grid - 1) * w.h + 0.5 * w.h;
  std::vector<double> grf, imp;
  Model6Extras ex;
  simulate_model6_t<double>(model6_params_t<double>(params), options.geometry, w.impact, w.n_grid, &grf, &imp, &ex);
  TrialReport rep;
  rep.id = trial.id;
  rep.impact_velocity_m_s = trial.impact_velocity_m_s;
  rep.window_end_s = w.end_s;
  const double shift = profile_shift(w, grf, options.contact_shift_min_s, options.contact_shift_max_s);
  rep.contact_shift_s = shift;
  rep.contact_shift_se_s =
      std::hypot(shift_se(w, grf, shift),
                 shift_discrepancy_s(w, grf, shift, options.contact_shift_min_s, options.contact_shift_max_s));
  Simulation& sim = rep.simulation;
  sim.t_s = trial.t_s;
  for (Eigen::VectorXd* v : {&sim.grf_n, &sim.impactor_m, &sim.surface_m, &sim.layer1_m, &sim.layer2_m}) v->setZero(n);
  sim.separation_s = ex.separation_s;
  const double v0 = trial.impact_velocity_m_s, g = trial.gravity_m_s2;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double t = trial.t_s[i];
    sim.grf_n[i] = at(grf, t - shift, w.h);
    sim.impactor_m[i] = t < 0.0 ? v0 * t + 0.5 * g * t * t : at(imp, t, w.h);
    sim.surface_m[i] = t < 0.0 ? 0.0 : at(ex.surface_m, t, w.h);
    sim.layer1_m[i] = t < 0.0 ? 0.0 : at(ex.interface_m, t, w.h);
  }
  std::vector<double> tv, fmv, fsv;
  for (int i : w.f_idx) {
    const double tc = trial.t_s[i] - shift;
    if (tc < 0.0) continue;
    tv.push_back(tc);
    fmv.push_back(trial.grf_n[i]);
    fsv.push_back(sim.grf_n[i]);
  }
  const auto nw = static_cast<Eigen::Index>(tv.size());
  const Eigen::VectorXd t = Eigen::Map<Eigen::VectorXd>(tv.data(), nw);
  const Eigen::VectorXd fm = Eigen::Map<Eigen::VectorXd>(fmv.data(), nw);
  const Eigen::VectorXd fs = Eigen::Map<Eigen::VectorXd>(fsv.data(), nw);
  rep.comparison = compare_forces(t, fm, fs);
  if (nw >= 3) {
    rep.measured = characteristics(t, fm);
    rep.simulated = characteristics(t, fs);
  }
  if (!w.k_idx.empty()) {
    double mm = -1e300, ms = -1e300, ss = 0.0;
    for (int i : w.k_idx) {
      mm = std::max(mm, trial.impactor_m[i]);
      const double d = sim.impactor_m[i] - trial.impactor_m[i];
      ss += d * d;
    }
    for (Eigen::Index i = 0; i < n; ++i)
      if (trial.t_s[i] >= 0.0 && trial.t_s[i] <= w.end_s) ms = std::max(ms, sim.impactor_m[i]);
    rep.max_deformation_mm_diff = 1000.0 * (ms - mm);
    rep.rms_impactor_mm = 1000.0 * std::sqrt(ss / static_cast<double>(w.k_idx.size()));
  }
  return rep;
}

namespace {

// Stops a solve once options.cancel is set (fit_model6 then throws).
class CancelCallback : public ceres::IterationCallback {
 public:
  explicit CancelCallback(const std::atomic<bool>* cancel) : cancel_(cancel) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary&) override {
    return cancel_ && cancel_->load() ? ceres::SOLVER_ABORT : ceres::SOLVER_CONTINUE;
  }

 private:
  const std::atomic<bool>* cancel_;
};

// Stops a second-stage solve that cannot end below `must_beat` (the cost
// it has to beat to be kept): checked every kChunk iterations, the solve
// stops when its cost, less what it would still gain at its last chunk's
// rate for every chunk it has left, stays above must_beat. Where the
// search ends (the rate is falling) that bound holds; a run crawling in a
// worse basin stops without its last iterations.
class BehindCallback : public ceres::IterationCallback {
 public:
  static constexpr int kChunk = 10;
  BehindCallback(double must_beat, int max_iterations) : must_beat_(must_beat), max_iterations_(max_iterations) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& it) override {
    if (it.iteration == 0) chunk_start_ = it.cost;
    if (!std::isfinite(must_beat_) || it.iteration == 0 || it.iteration % kChunk != 0) return ceres::SOLVER_CONTINUE;
    const double cost = it.cost;
    const double gain = std::max(0.0, chunk_start_ - cost);
    chunk_start_ = cost;
    const double chunks_left = std::ceil(static_cast<double>(max_iterations_ - it.iteration) / kChunk);
    return cost - chunks_left * gain > must_beat_ ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  double must_beat_;
  int max_iterations_;
  double chunk_start_ = std::numeric_limits<double>::infinity();
};

// The solver's settings of every solve here. With bounds, Ceres follows
// each trust-region step by a projected Armijo line search; with its
// default cubic interpolation each trial point costs a Jacobian (two
// 8-wide Jet passes), with quadratic interpolation only the cost (one
// simulation in doubles). At most 3 trial points: after those the trust
// region judges the step itself.
ceres::Solver::Options solver_options(const Model6FitOptions& options, CancelCallback* cancel) {
  ceres::Solver::Options so;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  so.line_search_interpolation_type = ceres::QUADRATIC;
  so.max_num_line_search_step_size_iterations = 3;
  if (options.cancel) so.callbacks.push_back(cancel);
  return so;
}

void throw_if_cancelled(const Model6FitOptions& options) {
  if (options.cancel && options.cancel->load()) throw Error("fit_model6: cancelled");
}

// The first stage with the clock shifts held within each round and each
// re-profiled for the current parameters between rounds; returns the
// iterations taken.
long reprofiled_rounds(ceres::Problem& problem, const ceres::Solver::Options& so, const double* u,
                       std::vector<double>& shifts, const std::vector<Window>& windows,
                       const Model6FitOptions& options, bool free_exponent, ceres::Solver::Summary& summary) {
  long iterations = 0;
  for (int round = 0; round < options.stage_rounds; ++round) {
    ceres::Solve(so, &problem, &summary);
    iterations += static_cast<long>(summary.iterations.size());
    const Model6ParamsT<double> p = model6_params_t<double>(to_params(u, options, free_exponent));
    for (size_t k = 0; k < windows.size(); ++k) {
      std::vector<double> grf;
      try {
        simulate_model6_t<double>(p, options.geometry, windows[k].impact, windows[k].n_grid, &grf, nullptr);
      } catch (const Error&) {
        continue;
      }
      shifts[k] = profile_shift(windows[k], grf, options.contact_shift_min_s, options.contact_shift_max_s);
    }
  }
  return iterations;
}

// The whole search from the start u0 (into u, shifts): the first stage with
// the clock shifts held, run twice (held at the contact estimate
// throughout, and re-profiled between rounds), then the second stage
// (shifts free) from each first-stage end; the lower final cost is the fit
// (the cheaper first-stage end need not lead to the cheaper optimum). A
// second-stage solve that cannot end below must_beat (what the search
// around this one keeps it against) nor below the other second-stage end
// stops early (BehindCallback). Returns the iterations taken; `summary` is
// the fit's.
long fit_staged(ceres::Problem& problem, const double* u0, double* u, std::vector<double>& shifts,
                const std::vector<Window>& windows, const Model6FitOptions& options, bool free_exponent,
                double must_beat, ceres::Solver::Summary& summary) {
  CancelCallback cancel(options.cancel);
  ceres::Solver::Options so = solver_options(options, &cancel);
  std::copy(u0, u0 + kFree, u);
  std::fill(shifts.begin(), shifts.end(), 0.0);
  for (double& sh : shifts) problem.SetParameterBlockConstant(&sh);
  long iterations = 0;
  so.max_num_iterations = options.stage_rounds * options.stage_iterations;
  ceres::Solve(so, &problem, &summary);
  iterations += static_cast<long>(summary.iterations.size());
  double held_u[kFree];
  std::copy(u, u + kFree, held_u);
  std::copy(u0, u0 + kFree, u);
  so.max_num_iterations = options.stage_iterations;
  iterations += reprofiled_rounds(problem, so, u, shifts, windows, options, free_exponent, summary);
  for (double& sh : shifts) problem.SetParameterBlockVariable(&sh);
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  auto second_stage = [&](double bound) {
    ceres::Solver::Options o = so;
    BehindCallback behind(bound, o.max_num_iterations);
    o.callbacks.push_back(&behind);
    ceres::Solve(o, &problem, &summary);
    iterations += static_cast<long>(summary.iterations.size());
  };
  second_stage(must_beat);
  double best_u[kFree];
  std::copy(u, u + kFree, best_u);
  const std::vector<double> best_shifts = shifts;
  const ceres::Solver::Summary profiled_summary = summary;
  std::copy(held_u, held_u + kFree, u);
  std::fill(shifts.begin(), shifts.end(), 0.0);
  second_stage(std::min(must_beat, profiled_summary.final_cost));
  if (!(summary.final_cost < profiled_summary.final_cost)) {
    std::copy(best_u, best_u + kFree, u);
    std::copy(best_shifts.begin(), best_shifts.end(), shifts.begin());  // in place: the problem holds their addresses
    summary = profiled_summary;
  }
  return iterations;
}

// The largest strains of the top and bottom elements over the trial's
// contact window in the column `params`.
Model6Reach column_reach(const TrialData& trial, const Model6Params& params, const Model6FitOptions& options) {
  const Window w = window_of(trial, options);
  Model6Extras ex;
  simulate_model6_t<double>(model6_params_t<double>(params), options.geometry, w.impact, w.n_grid, nullptr, nullptr,
                            &ex);
  Model6Reach r;
  r.id = trial.id;
  for (double e : ex.top_strain) r.max_top_strain = std::max(r.max_top_strain, e);
  for (double e : ex.base_strain) r.max_base_strain = std::max(r.max_base_strain, e);
  return r;
}

// Each trial's reach (res.reach) and a warning for each held-out trial that
// drives a foam beyond the training trials' reach by more than
// extrapolation_ratio in r = e / (e_d - e).
void check_extrapolation(const std::vector<TrialData>& trials, const Model6FitOptions& options,
                         Model6FitResult& res) {
  double top = 0.0, base = 0.0;
  for (const TrialData& t : trials) {
    Model6Reach r = column_reach(t, res.params, options);
    r.train = std::find(res.train_ids.begin(), res.train_ids.end(), t.id) != res.train_ids.end();
    if (r.train) top = std::max(top, r.max_top_strain), base = std::max(base, r.max_base_strain);
    res.reach.push_back(r);
  }
  auto deeper = [&](double e, double e_train, const FoamLaw& law) {
    const double ed = law.densification_strain;
    const double r = e / std::max(ed - e, 1e-3), r_train = e_train / std::max(ed - e_train, 1e-3);
    return r > options.extrapolation_ratio * r_train;
  };
  for (Model6Reach& r : res.reach) {
    if (r.train) continue;
    const bool top_beyond = deeper(r.max_top_strain, top, res.params.top);
    const bool base_beyond = deeper(r.max_base_strain, base, res.params.base);
    if (!top_beyond && !base_beyond) continue;
    r.extrapolated = true;
    const bool b = base_beyond;
    res.warnings.push_back(fmt::format(
        "{} drives the {} foam to {:.2f} strain, beyond the {:.2f} the training trial{} reached: its "
        "prediction extrapolates that foam's law past the strains the training data show (a densification the "
        "training impact did not reach is the fit's guess, not a measurement), so its error can exceed the "
        "training fit's",
        r.id, b ? "base" : "top", b ? r.max_base_strain : r.max_top_strain, b ? base : top,
        res.train_ids.size() > 1 ? "s" : ""));
  }
}

// The start the search goes on from (into u0): the generic start with the
// base foam's four stresses scaled by each of options.start_base_scales,
// each run for options.screen_iterations with the clock shifts held at the
// contact estimate; the lowest cost wins. How stiff the base foam is beside
// the top one is what a generic start knows least (a training impact may
// barely take the base past its linear part), and from the wrong side the
// search can end in a basin whose base hardens where the true base yields.
// u is the problem's parameter block. Returns the iterations taken.
long screen_starts(ceres::Problem& problem, double* u, double* u0, const double* lo, const double* hi,
                   std::vector<double>& shifts, const Model6FitOptions& options) {
  CancelCallback cancel(options.cancel);
  ceres::Solver::Options so = solver_options(options, &cancel);
  so.max_num_iterations = options.screen_iterations;
  for (double& sh : shifts) problem.SetParameterBlockConstant(&sh);
  long iterations = 0;
  double best_cost = std::numeric_limits<double>::infinity(), best[kFree];
  std::copy(u0, u0 + kFree, best);
  for (double scale : options.start_base_scales) {
    if (scale == 1.0) continue;  // the generic start, searched already
    double start[kFree];
    std::copy(u0, u0 + kFree, start);
    for (int i : {5, 6, 7, 8}) start[i] = std::clamp(u0[i] + std::log(scale), lo[i], hi[i]);
    std::copy(start, start + kFree, u);
    std::fill(shifts.begin(), shifts.end(), 0.0);
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    iterations += static_cast<long>(summary.iterations.size());
    if (summary.final_cost < best_cost) best_cost = summary.final_cost, std::copy(start, start + kFree, best);
  }
  for (double& sh : shifts) problem.SetParameterBlockVariable(&sh);
  std::copy(best, best + kFree, u0);
  return iterations;
}

// The problem fit_model6 searches: its parameter block u, the training
// trials' clock shifts (both held by the problem at their addresses) and
// which exponent path is on.
struct Search {
  ceres::Problem* problem;
  double* u;
  std::vector<double>* shifts;
  const std::vector<Window>* windows;
  const Model6FitOptions* options;
  bool* free_exponent;
  int n_res;
};

// The whole search from the start u0 (into s.u, s.shifts), two paths
// (fit_staged): the densification exponent held at options' value, then
// free. The foams' densification steepness differs (n from about 1.5 to 3),
// and a curve of the wrong steepness at the training impact's deepest
// strain misfits the peak and misplaces the contact; but with n free the
// other parameters can also end in a worse basin, and one more parameter
// lowers the cost of any misfit a little. The free path runs when the held
// fit is short of the noise (its RMS residual above free_exponent_min_rms
// noise SDs), and its exponent is kept when it ends at
// free_exponent_cost_ratio of the held path's cost or below. A search that
// is kept only below must_beat (a restart against the first search's cost)
// passes it on, the free path with its own bound beside it. Returns the
// iterations taken.
long search_from(Search& s, const double* u0, double must_beat, ceres::Solver::Summary& summary) {
  const Model6FitOptions& options = *s.options;
  *s.free_exponent = false;
  long iterations = fit_staged(*s.problem, u0, s.u, *s.shifts, *s.windows, options, false, must_beat, summary);
  throw_if_cancelled(options);
  double held_u[kFree];
  std::copy(s.u, s.u + kFree, held_u);
  const std::vector<double> held_shifts = *s.shifts;
  const ceres::Solver::Summary held_summary = summary;
  const double held_rms = std::sqrt(2.0 * held_summary.final_cost / std::max(1, s.n_res));
  if (held_rms > options.free_exponent_min_rms) {
    *s.free_exponent = true;
    const double free_must_beat = std::min(must_beat, options.free_exponent_cost_ratio * held_summary.final_cost);
    iterations += fit_staged(*s.problem, u0, s.u, *s.shifts, *s.windows, options, true, free_must_beat, summary);
    throw_if_cancelled(options);
  }
  if (*s.free_exponent && !(summary.final_cost <= options.free_exponent_cost_ratio * held_summary.final_cost)) {
    *s.free_exponent = false;
    std::copy(held_u, held_u + kFree, s.u);
    std::copy(held_shifts.begin(), held_shifts.end(), s.shifts->begin());  // in place: the problem holds their addresses
    summary = held_summary;
  }
  return iterations;
}

}  // namespace

Model6FitResult fit_model6(const std::vector<TrialData>& trials, const Model6FitOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<const TrialData*> train = training(trials, options.train_ids);
  std::vector<Window> windows;
  windows.reserve(train.size());
  double peak = 0.0;
  for (const TrialData* t : train) {
    windows.push_back(window_of(*t, options));
    peak = std::max(peak, windows.back().peak_n);
  }
  double u[kFree], lo[kFree], hi[kFree];
  start_and_bounds(peak / options.geometry.area_m2, u, lo, hi);
  u[kExponent] = std::clamp(std::log(options.densification_exponent - 1.0), lo[kExponent], hi[kExponent]);
  bool free_exponent = false;
  // The clock shifts start at the contact estimate and are held in a first
  // stage: freed from a generic start, they ran to their bound on the
  // generator's foams (the force matched 3 ms early, the travel 6-8 mm
  // deep) instead of the mat moving to its basin. Held at the contact
  // estimate, which reads the column's onset lag, the mat can move to a
  // wrong basin when that lag is large; re-profiled between rounds, it can
  // too on another foam: both are run (below).
  std::vector<double> shifts(train.size(), 0.0);
  ceres::Problem problem;
  int n_res = 0;
  for (size_t k = 0; k < windows.size(); ++k) {
    auto* cf = new TrialCostFunction(&windows[k], &options, &free_exponent);
    n_res += windows[k].n_residuals();
    problem.AddResidualBlock(cf, nullptr, u, &shifts[k]);
    problem.SetParameterLowerBound(&shifts[k], 0, options.contact_shift_min_s);
    problem.SetParameterUpperBound(&shifts[k], 0, options.contact_shift_max_s);
  }
  for (int i = 0; i < kFree; ++i) {
    problem.SetParameterLowerBound(u, i, lo[i]);
    problem.SetParameterUpperBound(u, i, hi[i]);
  }
  double u0[kFree];
  std::copy(u, u + kFree, u0);
  ceres::Solver::Summary summary;
  Search search{&problem, u, &shifts, &windows, &options, &free_exponent, n_res};
  long iterations = search_from(search, u0, std::numeric_limits<double>::infinity(), summary);
  // A fit short of the noise may be a wrong basin of the generic start:
  // the search runs again from the start the screen prefers among the base
  // foam's other stiffnesses, and the lower cost is the fit.
  const auto& scales = options.start_base_scales;
  if (std::sqrt(2.0 * summary.final_cost / std::max(1, n_res)) > options.restart_min_rms &&
      std::any_of(scales.begin(), scales.end(), [](double x) { return x != 1.0; })) {
    double first_u[kFree];
    std::copy(u, u + kFree, first_u);
    const std::vector<double> first_shifts = shifts;
    const ceres::Solver::Summary first_summary = summary;
    const bool first_free = free_exponent;
    double u1[kFree];
    std::copy(u0, u0 + kFree, u1);
    iterations += screen_starts(problem, u, u1, lo, hi, shifts, options);
    throw_if_cancelled(options);
    iterations += search_from(search, u1, first_summary.final_cost, summary);
    if (!(summary.final_cost < first_summary.final_cost)) {
      std::copy(first_u, first_u + kFree, u);
      std::copy(first_shifts.begin(), first_shifts.end(), shifts.begin());  // in place: the problem holds their addresses
      summary = first_summary;
      free_exponent = first_free;
    }
  }

  Model6FitResult res;
  res.params = to_params(u, options, free_exponent);
  for (const TrialData* t : train) res.train_ids.push_back(t->id);
  res.cost = summary.final_cost;
  res.n_residuals = n_res;
  res.iterations = iterations;
  const Eigen::VectorXd log_se = log_standard_errors(problem, summary.final_cost, n_res, &res.coordinate_covariance);
  res.coordinates = Eigen::Map<const Eigen::VectorXd>(u, kFree);
  res.free_exponent = free_exponent;
  for (int i = 0; i < kFree; ++i) {
    if (i == kExponent && !free_exponent) continue;  // held: a fixed number of the law, not an estimate
    ParameterEstimate e;
    e.name = free_names()[i];
    // n is fitted as log(n - 1).
    const double offset = i == kExponent ? 1.0 : 0.0;
    e.value = offset + std::exp(u[i]);
    e.at_bound = u[i] - lo[i] < 1e-3 * (hi[i] - lo[i]) || hi[i] - u[i] < 1e-3 * (hi[i] - lo[i]);
    // Delta method on the logarithm: se = exp(u) x se(u).
    e.se = std::exp(u[i]) * log_se[i];
    e.rel_se = e.se / e.value;
    e.identifiable = std::isfinite(log_se[i]) && log_se[i] < 1.0;
    // No 95 % interval: the column's effective value (kEffectiveNote).
    e.note = e.at_bound ? "the bound, not the data, sets it" : kEffectiveNote;
    res.estimates.push_back(e);
  }
  // Per channel, the training residual's RMS in noise units.
  double ff = 0.0, kk = 0.0;
  int nf = 0, nk = 0;
  for (size_t k = 0; k < windows.size(); ++k) {
    const TrialReport rep = predict_model6(*windows[k].data, res.params, options);
    for (int i : windows[k].f_idx) {
      const double d = (rep.simulation.grf_n[i] - windows[k].data->grf_n[i]) * windows[k].f_w;
      ff += d * d, ++nf;
    }
    for (int i : windows[k].k_idx) {
      const double d = (rep.simulation.impactor_m[i] - windows[k].data->impactor_m[i]) * windows[k].k_w;
      kk += d * d, ++nk;
    }
  }
  res.force_rms_sigma = nf ? std::sqrt(ff / nf) : kNaN;
  res.impactor_rms_sigma = nk ? std::sqrt(kk / nk) : kNaN;
  for (const TrialData& t : trials) {
    TrialReport rep = predict_model6(t, res.params, options);
    rep.train = std::find(res.train_ids.begin(), res.train_ids.end(), t.id) != res.train_ids.end();
    res.trials.push_back(std::move(rep));
  }
  check_extrapolation(trials, options, res);
  add_model6_prediction_intervals(trials, options, res);
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

Model6Params model6_params_at(const Eigen::VectorXd& coordinates, const Model6FitOptions& options,
                              bool free_exponent) {
  if (coordinates.size() != kFree) throw Error(fmt::format("model6_params_at: {} coordinates, not {}", coordinates.size(), kFree));
  return to_params(coordinates.data(), options, free_exponent);
}

}  // namespace dropfit::fitting
