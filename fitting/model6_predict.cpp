// Model 6's prediction intervals (fitting/model6_fit.h,
// add_model6_prediction_intervals).
//
// A predicted quantity q (peak force, time to peak, largest face travel,
// the force at each sample) of a trial errs by
//   q_hat - q = g_u' (u_hat - u) + g_v e_v + d,
// the fitted coordinates' error (covariance from the fit, g_u by central
// differences through simulate_model6), the trial's impact velocity error
// e_v (its measured SE; a training trial's is absorbed by the fit, whose
// parameters reproduce the measured force at the measured velocity) and
// the model's discrepancy d: a foam law of the wrong shape, which the
// parameters' covariance (from the noise, scaled by the training residual)
// does not hold. d's SD is the training trials' own misfit around the
// quantity's peak (simulated less measured, above the noise: the one place
// the data show how far the column's shape is from the mat's) times the
// trial's growth: how far it drives either foam beyond the training
// trials' reach in the densification coordinate r = e / (e_d - e), to the
// power n of the densification term (1 within their reach; the law beyond
// it is the fit's extrapolation, and its error grows as the stress taken
// from there).
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "core/error.h"
#include "core/parallel.h"
#include "fitting/detail/summary.h"
#include "fitting/model6_calibration.h"
#include "fitting/model6_fit.h"

