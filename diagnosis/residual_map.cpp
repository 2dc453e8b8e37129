// The held-out residual mapped against deflection, its rate, the time since
// contact and the recording order (diagnosis.h, "The residual traced to its
// form").
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"
#include "diagnosis/model_choice.h"

namespace dropfit::diagnosis {
namespace {

struct Sample {
  double r = 0.0, x = 0.0, v = 0.0, t = 0.0;
};

// Binned means of r over `key` in `bins` equal bins; r2 = their share of sum r^2.
ResidualAxis bin(const std::string& name, const std::vector<Sample>& s, double Sample::*key, int bins) {
  ResidualAxis a;
  a.name = name;
  if (s.empty()) return a;
  double lo = 1e300, hi = -1e300;
  for (const auto& q : s) lo = std::min(lo, q.*key), hi = std::max(hi, q.*key);
  const double w = std::max(hi - lo, 1e-12) / bins;
  std::vector<double> sum(bins, 0.0), n(bins, 0.0);
  double ss = 0.0;
  for (const auto& q : s) {
    const int b = std::clamp(static_cast<int>((q.*key - lo) / w), 0, bins - 1);
    sum[b] += q.r;
    n[b] += 1.0;
    ss += q.r * q.r;
  }
  double explained = 0.0;
  for (int b = 0; b < bins; ++b) {
    if (n[b] == 0.0) continue;
    a.centre.push_back(lo + (b + 0.5) * w);
    a.mean_sd.push_back(sum[b] / n[b]);
    a.count.push_back(n[b]);
    explained += sum[b] * sum[b] / n[b];
  }
  a.r2 = ss > 0.0 ? explained / ss : 0.0;
  return a;
}

}  // namespace

ResidualMap map_residual(const std::vector<fitting::TrialData>& trials,
                         const std::vector<fitting::TrialReport>& reports, double force_noise_n, double min_share) {
  ResidualMap m;
  std::vector<Sample> all, loading, unloading;
  std::vector<double> order, trial_mean;
  for (const auto& rep : reports) {
    if (rep.train) continue;
    const auto it = std::find_if(trials.begin(), trials.end(), [&](const auto& t) { return t.id == rep.id; });
    if (it == trials.end() || !it->accepted) continue;
    const fitting::TrialData& tr = *it;
    const Eigen::VectorXd& zs = rep.simulation.impactor_m;
    if (zs.size() != tr.t_s.size() || rep.simulation.grf_n.size() != tr.t_s.size()) continue;
    const double noise = std::isfinite(tr.force_noise_n) && tr.force_noise_n > 0.0 ? tr.force_noise_n : force_noise_n;
    double sum = 0.0;
    int n = 0;
    for (Eigen::Index i = 1; i + 1 < tr.t_s.size(); ++i) {
      const double tc = tr.t_s[i] - rep.contact_shift_s;
      if (tc < 0.0 || tr.t_s[i] > rep.window_end_s || !std::isfinite(tr.grf_n[i])) continue;
      Sample q;
      q.r = (tr.grf_n[i] - rep.simulation.grf_n[i]) / noise;
      const bool seen = tr.impactor_m.size() == tr.t_s.size() && std::isfinite(tr.impactor_m[i]);
      q.x = seen ? tr.impactor_m[i] : zs[i];
      q.v = (zs[i + 1] - zs[i - 1]) / (tr.t_s[i + 1] - tr.t_s[i - 1]);
      q.t = tc;
      all.push_back(q);
      (q.v >= 0.0 ? loading : unloading).push_back(q);
      sum += q.r;
      ++n;
    }
    if (n == 0) continue;
    order.push_back(static_cast<double>(it - trials.begin()));
    trial_mean.push_back(sum / n);
  }
  const int bins = 10;
  m.axes.push_back(bin("deflection_m", all, &Sample::x, bins));
  m.axes.push_back(bin("deflection_rate_m_s", all, &Sample::v, bins));
  m.axes.push_back(bin("time_since_contact_s", all, &Sample::t, bins));
  // Loading and unloading apart, each binned on the deflection.
  double ss = 0.0;
  for (const auto& q : all) ss += q.r * q.r;
  const ResidualAxis la = bin("loading", loading, &Sample::x, bins), ua = bin("unloading", unloading, &Sample::x, bins);
  double ex = 0.0;
  for (const ResidualAxis* a : {&la, &ua})
    for (size_t b = 0; b < a->mean_sd.size(); ++b) ex += a->mean_sd[b] * a->mean_sd[b] * a->count[b];
  m.loading_unloading_r2 = ss > 0.0 ? ex / ss : 0.0;
  // Recording order: per-trial means and their least-squares slope.
  ResidualAxis oa;
  oa.name = "recording_order";
  oa.centre = order;
  oa.mean_sd = trial_mean;
  oa.count.assign(order.size(), 1.0);
  const detail::LineFit line = detail::fit_line(order, trial_mean);
  if (line.ok) {
    m.order_slope_sd = line.slope;
    m.order_slope_t = line.slope_se > 0.0 ? line.slope / line.slope_se : (line.slope != 0.0 ? 1e9 : 0.0);
    oa.r2 = line.r2;
  }
  m.axes.push_back(oa);

  // The form: the strongest axis over min_share; memory when loading and
  // unloading apart explain clearly more than deflection and rate.
  const double rx = m.axes[0].r2, rv = m.axes[1].r2, rt = m.axes[2].r2;
  const double best = std::max({rx, rv, rt});
  if (line.ok && std::abs(m.order_slope_t) > 3.0 && oa.r2 > 0.8) {
    m.form = "trial_to_trial";
    m.proposal = fmt::format(
        "the held-out trials' mean residual trends with recording order ({:+.2f} noise SDs per trial, t = {:.1f}): "
        "the mat changes between trials (a stiffness or damping that drifts with the trial's place), not with speed",
        m.order_slope_sd, m.order_slope_t);
  } else if (m.loading_unloading_r2 > std::max(rx, rv) + min_share && m.loading_unloading_r2 >= min_share) {
    m.form = "memory";
    m.proposal = fmt::format(
        "at the same deflection loading and unloading disagree (they explain {:.0f} % of the residual, the deflection "
        "alone {:.0f} %, the rate {:.0f} %): a stress that relaxes, a viscoelastic arm (Maxwell or Prony term) "
        "beside the elastic curve",
        100 * m.loading_unloading_r2, 100 * rx, 100 * rv);
  } else if (best < min_share) {
    m.form = "none";
    m.proposal = fmt::format("no state explains the residual (deflection {:.0f} %, rate {:.0f} %, time {:.0f} %)",
                             100 * rx, 100 * rv, 100 * rt);
  } else if (best == rx) {
    const ResidualAxis& a = m.axes[0];
    const auto at = std::max_element(a.mean_sd.begin(), a.mean_sd.end(),
                                     [](double p, double q) { return std::abs(p) < std::abs(q); });
    const double where = a.centre[static_cast<size_t>(at - a.mean_sd.begin())];
    m.form = "elastic";
    m.proposal = fmt::format(
        "the residual follows the deflection ({:.0f} % of it), largest ({:+.1f} noise SDs) near {:.0f} mm: the elastic "
        "curve's shape is wrong there ({}: a hardening or densification term)",
        100 * rx, *at, 1000 * where, *at > 0 ? "too soft" : "too stiff");
  } else if (best == rv) {
    m.form = "viscous";
    m.proposal = fmt::format("the residual follows the deflection rate ({:.0f} % of it): a rate term (damping, or a "
                             "damping that differs between loading and unloading)",
                             100 * rv);
  } else {
    m.form = "memory";
    m.proposal = fmt::format(
        "the residual follows the time since contact ({:.0f} %) more than the deflection ({:.0f} %) or its rate ({:.0f} "
        "%): a memory, a stress that relaxes (Maxwell or Prony term)",
        100 * rt, 100 * rx, 100 * rv);
  }
  return m;
}

}  // namespace dropfit::diagnosis
