// The fitter's uncertainty (see detail/uncertainty.h, error_budget.h and fit.h).
#include "fitting/detail/uncertainty.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>

#include "core/parallel.h"
#include "fitting/detail/summary.h"
#include "fitting/model5_impl.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting::internal {

void covariance(const Optimum& opt, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                const ErrorBudget& budget, std::vector<ParameterEstimate>* est, std::vector<double>* shift_se,
                std::vector<std::string>* warnings) {
  const int np = space.size();
  const Eigen::MatrixXd& J = opt.jacobian;
  const int n = static_cast<int>(J.cols());
  if (J.rows() <= n || n < np || budget.covariance.rows() != n) {
    warnings->push_back("covariance not available (too few residuals)");
    return;
  }
  const Eigen::MatrixXd& cov = budget.covariance;
  const Eigen::VectorXd& ev = budget.eigenvalues;
  const double evmax = ev.maxCoeff();
  auto label = [&](int j) { return j < np ? param_display(space.free[j]) : fmt::format("clock shift {}", j - np + 1); };
  for (int i = 0; i < n; ++i) {
    const double lam = ev[i];
    if (lam < 1e-8 * evmax) {
      const Eigen::VectorXd v = budget.eigenvectors.col(i);
      std::string dir;
      for (int j = 0; j < n; ++j)
        if (std::abs(v[j]) > 0.3) dir += fmt::format("{}{:+.2f} {}", dir.empty() ? "" : " ", v[j], label(j));
      warnings->push_back(fmt::format("near-singular direction (eigenvalue ratio {:.1e}): {}", lam / evmax, dir));
    }
  }
  shift_se->clear();
  for (int j = np; j < n; ++j)
    shift_se->push_back(budget.lost[j] ? std::numeric_limits<double>::infinity() : std::sqrt(std::max(cov(j, j), 0.0)));
  for (int j = 0; j < np; ++j) {
    const FreeParam& f = space.free[j];
    ParameterEstimate& e = (*est)[j];
    double se_u = std::sqrt(std::max(cov(j, j), 0.0));
    const double white_u = std::sqrt(std::max(budget.white_covariance(j, j), 0.0));
    // A direction dropped from the inverse: the parameter is unconstrained.
    if (budget.lost[j]) se_u = std::numeric_limits<double>::infinity();
    if (f.transform == Transform::Log) {
      e.se = e.value * se_u;
      e.rel_se = se_u;
      e.se_white = e.value * white_u;
      e.ci_low = e.value * std::exp(-kZ95 * se_u);
      e.ci_high = e.value * std::exp(kZ95 * se_u);
    } else if (f.transform == Transform::Fraction) {
      e.se = space.total_mass * se_u;
      e.rel_se = e.se / std::max(mp.m1_kg, 1e-12);
      e.se_white = space.total_mass * white_u;
      e.ci_low = std::max(e.value - kZ95 * e.se, 0.0);
      e.ci_high = std::min(e.value + kZ95 * e.se, space.total_mass);
    } else {
      e.se = f.scale * se_u;
      e.rel_se = e.se / std::max(std::abs(e.value), 1e-300);
      e.se_white = f.scale * white_u;
      e.ci_low = e.value - kZ95 * e.se;
      e.ci_high = e.value + kZ95 * e.se;
    }
    e.interval = "wald";
    if (!(e.rel_se <= o.identifiability_rel_se)) {
      e.identifiable = false;
      e.note = fmt::format("weakly determined: relative SE {:.2g}", e.rel_se);
      warnings->push_back(fmt::format("{} is not pinned down by the data (relative SE {:.2g})", e.name, e.rel_se));
    }
    // Within a thousandth of the span a parameter is searched over (not of
    // its box: k1_cubic's box reaches 1e10 N/m^3, so a tenth of a percent of
    // it is 1e7, above the stiffening mats have).
    const double span = f.start_hi > f.start_lo ? std::min(f.upper - f.lower, f.start_hi - f.start_lo)
                                                : f.upper - f.lower;
    const double margin = 1e-3 * span;
    if (opt.u[j] <= f.lower + margin || opt.u[j] >= f.upper - margin) {
      // The data push it out of the physically sensible box: the box, not
      // the data, sets its value.
      if (e.identifiable)
        warnings->push_back(fmt::format("{} is not pinned down by the data: it sits at its bound ({:.6g})",
                                        e.name, e.value));
      else
        warnings->push_back(fmt::format("{} sits at its bound ({:.6g})", e.name, e.value));
      e.identifiable = false;
      e.at_bound = true;
      e.note = fmt::format("at the bound of its search range ({:.6g}): the bound, not the data, sets it", e.value);
    }
    if (!e.identifiable) {
      e.ci_low = e.ci_high = kNaN;
      e.interval.clear();
    }
  }
  for (int a = 0; a < np; ++a)
    for (int b = a + 1; b < np; ++b) {
      const double c = cov(a, b) / std::sqrt(std::max(cov(a, a) * cov(b, b), 1e-300));
      if (std::abs(c) > 0.995)
        warnings->push_back(fmt::format("{} and {} are correlated (r = {:.3f})", param_display(space.free[a]),
                                        param_display(space.free[b]), c));
    }
}