namespace dropfit::fitting {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

constexpr int kExponent = 14;  // log(n - 1), the last coordinate

double densification_coordinate(double strain, const FoamLaw& law) {
  return strain / std::max(law.densification_strain - strain, 1e-3);
}

// The simulation of one trial on the fit's grid (the trial's sample step
// over options.oversample, so the integrator takes the fit's steps).
struct TrialGrid {
  Impact impact;
  double h = 0.0;
};

TrialGrid grid_of(const TrialData& td, const TrialReport& rep, const Model6FitOptions& o) {
  const Eigen::Index n = td.t_s.size();
  if (n < 3) throw Error(fmt::format("trial {}: too few samples for a prediction", td.id));
  TrialGrid g;
  g.h = (td.t_s[n - 1] - td.t_s[0]) / static_cast<double>(n - 1) / std::max(1, o.oversample);
  g.impact.mass_kg = td.impactor_mass_kg;
  g.impact.gravity_m_s2 = td.gravity_m_s2;
  g.impact.velocity_m_s = td.impact_velocity_m_s;
  g.impact.first_output_s = 0.0;
  g.impact.output_dt_s = g.h;
  g.impact.duration_s = std::max(rep.window_end_s, 0.02) + 0.005;
  return g;
}

// The parameter and velocity part: each quantity's gradient in the free
// coordinates and the velocity, and its variance.
struct Propagated {
  internal::Summary value;
  Eigen::VectorXd force;                // on the trial's samples
  // peak, time to peak, travel: the parameters' and the velocity's part (the
  // time to peak's also the common timing discrepancy, where discrepancy is on)
  Eigen::Vector3d var = Eigen::Vector3d::Zero();
  Eigen::VectorXd force_var;
  // The peak's time scale sqrt(F / |F''|): a relative misfit e of the force
  // around the peak moves its time by about e times this.
  double peak_width_s = 0.0;
};

Propagated propagate(const TrialData& td, const TrialReport& rep, const Model6FitResult& res,
                     const Model6FitOptions& o) {
  const TrialGrid grid = grid_of(td, rep, o);
  std::vector<int> free;
  for (int j = 0; j < res.coordinates.size(); ++j)
    if (j != kExponent || res.free_exponent) free.push_back(j);
  const int np = static_cast<int>(free.size());
  auto run = [&](const Eigen::VectorXd& u, double v) {
    Impact imp = grid.impact;
    imp.velocity_m_s = v;
    return simulate_model6(model6_params_at(u, o, res.free_exponent), o.geometry, imp);
  };
  const double v0 = td.impact_velocity_m_s, shift = rep.contact_shift_s;
  const Simulation s0 = run(res.coordinates, v0);
  auto try_run = [&](const Eigen::VectorXd& u, double v) -> std::optional<Simulation> {
    try {
      return run(u, v);
    } catch (const Error&) {
      return std::nullopt;
    }
  };
  Propagated out;
  out.value = internal::summarise(s0);
  out.force = internal::force_on_samples(s0, td.t_s, shift, grid.h);
  Eigen::Index ip = 0;
  s0.grf_n.maxCoeff(&ip);
  if (ip > 0 && ip + 1 < s0.grf_n.size()) {
    const double curv = (s0.grf_n[ip - 1] - 2.0 * s0.grf_n[ip] + s0.grf_n[ip + 1]) / (grid.h * grid.h);
    if (curv < 0.0) out.peak_width_s = std::sqrt(s0.grf_n[ip] / -curv);
  }
  const Eigen::Index n = td.t_s.size();
  Eigen::MatrixXd g(3, np + 1), gf(n, np + 1);
  for (int j = 0; j <= np; ++j) {
    Eigen::VectorXd up = res.coordinates, um = up;
    double vp = v0, vm = v0, step;
    if (j < np) {
      step = 1e-3;  // in the logarithm: 0.1 % of the parameter
      up[free[j]] += step, um[free[j]] -= step;
    } else {
      step = 1e-3 * std::max(v0, 0.1);
      vp += step, vm -= step;
    }
    // A central difference, or a one-sided one where a side leaves the
    // law's domain (a coordinate at its bound: the densification strain at
    // 1, where the column is not defined beyond).
    std::optional<Simulation> sp = try_run(up, vp), sm = try_run(um, vm);
    double width = 2.0 * step;
    if (!sp && !sm) throw Error(fmt::format("trial {}: the column's simulation fails on both sides of {}", td.id,
                                            j < np ? fmt::format("coordinate {}", free[j]) : "the impact velocity"));
    if (!sp) sp = s0, width = step;
    if (!sm) sm = s0, width = step;
    const internal::Summary qp = internal::summarise(*sp), qm = internal::summarise(*sm);
    g.col(j) << (qp.peak_n - qm.peak_n) / width, (qp.t_peak_s - qm.t_peak_s) / width,
        (qp.max_travel_m - qm.max_travel_m) / width;
    gf.col(j) = (internal::force_on_samples(*sp, td.t_s, shift, grid.h) -
                 internal::force_on_samples(*sm, td.t_s, shift, grid.h)) /
                width;
  }
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(np + 1, np + 1);
  for (int a = 0; a < np; ++a)
    for (int b = 0; b < np; ++b) cov(a, b) = res.coordinate_covariance(free[a], free[b]);
  const double sv = std::isfinite(td.impact_velocity_se_m_s) ? td.impact_velocity_se_m_s : 0.0;
  const double scale = std::isfinite(td.calibration_scale_sd) ? td.calibration_scale_sd * v0 : 0.0;
  if (!rep.train) cov(np, np) = sv * sv + scale * scale;
  for (int k = 0; k < 3; ++k) out.var[k] = std::max(g.row(k).dot(cov * g.row(k).transpose()), 0.0);
  out.force_var = (gf * cov).cwiseProduct(gf).rowwise().sum().cwiseMax(0.0);
  return out;
}

// A channel's misfit around its peak: the RMS of simulated less measured
// over the contact's samples where the measured value is above half its
// largest, less the noise in quadrature (the structure a single value
// there carries; the whole window's RMS is diluted by the flat start and
// tail, which any column fits).
double excess_near_peak(const Eigen::VectorXd& t_s, const Eigen::VectorXd& measured, const Eigen::VectorXd& simulated,
                        double end_s, double noise) {
  if (measured.size() != t_s.size() || simulated.size() != t_s.size()) return 0.0;
  double top = -1e300;
  for (Eigen::Index i = 0; i < t_s.size(); ++i)
    if (t_s[i] >= 0.0 && t_s[i] <= end_s && std::isfinite(measured[i])) top = std::max(top, measured[i]);
  double ss = 0.0;
  int n = 0;
  for (Eigen::Index i = 0; i < t_s.size(); ++i)
    if (t_s[i] >= 0.0 && t_s[i] <= end_s && std::isfinite(measured[i]) && measured[i] > 0.5 * top) {
      const double d = simulated[i] - measured[i];
      ss += d * d, ++n;
    }
  return n > 0 ? std::sqrt(std::max(ss / n - noise * noise, 0.0)) : 0.0;
}

// The training trials' misfit (RMS over them) in the peak force (a share
// of the measured peak: the misfit around the force's peak in quadrature
// with the peak's own difference) and the largest travel (the misfit
// around the travel's peak: the measured largest travel is the top of a
// channel as noisy as a marker, biased by that noise). The time to peak's
// is the peak's share times the peak's width where it is used (the
// measured time to peak is read on the plate's samples, too coarse to show
// the column's misfit).
Model6Discrepancy training_misfit(const std::vector<TrialData>& trials, const Model6FitOptions& o,
                                  const Model6FitResult& res) {
  Model6Discrepancy d;
  int n = 0;
  for (const TrialReport& r : res.trials) {
    if (!r.train) continue;
    const auto td = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == r.id; });
    if (td == trials.end()) continue;
    const double fn = std::isfinite(td->force_noise_n) ? td->force_noise_n : o.force_noise_n;
    const double xn = std::isfinite(td->marker_noise_m) ? td->marker_noise_m : o.marker_noise_m;
    const Simulation& s = r.simulation;
    const double f_excess = excess_near_peak(td->t_s, td->grf_n, s.grf_n, r.window_end_s, fn);
    const double x_excess = excess_near_peak(td->t_s, td->impactor_m, s.impactor_m, r.window_end_s, xn);
    const double peak = r.measured.peak_force_n;
    const double dp = std::isfinite(r.comparison.peak_force_pct_diff) ? 0.01 * r.comparison.peak_force_pct_diff : 0.0;
    d.peak_force_n += dp * dp + (f_excess / peak) * (f_excess / peak);
    d.max_deformation_m += x_excess * x_excess;
    ++n;
  }
  if (n == 0) return d;
  d.peak_force_n = std::sqrt(d.peak_force_n / n);  // a share of the peak here
  d.max_deformation_m = std::sqrt(d.max_deformation_m / n);
  return d;
}

