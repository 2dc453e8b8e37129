// Key force-time characteristics (Mills, Pain & Yeadon 2006): see
// characteristics.h for the definitions.
#include "fitting/characteristics.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.h"

namespace dropfit::fitting {

namespace {

Eigen::VectorXd smoothed(const Eigen::VectorXd& f, int window) {
  if (window <= 1) return f;
  const int half = window / 2;
  const int n = static_cast<int>(f.size());
  Eigen::VectorXd out(n);
  for (int i = 0; i < n; ++i) {
    const int a = std::max(0, i - half), b = std::min(n - 1, i + half);
    out[i] = f.segment(a, b - a + 1).mean();
  }
  return out;
}

// Prominence of the local maximum at i. A side without samples (a peak at
// the signal's first or last sample) does not constrain it.
double prominence(const Eigen::VectorXd& f, int i) {
  const int n = static_cast<int>(f.size());
  const double none = -std::numeric_limits<double>::infinity();
  double left_min = i > 0 ? f[i] : none;
  for (int j = i - 1; j >= 0; --j) {
    if (f[j] > f[i]) break;
    left_min = std::min(left_min, f[j]);
  }
  double right_min = i < n - 1 ? f[i] : none;
  for (int j = i + 1; j < n; ++j) {
    if (f[j] > f[i]) break;
    right_min = std::min(right_min, f[j]);
  }
  const double base = std::max(left_min, right_min);
  return base == none ? f[i] : f[i] - base;
}

}  // namespace

Characteristics characteristics(const Eigen::VectorXd& t_s, const Eigen::VectorXd& force_n,
                                const CharacteristicsOptions& options) {
  const int n = static_cast<int>(force_n.size());
  if (t_s.size() != force_n.size())
    throw Error(fmt::format("characteristics: {} times but {} forces", t_s.size(), force_n.size()));
  if (n < 3) throw Error("characteristics: need at least 3 force samples");
  for (int i = 1; i < n; ++i)
    if (!(t_s[i] > t_s[i - 1])) throw Error("characteristics: sample times must increase");
  if (!force_n.allFinite()) throw Error("characteristics: force samples must be finite");

  const Eigen::VectorXd f = smoothed(force_n, options.smooth_samples);
  Characteristics c;
  Eigen::Index ip;
  c.peak_force_n = f.maxCoeff(&ip);
  c.time_to_peak_s = t_s[ip];

  // Prominent peaks in time order. A plateau counts once (its first sample).
  std::vector<int> peaks;
  const double min_prom = options.prominence_frac * std::abs(c.peak_force_n);
  const double min_height = options.min_peak_frac * c.peak_force_n;
  for (int i = 0; i < n; ++i) {
    const bool left_ok = i == 0 || f[i] > f[i - 1];
    int j = i;
    while (j + 1 < n && f[j + 1] == f[i]) ++j;  // plateau end
    const bool right_ok = j == n - 1 || f[j + 1] < f[i];
    if (left_ok && right_ok && f[i] >= min_height && prominence(f, i) >= min_prom) peaks.push_back(i);
    i = j;
  }
  c.n_peaks = static_cast<int>(peaks.size());
  if (!peaks.empty()) {
    c.first_peak_n = f[peaks[0]];
    c.first_peak_s = t_s[peaks[0]];
  }
  if (peaks.size() >= 2) {
    c.second_peak_n = f[peaks[1]];
    c.second_peak_s = t_s[peaks[1]];
    int im = peaks[0];
    for (int i = peaks[0]; i <= peaks[1]; ++i)
      if (f[i] < f[im]) im = i;
    c.min_between_n = f[im];
    c.min_between_s = t_s[im];
  }

  // Rate of loading up to the global peak.
  double best = -std::numeric_limits<double>::infinity();
  int ib = 0;
  for (int i = 0; i <= ip; ++i) {
    const int a = std::max(0, i - 1), b = std::min(n - 1, i + 1);
    const double rate = (f[b] - f[a]) / (t_s[b] - t_s[a]);
    if (rate > best) {
      best = rate;
      ib = i;
    }
  }
  c.max_loading_rate_n_s = best;
  c.max_loading_rate_s = t_s[ib];
  return c;
}

ForceComparison compare_forces(const Eigen::VectorXd& t_s, const Eigen::VectorXd& measured_n,
                               const Eigen::VectorXd& simulated_n) {
  if (t_s.size() != measured_n.size() || t_s.size() != simulated_n.size())
    throw Error("compare_forces: times, measured and simulated forces differ in length");
  ForceComparison out;
  double ss = 0.0, mpk = -std::numeric_limits<double>::infinity(),
         spk = -std::numeric_limits<double>::infinity();
  double mt = Characteristics::nan, st = Characteristics::nan;
  int count = 0;
  for (Eigen::Index i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(measured_n[i]) || !std::isfinite(simulated_n[i])) continue;
    const double d = simulated_n[i] - measured_n[i];
    ss += d * d;
    ++count;
    if (measured_n[i] > mpk) { mpk = measured_n[i]; mt = t_s[i]; }
    if (simulated_n[i] > spk) { spk = simulated_n[i]; st = t_s[i]; }
  }
  if (count == 0 || !(mpk > 0.0)) return out;
  out.rms_force_pct_peak = 100.0 * std::sqrt(ss / count) / mpk;
  out.peak_force_pct_diff = 100.0 * (spk - mpk) / mpk;
  out.time_to_peak_ms_diff = 1000.0 * (st - mt);
  return out;
}

}  // namespace dropfit::fitting
