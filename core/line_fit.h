#pragma once
// Ordinary least-squares line y = intercept + slope x, with the scatter
// about it (n - 2 degrees of freedom) and the slope's standard error from
// that scatter. ok is false with fewer than three points or no spread in x.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

namespace dropfit {

struct LineFit {
  bool ok = false;
  double slope = 0.0, intercept = 0.0, slope_se = 0.0;
  double residual_sd = 0.0;  // the points' SD about the line
  double r2 = 0.0;           // share of y's variance about its mean the line explains
  double at(double x) const { return intercept + slope * x; }
};

inline LineFit fit_line(const std::vector<double>& x, const std::vector<double>& y) {
  LineFit f;
  const std::size_t n = std::min(x.size(), y.size());
  if (n < 3) return f;
  double mx = 0.0, my = 0.0;
  for (std::size_t k = 0; k < n; ++k) mx += x[k], my += y[k];
  mx /= static_cast<double>(n), my /= static_cast<double>(n);
  double sxx = 0.0, sxy = 0.0, syy = 0.0;
  for (std::size_t k = 0; k < n; ++k) {
    sxx += (x[k] - mx) * (x[k] - mx);
    sxy += (x[k] - mx) * (y[k] - my);
    syy += (y[k] - my) * (y[k] - my);
  }
  if (!(sxx > 0.0)) return f;
  f.ok = true;
  f.slope = sxy / sxx;
  f.intercept = my - f.slope * mx;
  double rss = 0.0;
  for (std::size_t k = 0; k < n; ++k) rss += std::pow(y[k] - f.intercept - f.slope * x[k], 2);
  f.residual_sd = std::sqrt(rss / (static_cast<double>(n) - 2.0));
  f.slope_se = f.residual_sd / std::sqrt(sxx);
  f.r2 = syy > 0.0 ? 1.0 - rss / syy : 0.0;
  return f;
}

}  // namespace dropfit