// How far a trial drives either foam beyond the training trials' reach in
// r = e / (e_d - e): the larger ratio of the two foams, at least 1, to the
// power of the densification exponent n (the densification stress goes as
// r^n, and with it what a law of the wrong shape there gets wrong).
double reach_growth(const Model6Reach& r, const Model6FitResult& res) {
  double top = 0.0, base = 0.0;
  for (const Model6Reach& t : res.reach)
    if (t.train) top = std::max(top, t.max_top_strain), base = std::max(base, t.max_base_strain);
  const double rt = densification_coordinate(top, res.params.top);
  const double rb = densification_coordinate(base, res.params.base);
  double g = 1.0;
  if (rt > 0.0) g = std::max(g, densification_coordinate(r.max_top_strain, res.params.top) / rt);
  if (rb > 0.0) g = std::max(g, densification_coordinate(r.max_base_strain, res.params.base) / rb);
  return std::pow(g, res.params.top.densification_exponent);
}

// A 95 % interval of a value with the stated variance, on Student's t
// with `dof` degrees of freedom (the normal's quantile for an infinite dof).
PredictionInterval interval(double value, double variance, double dof) {
  PredictionInterval pi;
  pi.value = value;
  pi.se = std::sqrt(variance);
  const double q = t_quantile_95(dof);
  pi.low = value - q * pi.se;
  pi.high = value + q * pi.se;
  return pi;
}

// One trial's propagated part and its (uncalibrated) discrepancy.
struct TrialPart {
  const TrialData* data = nullptr;
  Propagated p;
  Model6Discrepancy d;
  bool ok = false;
};

// The largest measured face travel over the trial's contact window.
double measured_travel(const TrialData& td, double end_s) {
  double top = kNaN;
  for (Eigen::Index i = 0; i < td.t_s.size() && i < td.impactor_m.size(); ++i)
    if (td.t_s[i] >= 0.0 && td.t_s[i] <= end_s && std::isfinite(td.impactor_m[i]))
      top = std::isfinite(top) ? std::max(top, td.impactor_m[i]) : td.impactor_m[i];
  return top;
}

