// The free fall's own acceleration (trial.h: fit_fall_acceleration), the
// video's check of its time base and length scale against gravity.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <vector>

#include "trial/trial.h"

namespace dropfit::trial {
namespace {

struct Quadratic {
  Eigen::Vector3d coef;  // z = c0 + c1 tau + c2 tau^2
  Eigen::Matrix3d xtx_inv;
  double rss = 0.0;
  int n = 0;
};

bool fit_quadratic(const std::vector<double>& tau, const std::vector<double>& z, const std::vector<char>& use,
                   Quadratic& q) {
  Eigen::Matrix3d xtx = Eigen::Matrix3d::Zero();
  Eigen::Vector3d xty = Eigen::Vector3d::Zero();
  int n = 0;
  for (std::size_t i = 0; i < tau.size(); ++i) {
    if (!use[i]) continue;
    const Eigen::Vector3d x(1.0, tau[i], tau[i] * tau[i]);
    xtx += x * x.transpose();
    xty += x * z[i];
    ++n;
  }
  if (n < 4) return false;
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(xtx);
  if (ldlt.info() != Eigen::Success || !(ldlt.rcond() > 1e-14)) return false;
  q.coef = ldlt.solve(xty);
  q.xtx_inv = ldlt.solve(Eigen::Matrix3d::Identity());
  q.rss = 0.0;
  for (std::size_t i = 0; i < tau.size(); ++i) {
    if (!use[i]) continue;
    const double r = z[i] - q.coef[0] - q.coef[1] * tau[i] - q.coef[2] * tau[i] * tau[i];
    q.rss += r * r;
  }
  q.n = n;
  return true;
}

}  // namespace

FallAcceleration fit_fall_acceleration(const Eigen::VectorXd& t_s, const Eigen::VectorXd& z_m) {
  FallAcceleration out;
  const std::size_t n = static_cast<std::size_t>(std::min(t_s.size(), z_m.size()));
  if (n < 4) return out;
  double t_mid = 0.0;
  for (std::size_t i = 0; i < n; ++i) t_mid += t_s[static_cast<Eigen::Index>(i)] / static_cast<double>(n);
  std::vector<double> tau(n), z(n);
  for (std::size_t i = 0; i < n; ++i) {
    tau[i] = t_s[static_cast<Eigen::Index>(i)] - t_mid;  // centred: a well-conditioned normal matrix
    z[i] = z_m[static_cast<Eigen::Index>(i)];
  }
  std::vector<char> use(n, 1);
  Quadratic q;
  if (!fit_quadratic(tau, z, use, q)) return out;
  // One pass dropping residuals beyond 4 robust SDs (misdigitised frames).
  std::vector<double> r(n), absr(n);
  for (std::size_t i = 0; i < n; ++i) {
    r[i] = z[i] - q.coef[0] - q.coef[1] * tau[i] - q.coef[2] * tau[i] * tau[i];
    absr[i] = std::abs(r[i]);
  }
  std::nth_element(absr.begin(), absr.begin() + static_cast<std::ptrdiff_t>(n / 2), absr.end());
  const double sigma = std::max(1.4826 * absr[n / 2], 1e-6);
  bool dropped = false;
  for (std::size_t i = 0; i < n; ++i)
    if (std::abs(r[i]) > 4.0 * sigma) use[i] = 0, dropped = true;
  if (dropped && !fit_quadratic(tau, z, use, q)) return out;
  const double s2 = q.rss / std::max(q.n - 3, 1);
  double lo = 1e300, hi = -1e300;
  for (std::size_t i = 0; i < n; ++i)
    if (use[i]) lo = std::min(lo, tau[i]), hi = std::max(hi, tau[i]);
  out.ok = true;
  out.n_frames = q.n;
  out.span_s = hi - lo;
  // z = c0 + c1 tau + c2 tau^2 falls at a = -2 c2.
  out.accel_m_s2 = -2.0 * q.coef[2];
  out.se_m_s2 = 2.0 * std::sqrt(std::max(s2 * q.xtx_inv(2, 2), 0.0));
  return out;
}

std::string fall_acceleration_reason(const FallAcceleration& fall, const TrialOptions& o) {
  if (!fall.ok || !std::isfinite(fall.accel_m_s2) || !std::isfinite(fall.se_m_s2)) return {};
  const double g = o.gravity_m_s2;
  const double above = (fall.accel_m_s2 - g * (1.0 + o.fall_accel_excess)) / fall.se_m_s2;
  const double below = (g * (1.0 - o.fall_accel_deficit) - fall.accel_m_s2) / fall.se_m_s2;
  if (above <= o.fall_accel_sigma && below <= o.fall_accel_sigma) return {};
  if (!(fall.accel_m_s2 > 0.0))
    return fmt::format(
        "video: the impactor does not fall before contact (acceleration {:.2f} +- {:.2f} m/s^2 over {} frames): the "
        "face heights or the video's frame rate ([video] frame_rate_hz = {:g} Hz) are wrong",
        fall.accel_m_s2, fall.se_m_s2, fall.n_frames, o.frame_rate_hz);
  // A declared rate f reads a true f0 as a = g (f / f0)^2.
  const double free_rate_hz = o.frame_rate_hz * std::sqrt(g / fall.accel_m_s2);
  return fmt::format(
      "video: the impactor falls at {:.2f} +- {:.2f} m/s^2 before contact ({} frames over {:.0f} ms), {:+.1f} % from "
      "gravity {:.3f} m/s^2: the video's time base, its length scale or gravity is wrong ([video] frame_rate_hz = "
      "{:g} Hz would have to be {:.0f} Hz for a free fall; a calibration scale of {:.3f}; or [session] gravity_m_s2), "
      "and the impact velocity with it",
      fall.accel_m_s2, fall.se_m_s2, fall.n_frames, 1e3 * fall.span_s, 100.0 * (fall.accel_m_s2 / g - 1.0), g,
      o.frame_rate_hz, free_rate_hz, fall.accel_m_s2 / g);
}

}  // namespace dropfit::trial
