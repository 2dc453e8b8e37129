// Between trials (diagnosis.h, diagnose_order): does the mat stay the same
// mat from one trial to the next? And the session screen (screen_trials):
// the trials that cannot be measurements of the drops they claim to be.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

#include "core/parallel.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"
#include "trial/trial.h"

namespace dropfit::diagnosis {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The model's peak plate force at the trial's impact with every stiffness
// of `params` times `scale`; NaN when the model cannot be simulated.
double scaled_peak_n(const fitting::FitResult& fit, const fitting::TrialData& d, double scale) {
  const fitting::MatParams p = scaled_stiffness(fit.params, scale);
  fitting::Impact imp;
  imp.mass_kg = d.impactor_mass_kg;
  imp.velocity_m_s = d.impact_velocity_m_s;
  imp.gravity_m_s2 = d.gravity_m_s2;
  imp.output_dt_s = 1e-4;
  imp.duration_s = 0.3;
  try {
    const fitting::Simulation sim = fitting::simulate(fit.model, p, imp);
    return sim.grf_n.size() > 0 ? sim.grf_n.maxCoeff() : kNaN;
  } catch (const std::exception&) {
    return kNaN;
  }
}

// The stiffness scale at which the model matches the trial (`mismatch`
// crosses zero: bisection on the scale's logarithm within the options'
// bracket); NaN when the bracket does not hold it.
double stiffness_scale(const ScaleMismatch& mismatch, const fitting::TrialData& d, const OrderStageOptions& o) {
  if (!(d.impact_velocity_m_s > 0.0)) return kNaN;
  double lo = std::log(o.min_scale), hi = std::log(o.max_scale);
  const double f_lo = mismatch(d, std::exp(lo)), f_hi = mismatch(d, std::exp(hi));
  if (!(f_lo < 0.0 && f_hi > 0.0)) return kNaN;
  for (int it = 0; it < o.bisection_steps; ++it) {
    const double mid = 0.5 * (lo + hi);
    const double f = mismatch(d, std::exp(mid));
    if (!std::isfinite(f)) return kNaN;
    (f < 0.0 ? lo : hi) = mid;
  }
  return std::exp(0.5 * (lo + hi));
}

struct LeastSquares {
  Eigen::VectorXd beta, se;
  double rss = 0.0;
  int dof = 0;
};

// Ordinary least squares; the residual SD is floored at sd_floor.
LeastSquares ols(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, double sd_floor) {
  LeastSquares out;
  out.beta = x.colPivHouseholderQr().solve(y);
  out.rss = (y - x * out.beta).squaredNorm();
  out.dof = static_cast<int>(x.rows() - x.cols());
  const double s2 = std::max(out.dof > 0 ? out.rss / out.dof : 0.0, sd_floor * sd_floor);
  const Eigen::MatrixXd cov = s2 * (x.transpose() * x).inverse();
  out.se = cov.diagonal().cwiseSqrt();
  return out;
}

}  // namespace

fitting::MatParams scaled_stiffness(fitting::MatParams p, double scale) {
  p.k1_n_m *= scale, p.k2_n_m *= scale, p.k3_n_m *= scale, p.k1_cubic_n_m3 *= scale, p.maxwell_k_n_m *= scale;
  return p;
}

// See diagnosis.h.
OrderDiagnosis diagnose_order(const std::vector<fitting::TrialData>& trials, const fitting::FitResult& fit,
                              const OrderStageOptions& o) {
  // The peak grows with the stiffness.
  const ScaleMismatch peak = [&](const fitting::TrialData& d, double scale) {
    return d.grf_n.size() > 0 ? scaled_peak_n(fit, d, scale) - d.grf_n.maxCoeff()
                              : std::numeric_limits<double>::quiet_NaN();
  };
  return diagnose_order(trials, peak, o);
}