// A held-out trial's three checks (peak force, time to peak, largest
// travel): measured less predicted, the stated variance's parts and the
// measured value's own noise: the force's noise for the peak; the marker's
// and the travel reference's for the travel; for the time to peak, read on
// the plate's samples from the fitted contact, the sample step's
// quantisation (dt^2 / 12), the peak's jitter in the noise (sigma_F / F
// times the peak's width squared) and the contact's SE.
std::array<HeldOutCheck, 3> checks_of(const TrialPart& t, const TrialReport& rep, const Model6FitOptions& o) {
  const TrialData& td = *t.data;
  const double fn = std::isfinite(td.force_noise_n) ? td.force_noise_n : o.force_noise_n;
  const double xn = std::isfinite(td.marker_noise_m) ? td.marker_noise_m : o.marker_noise_m;
  const double ref = std::isfinite(td.travel_reference_se_m) ? td.travel_reference_se_m : 0.0;
  const Eigen::Index n = td.t_s.size();
  const double dt = (td.t_s[n - 1] - td.t_s[0]) / static_cast<double>(n - 1);
  const double shift_se = std::isfinite(rep.contact_shift_se_s) ? rep.contact_shift_se_s : 0.0;
  const double jitter = t.p.value.peak_n > 0.0 ? fn / t.p.value.peak_n * t.p.peak_width_s * t.p.peak_width_s : 0.0;
  std::array<HeldOutCheck, 3> c;
  c[0] = {rep.measured.peak_force_n - t.p.value.peak_n, t.p.var[0], t.d.peak_force_n * t.d.peak_force_n, fn * fn};
  c[1] = {rep.measured.time_to_peak_s - t.p.value.t_peak_s, t.p.var[1], t.d.time_to_peak_s * t.d.time_to_peak_s,
          dt * dt / 12.0 + jitter + shift_se * shift_se};
  c[2] = {measured_travel(td, rep.window_end_s) - t.p.value.max_travel_m, t.p.var[2],
          t.d.max_deformation_m * t.d.max_deformation_m, xn * xn + ref * ref};
  return c;
}

// How far an impact is from the nearest training impact in energy (one
// impactor mass): |1 - v^2 / v_train^2|; 1 where either is unknown.
double energy_distance(double v, const std::vector<double>& train_v2) {
  double out = kNaN;
  for (double t : train_v2)
    if (t > 0.0 && std::isfinite(t) && std::isfinite(v)) {
      const double d = std::abs(1.0 - v * v / t);
      out = std::isfinite(out) ? std::min(out, d) : d;
    }
  return std::isfinite(out) ? out : 1.0;
}

