// Table mode of the mat stage: per-trial summaries only (the paper's Table 1).
//
// The baseline is a linear model fitted to peak force and maximum deformation;
// its leave-one-trial-out peak-force errors are tested for a trend with
// impact velocity. In a linear model every peak scales with the impact
// velocity (gravity aside), so such a trend needs a term that is nonlinear in
// the loading phase: of the library's effects only stiffening is (hysteresis
// acts while unloading, the Maxwell arm is linear, layer masses are linear).
// fitting::fit_table does not fit effect terms (yet), so the fits here are
// small Ceres problems over fitting::simulate (numeric derivatives).
#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

using fitting::MatParams;

constexpr double kCubicScale = 1e7;  // k1_cubic = kCubicScale * u

struct Peaks {
  double force_n = kNaN, travel_m = kNaN;
};

Peaks simulate_peaks(const TableStageOptions& o, const MatParams& p, double v) {
  fitting::Impact imp;
  imp.mass_kg = o.impactor_mass_kg;
  imp.gravity_m_s2 = o.gravity_m_s2;
  imp.velocity_m_s = v;
  imp.output_dt_s = 2e-4;
  // Peak force and largest travel come well within the first half-period of
  // a landing mat (about 60 ms for the paper's); 0.15 s leaves room.
  imp.duration_s = 0.15;
  const fitting::Simulation s = fitting::simulate(o.model, p, imp);
  return {s.grf_n.maxCoeff(), s.impactor_m.maxCoeff()};
}

MatParams params_of(const TableStageOptions& o, const double* u, bool cubic) {
  MatParams p = o.base;
  p.k1_n_m = std::exp(u[0]);
  p.r1_n_s_m = std::exp(u[1]);
  p.k1_cubic_n_m3 = cubic ? kCubicScale * std::max(u[2], 0.0) : 0.0;
  return p;
}

// Residuals of one trial: peak force and maximum travel at the trial's
// velocity plus its correction (the second parameter block, when the
// velocity is treated as uncertain).
struct TableCost {
  const TableStageOptions* o;
  const fitting::TableTrial* t;
  bool cubic;
  bool use_peak = true;
  bool with_delta = false;
  bool operator()(double const* const* u, double* res) const {
    const double v = t->impact_velocity_m_s + (with_delta ? u[1][0] : 0.0);
    try {
      const Peaks pk = simulate_peaks(*o, params_of(*o, u[0], cubic), v);
      res[0] = use_peak ? (pk.force_n - t->peak_force_n) / o->peak_noise_n : 0.0;
      res[1] = std::isfinite(t->max_deformation_m) ? (pk.travel_m - t->max_deformation_m) / o->deformation_noise_m : 0.0;
    } catch (const Error&) {
      return false;
    }
    return std::isfinite(res[0]) && std::isfinite(res[1]);
  }
};

// The velocity correction's prior: delta / velocity_sd.
struct VelocityPrior {
  double sd;
  template <typename T>
  bool operator()(const T* delta, T* res) const {
    res[0] = delta[0] / T(sd);
    return true;
  }
};

ceres::CostFunction* table_cost(const TableStageOptions& o, const fitting::TableTrial* t, bool cubic, int n_theta,
                                bool use_peak, bool with_delta) {
  ceres::NumericDiffOptions nd;
  nd.relative_step_size = 1e-4;
  auto* c = new ceres::DynamicNumericDiffCostFunction<TableCost, ceres::CENTRAL>(
      new TableCost{&o, t, cubic, use_peak, with_delta}, ceres::TAKE_OWNERSHIP, nd);
  c->AddParameterBlock(n_theta);
  if (with_delta) c->AddParameterBlock(1);
  c->SetNumResiduals(2);
  return c;
}

void solve(ceres::Problem* problem) {
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = 100;
  so.function_tolerance = 1e-12;
  so.parameter_tolerance = 1e-10;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary sum;
  ceres::Solve(so, problem, &sum);
  if (!sum.IsSolutionUsable()) throw Error("table diagnosis: a fit did not converge to a usable solution");
}

struct TableFit {
  MatParams params;
  std::vector<double> theta;
  double cost = std::numeric_limits<double>::infinity();  // 0.5 sum of squared scaled residuals
};