// Per training trial with a measured budget: the impact velocity's
// correction (v_true - v_measured), the video contact instant's error and
// the travel reference's error; one for the session: the calibration's
// vertical scale error, which moves every trial's measured velocity and
// travel in proportion.
Nuisances nuisance_columns(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                           const MatParams& mp, const std::vector<double>& shifts, Eigen::Index n_res) {
  Nuisances nz;
  std::vector<Eigen::VectorXd> cols;
  std::vector<std::array<double, 3>> prior;  // per column: variance, partner column, covariance
  Eigen::VectorXd scale_col = Eigen::VectorXd::Zero(n_res);
  double scale_sd = 0.0;
  nz.velocity.assign(preps.size(), -1);
  Eigen::Index off = 0;
  for (size_t q = 0; q < preps.size(); ++q) {
    const Prepared& p = preps[q];
    const TrialData& td = *p.data;
    const int nf = static_cast<int>(p.f_idx.size()), nk = static_cast<int>(p.k_idx.size());
    const double shift = p.shifted() ? shifts[q] : 0.0;
    const double v = td.impact_velocity_m_s;
    // d residuals / d v: the simulation at v +- dv, at the fitted shift.
    Eigen::VectorXd dv_col = Eigen::VectorXd::Zero(n_res);
    if (std::isfinite(td.impact_velocity_se_m_s) || std::isfinite(td.calibration_scale_sd)) {
      const double dv = 1e-4 * std::max(v, 0.1);
      std::vector<double> rp(p.n_residuals()), rm(p.n_residuals());
      Prepared pp = p;
      pp.impact.velocity_m_s = v + dv;
      residuals_at(pp, simulate_window(pp, space, o, mp, nullptr), shift, rp.data());
      pp.impact.velocity_m_s = v - dv;
      residuals_at(pp, simulate_window(pp, space, o, mp, nullptr), shift, rm.data());
      for (int i = 0; i < p.n_residuals(); ++i) dv_col[off + i] = (rp[i] - rm[i]) / (2.0 * dv);
    }
    int vcol = -1;
    if (std::isfinite(td.impact_velocity_se_m_s) && td.impact_velocity_se_m_s > 0.0) {
      vcol = static_cast<int>(cols.size());
      nz.velocity[q] = vcol;
      cols.push_back(dv_col);
      prior.push_back({td.impact_velocity_se_m_s * td.impact_velocity_se_m_s, -1.0, 0.0});
    }
    if (nk > 0 && std::isfinite(td.contact_time_se_s) && td.contact_time_se_s > 0.0) {
      // The contact estimate late by dt: the measured travel at model time t
      // is the true travel at t + dt.
      const detail::Trace<double> s0 = simulate_window(p, space, o, mp, nullptr);
      Eigen::VectorXd c = Eigen::VectorXd::Zero(n_res);
      for (int j = 0; j < nk; ++j) {
        const double t = td.t_s[p.k_idx[j]], t0 = std::max(t - p.h, 0.0);
        const double rate = (on_grid(s0.impactor, t + p.h, p.h, 0.0) - on_grid(s0.impactor, t0, p.h, 0.0)) / (t + p.h - t0);
        c[off + nf + j] = p.k_w * rate;
      }
      // The free-fall fit's speed and instant err together: the velocity
      // correction is minus the speed's error.
      const double cov = std::isfinite(td.velocity_contact_time_cov) && vcol >= 0 ? -td.velocity_contact_time_cov : 0.0;
      prior.push_back({td.contact_time_se_s * td.contact_time_se_s, static_cast<double>(vcol), cov});
      cols.push_back(c);
    }
    if (nk > 0 && std::isfinite(td.travel_reference_se_m) && td.travel_reference_se_m > 0.0) {
      Eigen::VectorXd c = Eigen::VectorXd::Zero(n_res);
      for (int j = 0; j < nk; ++j) c[off + nf + j] = p.k_w;
      prior.push_back({td.travel_reference_se_m * td.travel_reference_se_m, -1.0, 0.0});
      cols.push_back(c);
    }
    if (std::isfinite(td.calibration_scale_sd) && td.calibration_scale_sd > 0.0) {
      // Lengths along z read (1 + s) times the truth: the velocity (the
      // simulation's input is v (1 + s): its correction -v s) and the travel.
      scale_sd = std::max(scale_sd, td.calibration_scale_sd);
      for (Eigen::Index i = 0; i < n_res; ++i) scale_col[i] -= v * dv_col[i];
      for (int j = 0; j < nk; ++j) scale_col[off + nf + j] += p.k_w * td.impactor_m[p.k_idx[j]];
    }
    off += p.n_residuals();
  }
  if (scale_sd > 0.0) {
    nz.scale = static_cast<int>(cols.size());
    cols.push_back(scale_col);
    prior.push_back({scale_sd * scale_sd, -1.0, 0.0});
  }
  const int m = static_cast<int>(cols.size());
  nz.K.resize(n_res, m);
  nz.P = Eigen::MatrixXd::Zero(m, m);
  for (int j = 0; j < m; ++j) {
    nz.K.col(j) = cols[j];
    nz.P(j, j) = prior[j][0];
    const int partner = static_cast<int>(prior[j][1]);
    if (partner >= 0) nz.P(j, partner) = nz.P(partner, j) = prior[j][2];
  }
  return nz;
}