// Widens each held-out trial's discrepancy by what the other held-out
// trials' checks show, in proportion to its squared energy distance from
// the training impact (fitting/model6_calibration.h); training trials keep
// the training misfit (their own, which their discrepancy already is).
// A discrepancy variance read from n other trials is itself uncertain
// (n degrees of freedom): the interval takes Student's t at the
// Welch-Satterthwaite degrees of freedom of the parameters' variance
// (known) plus that estimate.
void cross_validate(std::vector<TrialPart>& parts, const Model6FitResult& res, const Model6FitOptions& o) {
  std::vector<double> train_v2;
  for (std::size_t q = 0; q < parts.size(); ++q)
    if (parts[q].data && res.trials[q].train) train_v2.push_back(std::pow(parts[q].data->impact_velocity_m_s, 2));
  std::vector<std::size_t> held;
  std::array<std::vector<HeldOutCheck>, 3> checks;
  for (std::size_t q = 0; q < parts.size(); ++q) {
    if (!parts[q].ok || res.trials[q].train) continue;
    std::array<HeldOutCheck, 3> c = checks_of(parts[q], res.trials[q], o);
    const double d = energy_distance(parts[q].data->impact_velocity_m_s, train_v2);
    held.push_back(q);
    for (int k = 0; k < 3; ++k) {
      c[k].distance = d;
      checks[k].push_back(c[k]);
    }
  }
  std::array<std::vector<double>, 3> var;
  std::array<std::vector<int>, 3> dof;
  for (int k = 0; k < 3; ++k) {
    var[k] = cross_validated_discrepancy_var(checks[k]);
    dof[k] = cross_validated_dof(checks[k]);
  }
  // The time to peak's discrepancy is the peak's relative shape error times
  // the peak's width: where the peak's checks scale that shape error, the
  // time taken from the same shape grows alike. Its own checks seldom can:
  // the measured time to peak carries the plate's sampling (dt^2 / 12) and
  // the broad top's jitter, a few tenths of a millisecond, and the column's
  // timing error hides below that.
  for (std::size_t h = 0; h < held.size(); ++h) {
    const double own = checks[0][h].discrepancy_var;
    if (!(own > 0.0)) continue;
    const double from_peak = checks[1][h].discrepancy_var * var[0][h] / own;
    if (from_peak > var[1][h]) var[1][h] = from_peak, dof[1][h] = dof[0][h];
  }
  for (std::size_t h = 0; h < held.size(); ++h) {
    Model6Discrepancy& d = parts[held[h]].d;
    double* sd[3] = {&d.peak_force_n, &d.time_to_peak_s, &d.max_deformation_m};
    double* scale[3] = {&d.peak_force_scale, &d.time_to_peak_scale, &d.max_deformation_scale};
    double* dofs[3] = {&d.peak_force_dof, &d.time_to_peak_dof, &d.max_deformation_dof};
    for (int k = 0; k < 3; ++k) {
      const double before = checks[k][h].parameter_var + checks[k][h].discrepancy_var;
      *sd[k] = std::sqrt(var[k][h]);
      *dofs[k] = welch_dof(checks[k][h].parameter_var, var[k][h], dof[k][h]);
      *scale[k] = before > 0.0 ? std::sqrt((checks[k][h].parameter_var + var[k][h]) / before) : 1.0;
    }
  }
}

// The common timing discrepancy (Model6FitResult::timing_discrepancy_s):
// the shift that best aligns a fitted series f with the measured one moves,
// for a misfit m, by <m, f'> / <f', f'>, at most |m| / |f'|. Per training
// trial, on the samples of the contact window: for the force, that bound
// with the misfit above the plate's noise (how far the misfit can move the
// contact the force places); for the face travel, the shift itself (how
// far the column's contact stands from the one the video shows: a travel
// 2 mm behind at 6 m/s is 0.33 ms). The two in quadrature, RMS over the
// training trials.