TableFit fit_on(const std::vector<const fitting::TableTrial*>& train, const TableStageOptions& o, bool cubic,
                const std::vector<std::vector<double>>& starts) {
  TableFit best;
  const bool eiv = o.velocity_sd_m_s > 0.0;
  for (const auto& s : starts) {
    std::vector<double> u = s;
    u.resize(cubic ? 3 : 2, 0.0);
    std::vector<double> delta(train.size(), 0.0);
    ceres::Problem problem;
    for (std::size_t j = 0; j < train.size(); ++j) {
      if (eiv) {
        problem.AddResidualBlock(table_cost(o, train[j], cubic, static_cast<int>(u.size()), true, true), nullptr,
                                 u.data(), &delta[j]);
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<VelocityPrior, 1, 1>(new VelocityPrior{o.velocity_sd_m_s}),
                                 nullptr, &delta[j]);
        problem.SetParameterLowerBound(&delta[j], 0, -3.0 * o.velocity_sd_m_s);
        problem.SetParameterUpperBound(&delta[j], 0, 3.0 * o.velocity_sd_m_s);
      } else {
        problem.AddResidualBlock(table_cost(o, train[j], cubic, static_cast<int>(u.size()), true, false), nullptr,
                                 u.data());
      }
    }
    problem.SetParameterLowerBound(u.data(), 0, std::log(1e3));
    problem.SetParameterUpperBound(u.data(), 0, std::log(1e8));
    problem.SetParameterLowerBound(u.data(), 1, std::log(1.0));
    problem.SetParameterUpperBound(u.data(), 1, std::log(1e5));
    if (cubic) {
      problem.SetParameterLowerBound(u.data(), 2, 0.0);
      problem.SetParameterUpperBound(u.data(), 2, 1e3);
    }
    try {
      solve(&problem);
    } catch (const Error&) {
      continue;
    }
    double cost = 0.0;
    problem.Evaluate(ceres::Problem::EvaluateOptions(), &cost, nullptr, nullptr, nullptr);
    if (cost < best.cost) {
      best.cost = cost;
      best.theta = u;
      best.params = params_of(o, u.data(), cubic);
    }
  }
  if (!std::isfinite(best.cost)) throw Error("table diagnosis: every start of the fit failed");
  return best;
}

// The held-out trial's peak force: at its measured velocity, or, with an
// uncertain velocity, at the velocity (within its prior) that its measured
// deformation asks for.
double predict_peak(const TableFit& fit, const fitting::TableTrial& t, const TableStageOptions& o, bool cubic) {
  double delta = 0.0;
  if (o.velocity_sd_m_s > 0.0 && std::isfinite(t.max_deformation_m)) {
    std::vector<double> u = fit.theta;
    ceres::Problem problem;
    problem.AddResidualBlock(table_cost(o, &t, cubic, static_cast<int>(u.size()), false, true), nullptr, u.data(),
                             &delta);
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<VelocityPrior, 1, 1>(new VelocityPrior{o.velocity_sd_m_s}),
                             nullptr, &delta);
    problem.SetParameterBlockConstant(u.data());
    problem.SetParameterLowerBound(&delta, 0, -3.0 * o.velocity_sd_m_s);
    problem.SetParameterUpperBound(&delta, 0, 3.0 * o.velocity_sd_m_s);
    solve(&problem);
  }
  return simulate_peaks(o, fit.params, t.impact_velocity_m_s + delta).force_n;
}

std::vector<std::vector<double>> starts_for(const std::vector<const fitting::TableTrial*>& train,
                                            const TableStageOptions& o, const MatParams* from) {
  std::vector<std::vector<double>> s;
  if (from) s.push_back({std::log(from->k1_n_m), std::log(std::max(from->r1_n_s_m, 1.0)),
                         from->k1_cubic_n_m3 / kCubicScale});
  // Energy guess: F x / 2 ~ M v^2 / 2 on the slowest training trial.
  const auto* t = *std::min_element(train.begin(), train.end(), [](const auto* a, const auto* b) {
    return a->impact_velocity_m_s < b->impact_velocity_m_s;
  });
  const double x = std::isfinite(t->max_deformation_m) && t->max_deformation_m > 0.0
                       ? t->max_deformation_m
                       : o.impactor_mass_kg * t->impact_velocity_m_s * t->impact_velocity_m_s / t->peak_force_n;
  const double k = t->peak_force_n / x;
  const double rc = 2.0 * std::sqrt(k * o.impactor_mass_kg);
  s.push_back({std::log(k), std::log(0.1 * rc), 0.0});
  s.push_back({std::log(0.7 * k), std::log(0.05 * rc), 0.5 * k / (x * x) / kCubicScale});
  return s;
}

double pct(double sim, double meas) { return 100.0 * (sim - meas) / meas; }

}  // namespace

