// The fitter's uncertainty (see detail/uncertainty.h and fit.h).
#include "fitting/detail/uncertainty.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "fitting/model5_impl.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting::internal {

void covariance(const Optimum& opt, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                std::vector<ParameterEstimate>* est, std::vector<double>* shift_se,
                std::vector<std::string>* warnings) {
  const int np = space.size();
  const Eigen::MatrixXd& J = opt.jacobian;
  const int n = static_cast<int>(J.cols());
  if (J.rows() <= n || n < np) {
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
  auto label = [&](int j) { return j < np ? param_display(space.free[j]) : fmt::format("clock shift {}", j - np + 1); };
  for (int i = 0; i < n; ++i) {
    const double lam = ev[i];
    if (lam < 1e-8 * evmax) {
      const Eigen::VectorXd v = es.eigenvectors().col(i);
      std::string dir;
      for (int j = 0; j < n; ++j)
        if (std::abs(v[j]) > 0.3) dir += fmt::format("{}{:+.2f} {}", dir.empty() ? "" : " ", v[j], label(j));
      warnings->push_back(fmt::format("near-singular direction (eigenvalue ratio {:.1e}): {}", lam / evmax, dir));
    }
  }
  auto lost = [&](int j) {
    for (int i = 0; i < n; ++i)
      if (ev[i] <= 1e-14 * evmax && std::abs(es.eigenvectors()(j, i)) > 0.1) return true;
    return false;
  };
  shift_se->clear();
  for (int j = np; j < n; ++j)
    shift_se->push_back(lost(j) ? std::numeric_limits<double>::infinity() : std::sqrt(std::max(cov(j, j), 0.0)));
  for (int j = 0; j < np; ++j) {
    const FreeParam& f = space.free[j];
    ParameterEstimate& e = (*est)[j];
    double se_u = std::sqrt(std::max(cov(j, j), 0.0));
    // A direction dropped from the inverse: the parameter is unconstrained.
    if (lost(j)) se_u = std::numeric_limits<double>::infinity();
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