// The shift <m, f'> / <f', f'> (`bound`: |m| / |f'|, the misfit above
// `noise`) on the contact window; NaN where nothing is measured.
double channel_timing(const TrialData& td, const Eigen::VectorXd& fitted, const Eigen::VectorXd& measured,
                      double noise, double window_end_s, bool bound) {
  double ss = 0.0, rate = 0.0, along = 0.0;
  int m = 0;
  for (Eigen::Index i = 1; i + 1 < fitted.size(); ++i) {
    if (td.t_s[i] < 0.0 || td.t_s[i] > window_end_s || !std::isfinite(measured[i])) continue;
    const double d = fitted[i] - measured[i], df = (fitted[i + 1] - fitted[i - 1]) / (td.t_s[i + 1] - td.t_s[i - 1]);
    if (!std::isfinite(d) || !std::isfinite(df)) continue;
    ss += d * d, rate += df * df, along += d * df, ++m;
  }
  if (m == 0 || !(rate > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  if (!bound) return std::abs(along) / rate;
  return std::sqrt(std::max(ss / m - noise * noise, 0.0) / (rate / m));
}

double timing_discrepancy(const std::vector<TrialData>& trials, const Model6FitOptions& o, const Model6FitResult& res) {
  double sum = 0.0;
  int n = 0;
  for (const TrialReport& r : res.trials) {
    const auto td = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == r.id; });
    if (!r.train || td == trials.end() || r.simulation.grf_n.size() != td->t_s.size()) continue;
    const double fn = std::isfinite(td->force_noise_n) ? td->force_noise_n : o.force_noise_n;
    // A trial without force samples in its window says nothing of timing.
    const double dt_force = channel_timing(*td, r.simulation.grf_n, td->grf_n, fn, r.window_end_s, true);
    if (!std::isfinite(dt_force)) continue;
    double dt_travel = 0.0;
    if (r.simulation.impactor_m.size() == td->t_s.size() && td->impactor_m.size() == td->t_s.size())
      dt_travel = channel_timing(*td, r.simulation.impactor_m, td->impactor_m, 0.0, r.window_end_s, false);
    if (!std::isfinite(dt_travel)) dt_travel = 0.0;
    sum += dt_force * dt_force + dt_travel * dt_travel, ++n;
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

// The interval of one trial from its propagated part and discrepancy.
void set_intervals(const TrialPart& t, Prediction& out) {
  const Propagated& p = t.p;
  const Model6Discrepancy& d = t.d;
  out.peak_force_n = interval(p.value.peak_n, p.var[0] + d.peak_force_n * d.peak_force_n, d.peak_force_dof);
  out.time_to_peak_s = interval(p.value.t_peak_s, p.var[1] + d.time_to_peak_s * d.time_to_peak_s, d.time_to_peak_dof);
  out.max_deformation_m =
      interval(p.value.max_travel_m, p.var[2] + d.max_deformation_m * d.max_deformation_m, d.max_deformation_dof);
  // The band: each sample's share of the peak's discrepancy in proportion
  // to its force, on the peak's degrees of freedom.
  const double rel = p.value.peak_n > 0.0 ? d.peak_force_n / p.value.peak_n : 0.0;
  const Eigen::ArrayXd sd = (p.force_var.array() + (rel * p.force.array()).square()).sqrt();
  const double q = t_quantile_95(d.peak_force_dof);
  out.force_low_n = p.force.array() - q * sd;
  out.force_high_n = p.force.array() + q * sd;
}

}  // namespace

void add_model6_prediction_intervals(const std::vector<TrialData>& trials, const Model6FitOptions& options,
                                     Model6FitResult& res) {
  res.discrepancy.clear();
  res.timing_discrepancy_s = timing_discrepancy(trials, options, res);
  if (res.coordinates.size() != 15 || res.coordinate_covariance.rows() != 15) return;
  const Model6Discrepancy misfit = training_misfit(trials, options, res);
  std::vector<TrialPart> parts(res.trials.size());
  parallel_for(res.trials.size(), 2, [&](std::size_t q) {
    const TrialReport& rep = res.trials[q];
    const auto td = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == rep.id; });
    if (td == trials.end()) return;
    TrialPart& part = parts[q];
    try {
      part.data = &*td;
      part.p = propagate(*td, rep, res, options);
      Model6Discrepancy& d = part.d;
      d.id = rep.id;
      if (options.model_discrepancy) {
        // The column's common timing error (the shift that would align its
        // force with the training trials' measured one) moves its peak as it
        // moves its contact: a known part of the time to peak's variance,
        // beside the parameters', shared by every trial (docs/validation.md).
        part.p.var[1] += res.timing_discrepancy_s * res.timing_discrepancy_s;
        const auto r = std::find_if(res.reach.begin(), res.reach.end(), [&](const Model6Reach& x) { return x.id == rep.id; });
        d.growth = r == res.reach.end() ? 1.0 : reach_growth(*r, res);
        d.peak_force_n = misfit.peak_force_n * part.p.value.peak_n * d.growth;
        d.time_to_peak_s = misfit.peak_force_n * part.p.peak_width_s * d.growth;
        d.max_deformation_m = misfit.max_deformation_m * d.growth;
      }
      part.ok = true;
    } catch (const Error&) {
      part.ok = false;
    }
  });
  if (options.model_discrepancy && options.cross_validate_discrepancy) cross_validate(parts, res, options);
  for (std::size_t q = 0; q < res.trials.size(); ++q) {
    if (parts[q].data && !parts[q].ok) {
      res.warnings.push_back(fmt::format("trial {}: no prediction intervals (the column's simulation failed)",
                                         res.trials[q].id));
      continue;
    }
    if (!parts[q].ok) continue;
    set_intervals(parts[q], res.trials[q].prediction);
    if (options.model_discrepancy) res.discrepancy.push_back(parts[q].d);
  }
}

}  // namespace dropfit::fitting
