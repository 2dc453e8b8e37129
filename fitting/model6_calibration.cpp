// Model 6's uncertainty calibrations (fitting/model6_calibration.h).
#include "fitting/model6_calibration.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

namespace dropfit::fitting {

std::vector<double> cross_validated_discrepancy_var(const std::vector<HeldOutCheck>& checks, int min_others,
                                                    double min_discrepancy_share) {
  std::vector<double> out;
  out.reserve(checks.size());
  for (std::size_t i = 0; i < checks.size(); ++i) {
    const HeldOutCheck& c = checks[i];
    double excess = 0.0, disc = 0.0, stated = 0.0;
    int others = 0;
    for (std::size_t j = 0; j < checks.size(); ++j) {
      const HeldOutCheck& o = checks[j];
      if (j == i || !std::isfinite(o.residual)) continue;
      excess += o.residual * o.residual - o.noise_var - o.parameter_var;
      disc += o.discrepancy_var;
      stated += o.parameter_var + o.discrepancy_var;
      ++others;
    }
    double var = c.discrepancy_var;
    if (others >= min_others && stated > 0.0) {
      if (disc >= min_discrepancy_share * stated)
        var *= std::max(1.0, excess / disc);
      else
        var += (std::max(1.0, (excess + disc) / stated) - 1.0) * (c.parameter_var + c.discrepancy_var);
    }
    out.push_back(var);
  }
  return out;
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
