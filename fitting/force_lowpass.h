#pragma once
// A force channel's 2nd-order Butterworth low-pass (a charge amplifier's
// anti-alias filter) applied to a model's plate force, so that the model
// predicts what the plate records rather than what the mat does:
//   z'' = w^2 (u - z) - sqrt(2) w z',   w = 2 pi corner,
// u the mat's force, z the recorded one, both at rest (zero) before the
// contact. At low frequency it is a pure delay of sqrt(2) / w (0.225 ms x
// 1 kHz / corner); its phase departs from a delay in the third order of
// frequency and its gain in the fourth, and that departure is all that
// tells a filter from a clock offset.
//
// Exact discretisation on the simulation grid (step h from the contact):
// between grid values the force is the Catmull-Rom cubic the fitter
// interpolates it with (detail/objective.h on_grid), and the filter's state
// is carried across each step exactly for that cubic input:
//   x(h) = Phi x(0) + sum_j c_j G_j,  u(s h) = sum_j c_j s^j,
//   G_j = int_0^h e^{A (h - tau)} B (tau / h)^j dtau,
// the G_j by the recursion of integration by parts,
//   Psi_0 = A^-1 (Phi - I),  Psi_j = A^-1 (j / h Psi_{j-1} - I),  G_j = Psi_j B.
// Coefficients are doubles (the corner is profiled, not fitted by the
// optimiser); the force may be any scalar type (ceres::Jet included).
#include <Eigen/Core>
#include <Eigen/LU>
#include <cmath>
#include <numbers>
#include <vector>

namespace dropfit::fitting {

// The filter's step matrices for grid step h (s) and corner (Hz).
struct LowpassStep {
  Eigen::Matrix2d phi;
  Eigen::Matrix<double, 2, 4> g;  // columns G_0 .. G_3
};

inline LowpassStep lowpass_step(double h_s, double corner_hz) {
  const double w = 2.0 * std::numbers::pi * corner_hz;
  const double zeta = std::sqrt(0.5), sigma = zeta * w, wd = w * std::sqrt(1.0 - zeta * zeta);
  Eigen::Matrix2d a;
  a << 0.0, 1.0, -w * w, -2.0 * zeta * w;
  // e^{A h} for the underdamped pair -sigma +- i wd.
  const Eigen::Matrix2d sh = a + sigma * Eigen::Matrix2d::Identity();
  LowpassStep out;
  out.phi = std::exp(-sigma * h_s) * (std::cos(wd * h_s) * Eigen::Matrix2d::Identity() + std::sin(wd * h_s) / wd * sh);
  const Eigen::Matrix2d ainv = a.inverse(), eye = Eigen::Matrix2d::Identity();
  const Eigen::Vector2d b(0.0, w * w);
  Eigen::Matrix2d psi = ainv * (out.phi - eye);
  out.g.col(0) = psi * b;
  for (int j = 1; j < 4; ++j) {
    psi = ainv * (psi * (static_cast<double>(j) / h_s) - eye);
    out.g.col(j) = psi * b;
  }
  return out;
}

// The force on the grid (y[i] at i h from the contact, zero before it)
// replaced by what the filter passes; corner <= 0 leaves it unchanged.
template <typename T>
void force_lowpass(std::vector<T>& y, double h_s, double corner_hz) {
  const int n = static_cast<int>(y.size());
  if (!(corner_hz > 0.0) || n < 2) return;
  const LowpassStep st = lowpass_step(h_s, corner_hz);
  const std::vector<T> u = y;
  T x0 = T(0.0), x1 = T(0.0);
  y[0] = x0;
  for (int i = 0; i + 1 < n; ++i) {
    // The Catmull-Rom cubic on [i, i + 1], as on_grid interpolates it.
    const T um = i > 0 ? u[i - 1] : T(0.0), u0 = u[i], u1 = u[i + 1];
    const T u2 = i + 2 < n ? u[i + 2] : T(2.0) * u1 - u0;
    const T c[4] = {u0, T(0.5) * (u1 - um), T(0.5) * (T(2.0) * um - T(5.0) * u0 + T(4.0) * u1 - u2),
                    T(0.5) * (T(-1.0) * um + T(3.0) * u0 - T(3.0) * u1 + u2)};
    T n0 = x0 * st.phi(0, 0) + x1 * st.phi(0, 1), n1 = x0 * st.phi(1, 0) + x1 * st.phi(1, 1);
    for (int j = 0; j < 4; ++j) {
      n0 += c[j] * st.g(0, j);
      n1 += c[j] * st.g(1, j);
    }
    x0 = n0;
    x1 = n1;
    y[i + 1] = x0;
  }
}

// The filter's group delay at low frequency (s): sqrt(2) / (2 pi corner).
inline double lowpass_delay_s(double corner_hz) { return std::sqrt(2.0) / (2.0 * std::numbers::pi * corner_hz); }

}  // namespace dropfit::fitting