OrderDiagnosis diagnose_order(const std::vector<fitting::TrialData>& trials, const ScaleMismatch& mismatch,
                              const OrderStageOptions& o) {
  OrderDiagnosis out;
  // Each trial's scale (the simulations of one trial after another: on two
  // threads, a trial each).
  std::vector<double> scale(trials.size(), std::numeric_limits<double>::quiet_NaN());
  parallel_for(trials.size(), 2, [&](std::size_t k) {
    if (trials[k].accepted) scale[k] = stiffness_scale(mismatch, trials[k], o);
  });
  std::vector<double> order, speed, log_scale;
  for (std::size_t k = 0; k < trials.size(); ++k) {
    const fitting::TrialData& d = trials[k];
    if (!d.accepted) continue;
    const double s = scale[k];
    out.ids.push_back(d.id);
    out.stiffness_scale.push_back(s);
    if (!std::isfinite(s)) continue;
    order.push_back(static_cast<double>(k));
    speed.push_back(d.impact_velocity_m_s);
    log_scale.push_back(std::log(s));
  }
  const auto n = static_cast<Eigen::Index>(log_scale.size());
  if (n < 4) {
    out.notes.push_back(fmt::format("between trials: {} trial(s) with a stiffness scale; a change of the mat with "
                                    "recording order needs 4",
                                    n));
    return out;
  }
  const Eigen::VectorXd k = detail::to_vector(order), v = detail::to_vector(speed), y = detail::to_vector(log_scale);
  const double r_kv = correlation(k, v);
  if (std::abs(r_kv) > o.max_order_speed_correlation) {
    out.notes.push_back(fmt::format(
        "between trials: recording order follows impact speed (r = {:.2f}), so a change of the mat between trials "
        "cannot be told from a speed effect; not judged",
        r_kv));
    return out;
  }
  // log s = a + c (v - mean v) [+ b (k - mean k)]: the model's misfit with
  // speed takes c; what is left that follows recording order is the mat's.
  Eigen::MatrixXd x_speed(n, 2), x_both(n, 3);
  x_speed.col(0).setOnes();
  x_speed.col(1) = v.array() - v.mean();
  x_both.leftCols(2) = x_speed;
  x_both.col(2) = k.array() - k.mean();
  const LeastSquares without = ols(x_speed, y, o.scale_sd_floor);
  const LeastSquares with = ols(x_both, y, o.scale_sd_floor);
  // Each trial's scale as the trend fitted without it predicts (its own
  // peak not used); the in-sample trend when too few trials are left.
  out.trend_scale.assign(out.ids.size(), std::numeric_limits<double>::quiet_NaN());
  for (Eigen::Index i = 0, row = 0; i < static_cast<Eigen::Index>(out.ids.size()); ++i) {
    if (!std::isfinite(out.stiffness_scale[static_cast<std::size_t>(i)])) continue;
    Eigen::VectorXd beta = with.beta;
    if (n - 1 > x_both.cols()) {
      Eigen::MatrixXd xo(n - 1, x_both.cols());
      Eigen::VectorXd yo(n - 1);
      for (Eigen::Index r = 0, m = 0; r < n; ++r)
        if (r != row) xo.row(m) = x_both.row(r), yo(m) = y(r), ++m;
      beta = xo.colPivHouseholderQr().solve(yo);
    }
    out.trend_scale[static_cast<std::size_t>(i)] = std::exp(x_both.row(row).dot(beta));
    ++row;
  }
  const double rate = std::expm1(with.beta(2));  // relative stiffness change per trial
  const double rate_se = with.se(2);
  out.rate_per_trial = rate;
  out.rate_se = rate_se;
  const double t = with.beta(2) / rate_se;
  const double t_crit = trial::student_t_quantile(1.0 - 0.5 * o.alpha, std::max(1, with.dof));
  std::string scales;
  for (std::size_t i = 0; i < out.ids.size(); ++i)
    scales += fmt::format("{}{} {:.3f}", i ? ", " : "", out.ids[i], out.stiffness_scale[i]);
  const Eigen::VectorXd before = 100.0 * (y - x_speed * without.beta).array().abs();
  const Eigen::VectorXd after = 100.0 * (y - x_both * with.beta).array().abs();
  if (std::abs(t) >= t_crit && std::abs(rate) >= o.min_rate_per_trial) {
    Effect e;
    e.stage = "mat";
    e.name = "mat_change_between_trials";
    e.evidence = fmt::format(
        "the mat's stiffness changes with recording order, not with speed: {:+.1f} % +- {:.1f} % per trial "
        "(t = {:.1f}, {} trials, order and speed correlated r = {:.2f}); each trial's stiffness scale against one "
        "model of the mat: {} ({}). One set of mat parameters does not describe every trial",
        100.0 * rate, 100.0 * rate_se, t, n, r_kv, scales, rate < 0.0 ? "softening, as a foam under repeated impacts" : "stiffening or recovering");
    e.error_before = {{"stiffness_scale_pct_rms", detail::rms(before)}, {"stiffness_scale_pct_max", detail::max_abs(before)}};
    e.error_after = {{"stiffness_scale_pct_rms", detail::rms(after)}, {"stiffness_scale_pct_max", detail::max_abs(after)}};
    e.estimate = {{"rate_per_trial", rate}, {"rate_per_trial_se", rate_se}};
    for (std::size_t i = 0; i < out.ids.size(); ++i)
      e.estimate.push_back({"stiffness_scale_" + out.ids[i], out.stiffness_scale[i]});
    out.effects.push_back(std::move(e));
    out.changed = true;
  } else {
    out.rejected.push_back({"mat", "mat_change_between_trials",
                            fmt::format("stiffness scale against recording order {:+.2f} % +- {:.2f} % per trial "
                                        "(t = {:.1f}, needs {:.1f} and {:.1f} %): the same mat in every trial ({})",
                                        100.0 * rate, 100.0 * rate_se, t, t_crit, 100.0 * o.min_rate_per_trial,
                                        scales)});
  }
  return out;
}

}  // namespace dropfit::diagnosis
