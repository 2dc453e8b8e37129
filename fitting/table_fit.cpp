// Table mode: the mat models fitted to per-trial summaries (see table_fit.h).
#include "fitting/table_fit.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <utility>

#include "core/error.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting {

namespace {

// RK4 (effects on): the same step as simulate() takes (fitting/models.h).
const double kRk4Step = SimulateOptions{}.rk4_max_step_s;

inline bool finite_all(double x) { return std::isfinite(x); }
template <typename J>
bool finite_all(const J& x) {
  return ceres::isfinite(x);  // value and derivatives
}

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

// The training trials: the given ids, or the median-velocity trial.
std::vector<const TableTrial*> table_train(const std::vector<TableTrial>& trials, const TableFitOptions& o) {
  std::vector<const TableTrial*> train;
  if (o.train_ids.empty()) {
    std::vector<const TableTrial*> all;
    for (const auto& t : trials) all.push_back(&t);
    std::sort(all.begin(), all.end(), [](auto* a, auto* b) { return a->impact_velocity_m_s < b->impact_velocity_m_s; });
    train.push_back(all[(all.size() - 1) / 2]);
    return train;
  }
  for (const auto& id : o.train_ids) {
    auto it = std::find_if(trials.begin(), trials.end(), [&](const TableTrial& t) { return t.id == id; });
    if (it == trials.end()) throw Error(fmt::format("fit_table: training trial '{}' not found", id));
    train.push_back(&*it);
  }
  return train;
}

// The effective stiffness the training summaries show: peak force over
// maximum deformation (where the deformation is not given, a linear
// spring's F x = M v^2), the median over the training trials.
double table_k_eff(const std::vector<const TableTrial*>& train, const TableFitOptions& o) {
  std::vector<double> ks;
  for (const TableTrial* t : train) {
    const double F = t->peak_force_n, v = t->impact_velocity_m_s;
    if (!(F > 0.0)) continue;
    const double x = t->max_deformation_m > 0.0 ? t->max_deformation_m : o.impactor_mass_kg * v * v / F;
    if (x > 0.0) ks.push_back(F / x);
  }
  if (ks.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(ks.begin(), ks.end());
  return ks[ks.size() / 2];
}

// The box the search moves in (log of each free parameter). Stiffness:
// no series spring softer than a fraction of the effective stiffness (the
// series is softer than its softest spring), none beyond a multiple of it
// (rigid for this mat). Damping: up to a multiple of the impactor's
// critical damping on the effective stiffness.
struct Box {
  std::vector<double> lo, hi;
};

Box table_box(const std::vector<int>& idx, const TableFitOptions& o, double k_eff) {
  const bool data = std::isfinite(k_eff) && k_eff > 0.0;
  const double r_crit = data ? 2.0 * std::sqrt(k_eff * o.impactor_mass_kg) : 0.0;
  Box b;
  for (int f : idx) {
    double lo, hi;
    if (f < 3) {
      lo = data ? std::max(1e3, o.k_eff_lower_ratio * k_eff) : 1e3;
      hi = data ? std::min(1e8, o.k_eff_upper_ratio * k_eff) : 1e8;
    } else if (f < 6) {
      lo = 0.1;
      hi = data ? std::min(1e5, o.damping_ratio_max * r_crit) : 1e5;
    } else {
      lo = 1e-3;
      hi = 100.0;
    }
    if (!(hi > lo * 1.01)) hi = lo * 10.0;
    b.lo.push_back(std::log(lo));
    b.hi.push_back(std::log(hi));
  }
  return b;
}

// A start from the data: the effective stiffness in the softest spring
// (the top one), the others ten or more times stiffer, light damping (a
// fraction of critical on the impactor).
double table_guess(int f, ModelKind model, double k_eff, const TableFitOptions& o) {
  const double k = std::isfinite(k_eff) && k_eff > 0.0 ? k_eff : 1e5;
  const double rc = 2.0 * std::sqrt(k * o.impactor_mass_kg);
  const bool chain3 = model == ModelKind::Model3, chain4 = model == ModelKind::Model4;
  switch (f) {
    case 0: return k * (chain4 ? 1.2 : chain3 ? 1.1 : 1.0);
    case 1: return k * (chain4 ? 15.0 : 11.0);
    case 2: return 10.0 * k;
    case 3: return rc * (chain4 ? 0.05 : chain3 ? 0.1 : 0.2);
    case 4:
    case 5: return 0.2 * rc;
    default: return o.base.m_eff_kg > 0.0 ? o.base.m_eff_kg : 1.0;
  }
}

// The starts (log space, inside the box): the data's guess, the given base
// values (where set), then random points within +-1.5 (a factor 4.5) of
// the data's guess.
std::vector<std::vector<double>> table_starts(const std::vector<int>& idx, const TableFitOptions& o, double k_eff,
                                              const Box& box) {
  const int n = static_cast<int>(idx.size());
  std::vector<double> guess(n), given(n);
  bool any_given = false;
  for (int i = 0; i < n; ++i) {
    guess[i] = std::log(table_guess(idx[i], o.model, k_eff, o));
    const double v = get_parameter(o.base, o.free[i]);
    given[i] = v > 0.0 ? std::log(v) : guess[i];
    any_given = any_given || v > 0.0;
  }
  std::vector<std::vector<double>> starts = {guess};
  if (any_given && o.starts > 1) starts.push_back(given);
  std::mt19937_64 rng(o.seed);
  while (static_cast<int>(starts.size()) < o.starts) {
    std::vector<double> u = guess;
    for (auto& x : u) x += std::uniform_real_distribution<double>(-1.5, 1.5)(rng);
    starts.push_back(u);
  }
  for (auto& u : starts)
    for (int i = 0; i < n; ++i) u[i] = std::clamp(u[i], box.lo[i], box.hi[i]);
  return starts;
}

// Levenberg-Marquardt from one start; false when it did not end usable.
bool table_solve(const std::vector<const TableTrial*>& train, const TableFitOptions& o, const std::vector<int>& idx,
                 const detail::Layout& layout, const Box& box, std::vector<double>* u, double* cost) {
  const int n = static_cast<int>(idx.size());
  ceres::Problem problem;
  for (const TableTrial* t : train) {
    auto* c = new ceres::DynamicAutoDiffCostFunction<TableCost, 8>(new TableCost{&o, t, idx, layout});
    c->AddParameterBlock(n);
    c->SetNumResiduals(2);
    problem.AddResidualBlock(c, nullptr, u->data());
  }
  for (int i = 0; i < n; ++i) {
    problem.SetParameterLowerBound(u->data(), i, box.lo[i]);
    problem.SetParameterUpperBound(u->data(), i, box.hi[i]);
  }
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = 200;
  so.function_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary sum;
  ceres::Solve(so, &problem, &sum);
  *cost = sum.final_cost;
  return sum.IsSolutionUsable();
}

MatParams table_params(const TableFitOptions& o, const std::vector<double>& u) {
  MatParams p = o.base;
  for (size_t i = 0; i < u.size(); ++i) set_parameter(p, o.free[i], std::exp(u[i]));
  return p;
}

// Why an optimum is not a mat for the training impacts (empty: it is).
std::string table_degenerate_on(const TableFitOptions& o, const MatParams& p,
                                const std::vector<const TableTrial*>& train) {
  for (const TableTrial* t : train) {
    const std::string why = table_degenerate(o, p, t->impact_velocity_m_s);
    if (!why.empty()) return fmt::format("impact {}: {}", t->id, why);
  }
  return "";
}

TableTrialReport table_report(const TableFitOptions& o, const MatParams& p, const TableTrial& t, bool train) {
  const Simulation s = table_sim(o, p, t.impact_velocity_m_s);
  TableTrialReport r;
  r.id = t.id;
  r.train = train;
  r.impact_velocity_m_s = t.impact_velocity_m_s;
  r.peak_force_n = t.peak_force_n;
  r.simulated_peak_force_n = s.grf_n.maxCoeff();
  r.peak_force_pct_diff = 100.0 * (r.simulated_peak_force_n - t.peak_force_n) / t.peak_force_n;
  r.max_deformation_m = t.max_deformation_m;
  r.simulated_max_deformation_m = s.impactor_m.maxCoeff();
  return r;
}

}  // namespace

std::vector<std::string> table_free(ModelKind model) {
  switch (model) {
    case ModelKind::Model1: return {"k1_n_m", "r1_n_s_m"};
    case ModelKind::Model2: return {"k1_n_m", "r1_n_s_m", "m_eff_kg"};
    case ModelKind::Model3: return {"k1_n_m", "k2_n_m", "r1_n_s_m", "r2_n_s_m"};
    default: return {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m"};
  }
}

TableFitOptions table_options(ModelKind model, double impactor_mass_kg, double m1_kg, double m2_kg) {
  TableFitOptions o;
  o.model = model;
  o.base = paper_table2(model, model == ModelKind::Model2 ? 2.0 : 0.0);
  o.base.m1_kg = m1_kg;
  o.base.m2_kg = m2_kg;
  o.free = table_free(model);
  o.impactor_mass_kg = impactor_mass_kg;
  return o;
}

std::string table_degenerate(const TableFitOptions& o, const MatParams& p, double velocity_m_s) {
  Impact imp;
  imp.mass_kg = o.impactor_mass_kg;
  imp.gravity_m_s2 = o.gravity_m_s2;
  imp.velocity_m_s = velocity_m_s;
  imp.output_dt_s = 5e-4;
  imp.duration_s = o.rebound_horizon_s;
  Simulation s;
  try {
    s = simulate(o.model, p, imp);
  } catch (const Error& e) {
    return fmt::format("the model does not run ({})", e.what());
  }
  Eigen::Index ip = 0;
  s.grf_n.maxCoeff(&ip);
  const double t_peak = s.t_s[ip];
  if (t_peak < o.contact_peak_s)
    return fmt::format("the simulated peak force comes at contact ({:.1f} ms after it): the damper, not the spring, "
                       "sets it",
                       1e3 * t_peak);
  if (!std::isfinite(s.separation_s))
    return fmt::format("the impactor never leaves the mat (still in it {:.2g} s after contact)", o.rebound_horizon_s);
  return "";
}

TableFitResult fit_table(const std::vector<TableTrial>& trials, const TableFitOptions& options) {
  if (trials.empty()) throw Error("fit_table: no trials");
  if (options.model == ModelKind::Model5) throw Error("fit_table: Model 5 is not supported in table mode");
  if (options.free.empty()) throw Error("fit_table: nothing to fit");
  if (options.starts < 1) throw Error("fit_table: starts must be at least 1");
  const std::vector<const TableTrial*> train = table_train(trials, options);
  std::vector<int> idx;
  for (const auto& n : options.free) idx.push_back(table_index(n));
  const int n = static_cast<int>(idx.size());
  const detail::Layout layout =
      detail::layout_for(options.model, options.model == ModelKind::Model2 && options.base.m_eff_kg <= 0.0 &&
                                            std::find(idx.begin(), idx.end(), 6) == idx.end());
  const double k_eff = table_k_eff(train, options);
  const Box box = table_box(idx, options, k_eff);

  std::vector<std::pair<double, std::vector<double>>> optima;
  for (std::vector<double> u : table_starts(idx, options, k_eff, box)) {
    double cost = 0.0;
    if (table_solve(train, options, idx, layout, box, &u, &cost)) optima.push_back({cost, u});
  }
  if (optima.empty()) throw Error("fit_table: every start failed");
  std::sort(optima.begin(), optima.end());

  // The best optimum that is a mat (its peak after contact, the impactor
  // leaving it); degenerate optima are counted, never returned.
  TableFitResult res;
  std::vector<std::vector<double>> kept;
  int degenerate = 0;
  std::string first_reason;
  for (const auto& [c, u] : optima) {
    bool seen = false;
    for (const auto& d : kept) {
      double dmax = 0.0;
      for (int i = 0; i < n; ++i) dmax = std::max(dmax, std::abs(u[i] - d[i]));
      if (dmax < 0.01) seen = true;
    }
    if (seen) continue;
    const MatParams p = table_params(options, u);
    const std::string why = table_degenerate_on(options, p, train);
    if (!why.empty()) {
      ++degenerate;
      if (first_reason.empty()) first_reason = why;
      continue;
    }
    if (kept.empty()) {
      res.params = p;
      res.cost = c;
    } else if (c <= res.cost + 0.5) {
      // Another optimum that fits as well (within half a unit of
      // chi-square): summaries rarely pin a model down uniquely.
      res.alternatives.push_back(p);
    } else {
      continue;
    }
    kept.push_back(u);
  }
  if (kept.empty()) {
    res.params = table_params(options, optima.front().second);
    res.cost = optima.front().first;
    res.refused = first_reason;
    res.warnings.push_back("no optimum is a physical mat: " + first_reason);
  } else if (degenerate > 0) {
    res.warnings.push_back(fmt::format("{} degenerate optimum(s) set aside (e.g. {})", degenerate, first_reason));
  }
  if (!res.alternatives.empty())
    res.warnings.push_back(fmt::format("{} other parameter sets fit the training summaries as well (see alternatives)",
                                       res.alternatives.size()));
  if (2 * static_cast<int>(train.size()) < n)
    res.warnings.push_back(fmt::format("{} parameters from {} numbers: not all are identifiable", n, 2 * train.size()));
  for (const auto& t : trials)
    res.trials.push_back(table_report(options, res.params, t, std::find(train.begin(), train.end(), &t) != train.end()));
  return res;
}

std::vector<TableHeldOut> table_leave_one_out(const std::vector<TableTrial>& trials, const TableFitOptions& options,
                                              std::vector<std::string>* notes) {
  std::vector<TableHeldOut> out;
  for (const auto& held : trials) {
    TableFitOptions o = options;
    o.train_ids.clear();
    for (const auto& t : trials)
      if (t.id != held.id) o.train_ids.push_back(t.id);
    const TableFitResult fit = fit_table(trials, o);
    if (!fit.refused.empty()) {
      if (notes) notes->push_back(fmt::format("impact {} left out: no physical fit ({})", held.id, fit.refused));
      continue;
    }
    for (const auto& r : fit.trials) {
      if (r.id != held.id) continue;
      out.push_back({held.id, fit.params, r.impact_velocity_m_s, r.peak_force_n, r.simulated_peak_force_n,
                     r.peak_force_pct_diff, r.max_deformation_m, r.simulated_max_deformation_m});
    }
  }
  return out;
}

TablePeakCurve table_peak_curve(const std::vector<TableTrial>& trials, const TableFitOptions& options,
                                const MatParams& params, int points) {
  TablePeakCurve c;
  if (trials.empty() || points < 2) return c;
  double vmin = trials.front().impact_velocity_m_s, vmax = vmin;
  for (const auto& t : trials) {
    vmin = std::min(vmin, t.impact_velocity_m_s);
    vmax = std::max(vmax, t.impact_velocity_m_s);
  }
  for (int i = 0; i < points; ++i) {
    const double v = (0.9 * vmin) + (1.1 * vmax - 0.9 * vmin) * i / static_cast<double>(points - 1);
    c.velocity_m_s.push_back(v);
    c.peak_force_n.push_back(table_sim(options, params, v).grf_n.maxCoeff());
  }
  return c;
}

}  // namespace dropfit::fitting