ErrorBudget budget_at(const std::vector<Prepared>& preps, const Optimum& opt, const Nuisances& nz) {
  if (opt.jacobian.rows() != opt.residuals.size() || opt.jacobian.rows() == 0) return {};
  std::vector<ResidualBlock> blocks;
  int off = 0;
  for (const Prepared& p : preps) {
    const int nf = static_cast<int>(p.f_idx.size()), nk = static_cast<int>(p.k_idx.size());
    blocks.push_back({off, nf});
    blocks.push_back({off + nf, nk});
    off += nf + nk;
  }
  return error_budget(opt.jacobian, opt.residuals, blocks, nz.K, nz.P);
}

void mark_model_limited(FitResult* res) {
  for (const auto& c : res->channels)
    if (c.rms_sigma > 1.5 && c.lag1_autocorrelation > 0.5) {
      for (auto& e : res->estimates) e.model_limited = e.free;
      res->warnings.push_back(fmt::format(
          "the {} residual stays above its noise ({:.1f} noise SDs RMS, lag-1 autocorrelation {:.2f}): the model "
          "limits the parameters, and their intervals hold that residual, not the noise alone",
          c.name, c.rms_sigma, c.lag1_autocorrelation));
      return;
    }
}

double parabola_top(const Eigen::VectorXd& y, Eigen::Index i, double* offset) {
  *offset = 0.0;
  if (i <= 0 || i + 1 >= y.size()) return y[i];
  const double a = y[i - 1], b = y[i], c = y[i + 1], curv = a - 2.0 * b + c;
  if (!(curv < 0.0)) return b;
  *offset = 0.5 * (a - c) / curv;
  return b - 0.25 * (a - c) * *offset;
}

Summary summarise(const Simulation& s) {
  Summary out;
  if (s.grf_n.size() < 3) return out;
  Eigen::Index ip = 0, iy = 0;
  s.grf_n.maxCoeff(&ip);
  double off = 0.0;
  out.peak_n = parabola_top(s.grf_n, ip, &off);
  out.t_peak_s = s.t_s[ip] + off * (s.t_s[1] - s.t_s[0]);
  if (s.impactor_m.size() == s.grf_n.size()) {
    s.impactor_m.maxCoeff(&iy);
    out.max_travel_m = parabola_top(s.impactor_m, iy, &off);
  }
  return out;
}

