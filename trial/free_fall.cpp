// The face's free fall before contact (trial.h): the fit with gravity known
// that gives the impact velocity and the video's contact instant, and the
// fit with the acceleration free that checks the video's time base and
// length scale against gravity. Both are one robust polynomial least squares.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <boost/math/distributions/students_t.hpp>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "trial/trial.h"

namespace dropfit::trial {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

struct PolyFit {
  Eigen::VectorXd coef;     // y = sum_k coef[k] tau^k
  Eigen::MatrixXd xtx_inv;  // (X'X)^-1
  double rss = 0.0;
  int n = 0;                // points used
};

// Least squares of y = sum_{k <= degree} c_k tau^k over the flagged points;
// none with fewer than degree + 2 points or a singular normal matrix.
std::optional<PolyFit> poly_fit(const std::vector<double>& tau, const std::vector<double>& y,
                                const std::vector<char>& use, int degree) {
  const int m = degree + 1;
  Eigen::MatrixXd xtx = Eigen::MatrixXd::Zero(m, m);
  Eigen::VectorXd xty = Eigen::VectorXd::Zero(m), x(m);
  int n = 0;
  for (std::size_t i = 0; i < tau.size(); ++i) {
    if (!use[i]) continue;
    for (int k = 0; k < m; ++k) x[k] = k == 0 ? 1.0 : x[k - 1] * tau[i];
    xtx += x * x.transpose();
    xty += x * y[i];
    ++n;
  }
  if (n < m + 1) return std::nullopt;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(xtx);
  if (ldlt.info() != Eigen::Success || !(ldlt.rcond() > 1e-14)) return std::nullopt;
  PolyFit f;
  f.coef = ldlt.solve(xty);
  f.xtx_inv = ldlt.solve(Eigen::MatrixXd::Identity(m, m));
  f.n = n;
  for (std::size_t i = 0; i < tau.size(); ++i) {
    if (!use[i]) continue;
    double p = 0.0;
    for (int k = m - 1; k >= 0; --k) p = p * tau[i] + f.coef[k];
    f.rss += (y[i] - p) * (y[i] - p);
  }
  return f;
}

// The fit, then one pass dropping residuals beyond 4 robust SDs
// (misdigitised frames) and the refit.
std::optional<PolyFit> robust_poly_fit(const std::vector<double>& tau, const std::vector<double>& y, int degree) {
  const std::size_t n = tau.size();
  std::vector<char> use(n, 1);
  std::optional<PolyFit> fit = poly_fit(tau, y, use, degree);
  if (!fit) return fit;
  std::vector<double> r(n), absr(n);
  for (std::size_t i = 0; i < n; ++i) {
    double p = 0.0;
    for (int k = degree; k >= 0; --k) p = p * tau[i] + fit->coef[k];
    r[i] = y[i] - p;
    absr[i] = std::abs(r[i]);
  }
  std::nth_element(absr.begin(), absr.begin() + static_cast<std::ptrdiff_t>(n / 2), absr.end());
  const double sigma = std::max(1.4826 * absr[n / 2], 1e-6);
  bool dropped = false;
  for (std::size_t i = 0; i < n; ++i)
    if (std::abs(r[i]) > 4.0 * sigma) use[i] = 0, dropped = true;
  return dropped ? poly_fit(tau, y, use, degree) : fit;
}

}  // namespace

double FreeFallFit::height_at(double t_s, double gravity_m_s2) const {
  const double tau = t_s - t_ref_s;
  return z_ref_m + v_ref_m_s * tau - 0.5 * gravity_m_s2 * tau * tau;
}

