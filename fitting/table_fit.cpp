// Table mode: the mat models fitted to per-trial summaries (see fit.h).
#include "fitting/fit.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
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