Eigen::VectorXd force_on_samples(const Simulation& s, const Eigen::VectorXd& t_s, double shift, double h) {
  const Eigen::Index n = t_s.size();
  Eigen::VectorXd f = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double tau = t_s[i] - shift;
    if (tau < 0.0) continue;
    const double x = tau / h;
    const Eigen::Index k = static_cast<Eigen::Index>(std::floor(x));
    if (k + 1 >= s.grf_n.size()) {
      f[i] = s.grf_n[s.grf_n.size() - 1];
      continue;
    }
    const double a = x - static_cast<double>(k);
    f[i] = (1.0 - a) * s.grf_n[k] + a * s.grf_n[k + 1];
  }
  return f;
}

namespace {

// What a held-out quantity's interval is built from: the fitted
// coordinates' covariance and their covariance with the session's scale
// error and with this trial's own velocity error (a training trial's).
struct PredictionBasis {
  Eigen::MatrixXd cov_u;           // free parameters (optimiser coordinates)
  Eigen::VectorXd cov_u_scale;     // cov(u_hat, s), empty: none
  double scale_sd = 0.0;
  Eigen::VectorXd cov_u_velocity;  // cov(u_hat, e_v) of this trial, empty: none (held out)
};

Prediction prediction_intervals(const TrialData& td, const TrialReport& rep, const ParamSpace& space,
                                const FitOptions& o, const Eigen::VectorXd& u, const PredictionBasis& b) {
  Prediction out;
  const int np = space.size();
  Impact imp;
  imp.mass_kg = td.impactor_mass_kg;
  imp.gravity_m_s2 = td.gravity_m_s2;
  imp.velocity_m_s = td.impact_velocity_m_s;
  imp.first_output_s = 0.0;
  imp.output_dt_s = 1e-4;
  imp.duration_s = std::max(rep.window_end_s, 0.05) + 0.005;
  auto run = [&](const Eigen::VectorXd& uu, double v) {
    Impact i2 = imp;
    i2.velocity_m_s = v;
    return simulate_model(o, space.to_mat(uu.data()), i2);
  };
  const Simulation s0 = run(u, imp.velocity_m_s);
  const Summary q0 = summarise(s0);
  const Eigen::Index n = td.t_s.size();
  const double shift = rep.contact_shift_s;
  const Eigen::VectorXd f0 = force_on_samples(s0, td.t_s, shift, imp.output_dt_s);
  // Central differences: every free parameter, then the velocity.
  Eigen::MatrixXd g(3, np + 1), gf(n, np + 1);
  for (int j = 0; j <= np; ++j) {
    Eigen::VectorXd up = u, um = u;
    double vp = imp.velocity_m_s, vm = vp, step;
    if (j < np) {
      step = 1e-3 * std::max(std::abs(u[j]), 1.0);
      up[j] += step, um[j] -= step;
    } else {
      step = 1e-3 * std::max(vp, 0.1);
      vp += step, vm -= step;
    }
    const Simulation sp = run(up, vp), sm = run(um, vm);
    const Summary qp = summarise(sp), qm = summarise(sm);
    g(0, j) = (qp.peak_n - qm.peak_n) / (2.0 * step);
    g(1, j) = (qp.t_peak_s - qm.t_peak_s) / (2.0 * step);
    g(2, j) = (qp.max_travel_m - qm.max_travel_m) / (2.0 * step);
    gf.col(j) = (force_on_samples(sp, td.t_s, shift, imp.output_dt_s) -
                 force_on_samples(sm, td.t_s, shift, imp.output_dt_s)) /
                (2.0 * step);
  }
  const double v = imp.velocity_m_s;
  const double sv2 = std::isfinite(td.impact_velocity_se_m_s) ? td.impact_velocity_se_m_s * td.impact_velocity_se_m_s : 0.0;
  // error = g_u' (u_hat - u) + g_v (e_v + v s).
  auto variance = [&](const Eigen::VectorXd& gu, double gv) {
    double var = gu.dot(b.cov_u * gu) + gv * gv * (sv2 + v * v * b.scale_sd * b.scale_sd);
    if (b.cov_u_scale.size() == np) var += 2.0 * gv * v * gu.dot(b.cov_u_scale);
    if (b.cov_u_velocity.size() == np) var += 2.0 * gv * gu.dot(b.cov_u_velocity);
    return std::max(var, 0.0);
  };
  auto interval = [&](double value, int row) {
    PredictionInterval pi;
    pi.value = value;
    pi.se = std::sqrt(variance(g.row(row).head(np).transpose(), g(row, np)));
    pi.low = value - kZ95 * pi.se;
    pi.high = value + kZ95 * pi.se;
    return pi;
  };
  out.peak_force_n = interval(q0.peak_n, 0);
  out.time_to_peak_s = interval(q0.t_peak_s, 1);
  out.max_deformation_m = interval(q0.max_travel_m, 2);
  // The fitted contact instant moves with the parameters and the velocity:
  // profiled over the force window, ds/dq = sum F' dF/dq / sum F'^2 (the
  // simulated force F(t - s), F' its slope, the fit's equal weights).
  Eigen::VectorXd slope = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 1; i + 1 < n; ++i) slope[i] = (f0[i + 1] - f0[i - 1]) / (td.t_s[i + 1] - td.t_s[i - 1]);
  Eigen::RowVectorXd num = Eigen::RowVectorXd::Zero(np + 1);
  double den = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (td.t_s[i] < shift - o.contact_search_s || td.t_s[i] > rep.window_end_s) continue;
    num += slope[i] * gf.row(i);
    den += slope[i] * slope[i];
  }
  if (den > 0.0) {
    const Eigen::RowVectorXd ds = num / den;
    out.contact_shift_se_s = std::sqrt(variance(ds.head(np).transpose(), ds[np]));
  }
  // The force-time band: parameters, velocity and the trial's clock shift.
  out.force_low_n.resize(n);
  out.force_high_n.resize(n);
  const double sse = std::isfinite(rep.contact_shift_se_s) ? rep.contact_shift_se_s : 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const double sd = std::sqrt(variance(gf.row(i).head(np).transpose(), gf(i, np)) + slope[i] * slope[i] * sse * sse);
    out.force_low_n[i] = f0[i] - kZ95 * sd;
    out.force_high_n[i] = f0[i] + kZ95 * sd;
  }
  return out;
}

}  // namespace

