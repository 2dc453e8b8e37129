// Simulated annealing after Corana et al. (1987); see anneal.h.
#include "fitting/anneal.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <random>
#include <vector>

#include "core/error.h"

namespace dropfit::fitting {

AnnealResult anneal(const std::function<double(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& x0,
                    const Eigen::VectorXd& lower, const Eigen::VectorXd& upper,
                    const AnnealOptions& options) {
  const int n = static_cast<int>(x0.size());
  if (n == 0 || lower.size() != n || upper.size() != n)
    throw Error("anneal: x0, lower and upper must have the same, non-zero size");
  for (int h = 0; h < n; ++h)
    if (!(lower[h] < upper[h]) || !std::isfinite(lower[h]) || !std::isfinite(upper[h]))
      throw Error(fmt::format("anneal: bounds of coordinate {} are not finite and increasing", h));
  if (!(options.rt > 0.0 && options.rt < 1.0)) throw Error("anneal: rt must lie in (0, 1)");
  if (options.ns < 1 || options.neps < 1) throw Error("anneal: ns and neps must be positive");

  std::mt19937_64 rng(options.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const Eigen::VectorXd width = upper - lower;
  auto eval = [&](const Eigen::VectorXd& x) {
    const double v = f(x);
    return std::isfinite(v) ? v : std::numeric_limits<double>::infinity();
  };

  AnnealResult res;
  Eigen::VectorXd x = x0.cwiseMax(lower).cwiseMin(upper);
  double fx = eval(x);
  ++res.evaluations;
  if (!std::isfinite(fx)) throw Error("anneal: the objective is not finite at the starting point");
  Eigen::VectorXd xopt = x;
  double fopt = fx;

  double T = options.initial_temperature;
  if (!(T > 0.0)) {
    // Spread of f over random points in the bounds (finite values only).
    std::vector<double> vals;
    for (int i = 0; i < std::max(10, 5 * n); ++i) {
      Eigen::VectorXd xr(n);
      for (int h = 0; h < n; ++h) xr[h] = lower[h] + uni(rng) * width[h];
      const double v = eval(xr);
      ++res.evaluations;
      if (std::isfinite(v)) {
        vals.push_back(v);
        if (v < fopt) { fopt = v; xopt = xr; }
      }
    }
    double mean = 0.0;
    for (double v : vals) mean += v;
    mean = vals.empty() ? 0.0 : mean / vals.size();
    double var = 0.0;
    for (double v : vals) var += (v - mean) * (v - mean);
    T = vals.size() > 1 ? std::sqrt(var / (vals.size() - 1)) : 0.0;
    if (!(T > 0.0)) T = std::max(1.0, std::abs(fx));
  }

  const int nt = options.nt > 0 ? options.nt : std::max(100, 5 * n);
  Eigen::VectorXd vm = width / 2.0;
  std::vector<int> nacp(n, 0);
  std::deque<double> fstar;  // most recent end-of-temperature values first

  while (res.evaluations < options.max_evaluations) {
    for (int m = 0; m < nt && res.evaluations < options.max_evaluations; ++m) {
      for (int j = 0; j < options.ns; ++j) {
        for (int h = 0; h < n; ++h) {
          Eigen::VectorXd xp = x;
          xp[h] = x[h] + (2.0 * uni(rng) - 1.0) * vm[h];
          if (xp[h] < lower[h] || xp[h] > upper[h]) xp[h] = lower[h] + uni(rng) * width[h];
          const double fp = eval(xp);
          ++res.evaluations;
          bool accept = fp <= fx;
          if (!accept && std::isfinite(fp)) accept = uni(rng) < std::exp(-(fp - fx) / T);
          if (accept) {
            x = xp;
            fx = fp;
            ++nacp[h];
            if (fp < fopt) { fopt = fp; xopt = xp; }
          }
        }
      }
      for (int h = 0; h < n; ++h) {
        const double r = static_cast<double>(nacp[h]) / options.ns;
        if (r > 0.6) vm[h] *= 1.0 + options.c * (r - 0.6) / 0.4;
        else if (r < 0.4) vm[h] /= 1.0 + options.c * (0.4 - r) / 0.4;
        vm[h] = std::min(vm[h], width[h]);
        nacp[h] = 0;
      }
    }
    ++res.temperatures;
    fstar.push_front(fx);
    if (static_cast<int>(fstar.size()) > options.neps) fstar.pop_back();
    const double tol = options.eps * std::max(std::abs(fopt), 1e-300);
    bool done = static_cast<int>(fstar.size()) == options.neps && std::abs(fx - fopt) <= tol;
    for (size_t i = 1; done && i < fstar.size(); ++i) done = std::abs(fstar[0] - fstar[i]) <= tol;
    if (done) {
      res.converged = true;
      break;
    }
    T *= options.rt;
    x = xopt;
    fx = fopt;
  }
  res.x = xopt;
  res.f = fopt;
  return res;
}

}  // namespace dropfit::fitting