TableDiagnosis diagnose_table(const std::vector<fitting::TableTrial>& trials, const TableStageOptions& o) {
  if (o.model != fitting::ModelKind::Model1 && o.model != fitting::ModelKind::Model2)
    throw Error("table diagnosis: the baseline must be Model 1 or 2 (two summaries per trial)");
  TableDiagnosis out;
  const auto n = static_cast<Eigen::Index>(trials.size());
  if (n < 3) throw Error(fmt::format("table diagnosis: {} trials; at least 3 are needed to hold one out", n));
  std::vector<const fitting::TableTrial*> all;
  for (const auto& t : trials) {
    if (!(t.impact_velocity_m_s > 0.0) || !(t.peak_force_n > 0.0))
      throw Error(fmt::format("table diagnosis: trial {} needs a positive velocity and peak force", t.id));
    all.push_back(&t);
    out.ids.push_back(t.id);
  }

  // Fits on every trial (information criterion) and leave-one-trial-out
  // predictions (held-out error), without and with stiffening.
  const TableFit lin_all = fit_on(all, o, false, starts_for(all, o, nullptr));
  const TableFit cub_all = fit_on(all, o, true, starts_for(all, o, &lin_all.params));
  out.params_before = lin_all.params;
  out.params_after = lin_all.params;
  out.heldout_pct_before.resize(n);
  out.heldout_pct_after.resize(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    std::vector<const fitting::TableTrial*> train;
    for (Eigen::Index j = 0; j < n; ++j)
      if (j != i) train.push_back(all[static_cast<std::size_t>(j)]);
    // Each fold starts from the fit to every trial (close by construction);
    // the generic starts only when that fails.
    auto fold = [&](bool cubic, const MatParams& from) {
      const std::vector<std::vector<double>> all_starts = starts_for(train, o, &from);
      try {
        return fit_on(train, o, cubic, {all_starts.front()});
      } catch (const Error&) {
        return fit_on(train, o, cubic, all_starts);
      }
    };
    const TableFit lin = fold(false, lin_all.params);
    const TableFit cub = fold(true, cub_all.params);
    const double v = trials[static_cast<std::size_t>(i)].impact_velocity_m_s;
    const double f = trials[static_cast<std::size_t>(i)].peak_force_n;
    const auto& held = trials[static_cast<std::size_t>(i)];
    out.heldout_pct_before(i) = pct(predict_peak(lin, held, o, false), f);
    out.heldout_pct_after(i) = pct(predict_peak(cub, held, o, true), f);
    (void)v;
  }

  // Structure: the held-out errors against velocity.
  Eigen::VectorXd vel(n);
  for (Eigen::Index i = 0; i < n; ++i) vel(i) = trials[static_cast<std::size_t>(i)].impact_velocity_m_s;
  const double r = correlation(out.heldout_pct_before, vel);
  Eigen::Index lo = 0, hi = 0;
  vel.minCoeff(&lo);
  vel.maxCoeff(&hi);
  const bool trend = std::abs(r) >= o.min_trend_r;

  const Eigen::VectorXd before = out.heldout_pct_before.cwiseAbs(), after = out.heldout_pct_after.cwiseAbs();
  const detail::Verdict v = detail::judge(before, after, 0.0, 2.0 * lin_all.cost, 2, 2.0 * cub_all.cost, 3,
                                          2.0 * static_cast<double>(n), 0.0, Criterion::AICc, o.decision);
  auto errors = [&](const Eigen::VectorXd& h) {
    return ErrorSet{{"heldout_peak_force_pct_max", detail::max_abs(h)},
                    {"heldout_peak_force_pct_rms", detail::rms(h)},
                    {fmt::format("heldout_peak_force_pct_{}", trials[static_cast<std::size_t>(lo)].id), h(lo)},
                    {fmt::format("heldout_peak_force_pct_{}", trials[static_cast<std::size_t>(hi)].id), h(hi)}};
  };
  if (trend && v.keep()) {
    Effect e;
    e.stage = "mat";
    e.name = "stiffness_nonlinearity";
    e.evidence = fmt::format(
        "the linear model's held-out peak-force error trends with impact velocity (r = {:.2f}): {:+.1f} % on "
        "{} ({:.2f} m/s), {:+.1f} % on {} ({:.2f} m/s); only stiffening is nonlinear in the loading phase; "
        "k1_cubic = {:.3g} N/m^3, AICc {:.1f}",
        r, out.heldout_pct_before(lo), trials[static_cast<std::size_t>(lo)].id, vel(lo), out.heldout_pct_before(hi),
        trials[static_cast<std::size_t>(hi)].id, vel(hi), cub_all.params.k1_cubic_n_m3, v.ic.delta);
    e.error_before = errors(out.heldout_pct_before);
    e.error_after = errors(out.heldout_pct_after);
    e.estimate = {{"k1_n_m", cub_all.params.k1_n_m},
                  {"r1_n_s_m", cub_all.params.r1_n_s_m},
                  {"k1_cubic_n_m3", cub_all.params.k1_cubic_n_m3}};
    out.effects.push_back(std::move(e));
    out.params_after = cub_all.params;
  } else {
    out.rejected.push_back({"mat", "stiffness_nonlinearity",
                            trend ? v.reason("peak force error (%)", Criterion::AICc)
                                  : fmt::format("held-out peak-force errors do not trend with velocity (r = {:.2f})", r)});
    out.heldout_pct_after = out.heldout_pct_before;
    if (trend)
      out.remaining.push_back({"mat", "velocity_trend",
                               fmt::format("held-out peak-force error trends with impact velocity (r = {:.2f}) and "
                                           "stiffening does not remove it",
                                           r)});
  }
  return out;
}

}  // namespace dropfit::diagnosis