void add_prediction_intervals(const std::vector<TrialData>& trials, const std::vector<Prepared>& preps,
                              const ParamSpace& space, const FitOptions& o, const Eigen::VectorXd& u,
                              const ErrorBudget& budget, const Nuisances& nz, FitResult* res) {
  const int np = space.size();
  auto data_of = [&](const TrialReport& r) -> const TrialData* {
    for (const auto& t : trials)
      if (t.id == r.id) return &t;
    return nullptr;
  };
  if (budget.covariance.rows() >= np) {
    PredictionBasis basis;
    basis.cov_u = budget.covariance.topLeftCorner(np, np);
    if (nz.scale >= 0) {
      basis.cov_u_scale = budget.nuisance_cross.col(nz.scale).head(np);
      basis.scale_sd = std::sqrt(nz.P(nz.scale, nz.scale));
    }
    std::vector<char> failed(res->trials.size(), 0);
    // In parallel, each trial its own simulations (a custom simulator is
    // not assumed thread-safe).
    parallel_for(res->trials.size(), o.simulator ? 1 : o.threads, [&](size_t q) {
      TrialReport& rep = res->trials[q];
      const TrialData* td = data_of(rep);
      if (!td) return;
      PredictionBasis b = basis;
      // A training trial's own velocity error is in the fit (the velocity
      // nuisance is minus that error).
      for (size_t k = 0; k < preps.size(); ++k)
        if (preps[k].data == td && nz.velocity[k] >= 0)
          b.cov_u_velocity = -budget.nuisance_cross.col(nz.velocity[k]).head(np);
      try {
        rep.prediction = prediction_intervals(*td, rep, space, o, u, b);
      } catch (...) {
        failed[q] = 1;
      }
    });
    for (size_t q = 0; q < res->trials.size(); ++q)
      if (failed[q]) res->warnings.push_back(fmt::format("trial {}: no prediction intervals", res->trials[q].id));
  }
  for (TrialReport& r : res->trials) {
    const TrialData* td = data_of(r);
    // A held-out trial's shift was fitted with the parameters held: what it
    // inherits from them and its velocity adds to its own noise's part.
    if (!r.train && std::isfinite(r.contact_shift_se_s) && std::isfinite(r.prediction.contact_shift_se_s))
      r.contact_shift_se_s = std::hypot(r.contact_shift_se_s, r.prediction.contact_shift_se_s);
    const double video_se = td && std::isfinite(td->contact_time_se_s) ? td->contact_time_se_s : 0.0;
    if (std::isfinite(r.contact_shift_se_s)) r.offset_se_s = std::hypot(r.contact_shift_se_s, video_se);
  }
}

