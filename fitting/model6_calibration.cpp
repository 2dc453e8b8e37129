// Model 6's uncertainty calibrations (fitting/model6_calibration.h).
#include "fitting/model6_calibration.h"

#include <boost/math/distributions/students_t.hpp>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

namespace dropfit::fitting {

namespace {

// kappa^2 >= 0, the scale of the shape w that the checks' excesses
// e_j = r_j^2 - noise_j - parameter_j - discrepancy_j estimate
// (E[e_j] = kappa^2 w_j), by weighted least squares: each e_j / w_j
// weighted by w_j^2 / (noise_j + parameter_j + discrepancy_j + kappa^2
// w_j)^2, the inverse of its variance (r_j^2 scatters as chi-square with
// one degree of freedom about its expectation), iterated to its fixed
// point. A check whose stated variance dwarfs its shape (a peak whose
// parameters' SE is several per cent) then tells little; in a plain sum its
// large negative excess would cancel every other trial's.
double shape_scale(const std::vector<double>& excess, const std::vector<double>& w, const std::vector<double>& stated) {
  double k2 = 0.0;
  for (int it = 0; it < 100; ++it) {
    double num = 0.0, den = 0.0;
    for (std::size_t j = 0; j < w.size(); ++j) {
      if (!(w[j] > 0.0)) continue;
      const double v = stated[j] + k2 * w[j];
      const double a = w[j] * w[j] / (v * v);
      num += a * excess[j] / w[j], den += a;
    }
    const double next = den > 0.0 ? std::max(num / den, 0.0) : 0.0;
    const bool done = std::abs(next - k2) <= 1e-12 * std::max(next, 1e-300);
    k2 = next;
    if (done) break;
  }
  return k2;
}

}  // namespace

std::vector<double> cross_validated_discrepancy_var(const std::vector<HeldOutCheck>& checks, int min_others,
                                                    double min_discrepancy_share) {
  std::vector<double> out;
  out.reserve(checks.size());
  for (std::size_t i = 0; i < checks.size(); ++i) {
    const HeldOutCheck& c = checks[i];
    std::vector<const HeldOutCheck*> others;
    double share = 0.0;
    for (std::size_t j = 0; j < checks.size(); ++j) {
      const HeldOutCheck& o = checks[j];
      if (j == i || !std::isfinite(o.residual)) continue;
      others.push_back(&o);
      const double st = o.parameter_var + o.discrepancy_var;
      share += st > 0.0 ? o.discrepancy_var / st : 0.0;
    }
    if (static_cast<int>(others.size()) < min_others) {
      out.push_back(c.discrepancy_var);
      continue;
    }
    const bool by_misfit = share / static_cast<double>(others.size()) >= min_discrepancy_share;
    auto base = [&](const HeldOutCheck& x) {
      return by_misfit ? x.discrepancy_var : x.parameter_var + x.discrepancy_var;
    };
    double shaped = 0.0, flat = 0.0;
    for (const HeldOutCheck* o : others) shaped += o->distance * o->distance * base(*o), flat += base(*o);
    const bool by_distance = shaped > 1e-9 * flat;
    auto shape = [&](const HeldOutCheck& x) { return by_distance ? x.distance * x.distance * base(x) : base(x); };
    std::vector<double> excess, w, stated;
    for (const HeldOutCheck* o : others) {
      excess.push_back(o->residual * o->residual - o->noise_var - o->parameter_var - o->discrepancy_var);
      w.push_back(shape(*o));
      stated.push_back(o->noise_var + o->parameter_var + o->discrepancy_var);
    }
    out.push_back(c.discrepancy_var + shape(c) * shape_scale(excess, w, stated));
  }
  return out;
}

std::vector<int> cross_validated_dof(const std::vector<HeldOutCheck>& checks, int min_others) {
  int finite = 0;
  for (const HeldOutCheck& c : checks) finite += std::isfinite(c.residual) ? 1 : 0;
  std::vector<int> out;
  out.reserve(checks.size());
  for (const HeldOutCheck& c : checks) {
    const int others = finite - (std::isfinite(c.residual) ? 1 : 0);
    out.push_back(others >= min_others ? others : 0);
  }
  return out;
}

double welch_dof(double known_var, double estimated_var, double dof) {
  if (!(dof >= 1.0) || !(estimated_var > 0.0)) return std::numeric_limits<double>::infinity();
  const double total = std::max(known_var, 0.0) + estimated_var;
  return total * total / (estimated_var * estimated_var / dof);
}

double t_quantile_95(double dof) {
  constexpr double kNormal = 1.959964;
  if (!(dof > 0.0) || !std::isfinite(dof) || dof > 1e6) return kNormal;
  return boost::math::quantile(boost::math::students_t(dof), 0.975);
}

double birge_ratio(const std::vector<double>& values, const std::vector<double>& ses) {
  if (values.size() < 2 || values.size() != ses.size()) return 1.0;
  double sw = 0.0, swx = 0.0;
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (!(ses[i] > 0.0) || !std::isfinite(ses[i]) || !std::isfinite(values[i])) return 1.0;
    const double w = 1.0 / (ses[i] * ses[i]);
    sw += w, swx += w * values[i];
  }
  const double mean = swx / sw;
  double chi2 = 0.0;
  for (std::size_t i = 0; i < values.size(); ++i) chi2 += std::pow((values[i] - mean) / ses[i], 2);
  return std::max(1.0, std::sqrt(chi2 / static_cast<double>(values.size() - 1)));
}

std::vector<double> calibrated_offset_ses(const std::vector<double>& offsets_s, const std::vector<double>& ses_s,
                                          double common_s) {
  const double b = birge_ratio(offsets_s, ses_s);
  const double c = std::isfinite(common_s) ? common_s : 0.0;
  std::vector<double> out;
  out.reserve(ses_s.size());
  for (double se : ses_s) out.push_back(std::hypot(b * se, c));
  return out;
}

}  // namespace dropfit::fitting