FreeFallFit fit_free_fall(const Eigen::VectorXd& t_s, const Eigen::VectorXd& z_m, double gravity_m_s2,
                          double contact_height_m, double t_ref_s) {
  FreeFallFit out;
  out.t_ref_s = t_ref_s;
  const std::size_t n = static_cast<std::size_t>(t_s.size());
  // Gravity known: z + g tau^2 / 2 is a line in tau.
  std::vector<double> tau(n), y(n);
  for (std::size_t i = 0; i < n; ++i) {
    tau[i] = t_s[static_cast<Eigen::Index>(i)] - t_ref_s;
    y[i] = z_m[static_cast<Eigen::Index>(i)] + 0.5 * gravity_m_s2 * tau[i] * tau[i];
  }
  const std::optional<PolyFit> fit = robust_poly_fit(tau, y, 1);
  if (!fit) return out;
  const int used = fit->n;
  out.n_frames = used;
  out.z_ref_m = fit->coef[0];
  out.v_ref_m_s = fit->coef[1];
  const double s2 = fit->rss / (used - 2);
  out.rms_m = std::sqrt(fit->rss / used);
  out.covariance = s2 * fit->xtx_inv;

  // Arrival at the contact height: the descending root of
  // z0 + v0 tau - g tau^2 / 2 = H, tau = 2 (H - z0) / (v0 - s), s = sqrt(v0^2 - 2 g (H - z0)).
  const double z0 = out.z_ref_m, v0 = out.v_ref_m_s;
  const double disc = v0 * v0 - 2.0 * gravity_m_s2 * (contact_height_m - z0);
  if (!(disc > 0.0)) return out;
  const double s = std::sqrt(disc);
  if (!(v0 - s < 0.0)) return out;
  out.contact_time_s = t_ref_s + 2.0 * (contact_height_m - z0) / (v0 - s);
  out.contact_speed_m_s = s;
  const Eigen::Vector2d grad(gravity_m_s2 / s, v0 / s);
  const double var = grad.dot(out.covariance * grad);
  out.contact_speed_ci_m_s = student_t_quantile(0.975, used - 2) * std::sqrt(std::max(var, 0.0));
  // The arrival tau solves z0 + v0 tau - g tau^2 / 2 = H where the face
  // descends at s: d tau / d z0 = 1 / s, d tau / d v0 = tau / s.
  const double arrival = out.contact_time_s - t_ref_s;
  const Eigen::Vector2d grad_t(1.0 / s, arrival / s);
  out.contact_speed_se_m_s = std::sqrt(std::max(var, 0.0));
  out.contact_time_se_s = std::sqrt(std::max(grad_t.dot(out.covariance * grad_t), 0.0));
  out.speed_time_cov = grad.dot(out.covariance * grad_t);
  out.ok = true;
  return out;
}

double student_t_quantile(double p, double dof) {
  if (!(p > 0.0 && p < 1.0) || !(dof > 0.0)) return kNaN;
  return boost::math::quantile(boost::math::students_t(dof), p);
}

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
  const std::optional<PolyFit> q = robust_poly_fit(tau, z, 2);
  if (!q) return out;
  const double s2 = q->rss / std::max(q->n - 3, 1);
  const auto [lo, hi] = std::minmax_element(tau.begin(), tau.end());
  out.ok = true;
  out.n_frames = q->n;
  out.span_s = *hi - *lo;
  // z = c0 + c1 tau + c2 tau^2 falls at a = -2 c2.
  out.accel_m_s2 = -2.0 * q->coef[2];
  out.se_m_s2 = 2.0 * std::sqrt(std::max(s2 * q->xtx_inv(2, 2), 0.0));
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

std::pair<double, double> airborne_stretch_s(const Eigen::VectorXd& h, double top_m, double contact_frame,
                                             double frame_rate_hz, int trigger_frame, double offset_s,
                                             double gravity_m_s2) {
  constexpr double kSettle_s = 0.050, kAbove_m = 0.005, kMin_s = 0.050;
  const int nf = static_cast<int>(h.size());
  auto time = [&](int frame) { return (frame - trigger_frame) / frame_rate_hz; };
  int i = std::max(0, static_cast<int>(std::ceil(contact_frame))) + 1;
  while (i < nf && !(std::isfinite(h[i]) && h[i] >= top_m + kAbove_m)) ++i;
  if (i >= nf) return {kNaN, kNaN};
  const double leave_s = time(i);
  // z + g u^2 / 2 = z0 + v_up u over the frames in the air (u from leaving).
  std::vector<double> u, y;
  for (; i < nf && !(std::isfinite(h[i]) && h[i] < top_m + kAbove_m); ++i) {
    if (!std::isfinite(h[i])) continue;
    u.push_back(time(i) - leave_s);
    y.push_back(h[i] + 0.5 * gravity_m_s2 * u.back() * u.back());
  }
  if (u.size() < 10) return {kNaN, kNaN};
  const std::optional<PolyFit> fit = poly_fit(u, y, std::vector<char>(u.size(), 1), 1);
  if (!fit) return {kNaN, kNaN};
  const double v_up = fit->coef[1];
  const double from = leave_s + kSettle_s - offset_s, to = leave_s + 0.9 * 2.0 * v_up / gravity_m_s2 - offset_s;
  if (!(to - from >= kMin_s)) return {kNaN, kNaN};
  return {from, to};
}

}  // namespace dropfit::trial