Simulation simulate_model(const FitOptions& o, const MatParams& mp, const Impact& imp) {
  if (o.simulator) return o.simulator(mp, imp);
  if (o.model == ModelKind::Model5) return simulate_model5(mp, o.model5_geometry, imp);
  return simulate(o.model, mp, imp);
}

namespace {

double sim_peak(const FitOptions& o, const MatParams& mp, const Impact& imp) {
  const Simulation s = simulate_model(o, mp, imp);
  return s.grf_n.maxCoeff();
}

}  // namespace

// Sensitivity of the peak force to -10 % / +10 % on each stiffness and
// damping. From the exact derivatives, in one dual-number simulation: the
// peak's elasticity E = d ln F / d ln p (the envelope: the derivative at the
// peak sample), carried as a power law, 100 (0.9^E - 1) and 100 (1.1^E - 1)
// (exact when the peak goes as a power of the parameter, as a spring-mass
// impact's goes as sqrt(k)). A custom simulator is re-run at +-10 %.
std::vector<SensitivityEntry> sensitivity_table(const FitOptions& o, const MatParams& mp, const Impact& imp) {
  const ModelKind shape = o.model == ModelKind::Model5 ? ModelKind::Model4 : o.model;
  std::vector<std::string> names;
  for (const auto& name : parameter_names(shape, false))
    if (is_stiffness_or_damping(name)) names.push_back(name);
  std::vector<SensitivityEntry> out;
  if (o.simulator) {
    const double base = sim_peak(o, mp, imp);
    for (const auto& name : names) {
      SensitivityEntry s;
      s.name = name;
      MatParams lo = mp, hi = mp;
      set_parameter(lo, name, 0.9 * get_parameter(mp, name));
      set_parameter(hi, name, 1.1 * get_parameter(mp, name));
      s.peak_pct_minus10 = 100.0 * (sim_peak(o, lo, imp) - base) / base;
      s.peak_pct_plus10 = 100.0 * (sim_peak(o, hi, imp) - base) / base;
      out.push_back(s);
    }
    return out;
  }
  using J = ceres::Jet<double, 8>;
  detail::ParamsT<J> p = detail::to_params_t<J>(shape, mp);
  for (size_t a = 0; a < names.size() && a < 8; ++a) {
    const std::string& n = names[a];
    J& f = n[0] == 'k' ? p.k[n[1] - '1'] : p.r[n[1] - '1'];
    f.v[a] = f.a;  // d / d ln p
  }
  const int n_out =
      static_cast<int>(std::floor((imp.duration_s - imp.first_output_s) / imp.output_dt_s + 1e-9)) + 1;
  std::vector<J> grf;
  if (o.model == ModelKind::Model5) {
    simulate_model5_t<J>(model5_params_t(p), o.model5_geometry, imp, n_out, &grf, nullptr, nullptr);
  } else {
    detail::Trace<J> tr;
    detail::run_model<J>(detail::layout_for(shape, mp.m_eff_kg <= 0.0), p, imp, !mp.has_effects(),
                         SimulateOptions{}.rk4_max_step_s, n_out, tr);
    grf = std::move(tr.grf);
  }
  size_t ip = 0;
  for (size_t i = 1; i < grf.size(); ++i)
    if (grf[i].a > grf[ip].a) ip = i;
  for (size_t a = 0; a < names.size() && a < 8; ++a) {
    const double e = grf[ip].v[a] / grf[ip].a;
    SensitivityEntry s;
    s.name = names[a];
    s.peak_pct_minus10 = 100.0 * (std::pow(0.9, e) - 1.0);
    s.peak_pct_plus10 = 100.0 * (std::pow(1.1, e) - 1.0);
    out.push_back(s);
  }
  return out;
}

}  // namespace dropfit::fitting::internal
