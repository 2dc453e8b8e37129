// The sandwich covariance (fitting/error_budget.h) against Monte Carlo on a
// straight-line fit whose noise and inputs are known.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <Eigen/QR>

#include "fitting/error_budget.h"

namespace {

using dropfit::fitting::error_budget;
using dropfit::fitting::ResidualBlock;

// y_i = a + b x_i + e_i, e an AR(1) process (phi, innovation SD chosen so
// that e has SD 1); returns the least-squares (a, b) and its residuals.
struct LineFit {
  Eigen::Vector2d u;
  Eigen::VectorXd r;
};

LineFit fit_line(const Eigen::MatrixXd& J, const Eigen::VectorXd& y) {
  LineFit f;
  f.u = J.colPivHouseholderQr().solve(y);
  f.r = J * f.u - y;
  return f;
}

Eigen::MatrixXd design(int n) {
  Eigen::MatrixXd J(n, 2);
  for (int i = 0; i < n; ++i) J(i, 0) = 1.0, J(i, 1) = static_cast<double>(i) / n;
  return J;
}

Eigen::VectorXd ar1(int n, double phi, std::mt19937_64& rng) {
  std::normal_distribution<double> z(0.0, 1.0);
  Eigen::VectorXd e(n);
  e[0] = z(rng);
  for (int i = 1; i < n; ++i) e[i] = phi * e[i - 1] + std::sqrt(1.0 - phi * phi) * z(rng);
  return e;
}

// With AR(1) noise of phi 0.6 the white-noise SE of the slope is too small
// by about sqrt((1 + phi) / (1 - phi)) = 2; the AR sandwich's matches the
// spread over 2000 draws within 10 % (the AR fit's own scatter on 200
// residuals is a few per cent).
TEST(ErrorBudget, CorrelatedNoiseSandwichMatchesMonteCarlo) {
  const int n = 200, draws = 2000;
  const Eigen::MatrixXd J = design(n);
  std::mt19937_64 rng(11);
  double sum_b = 0.0, sum_b2 = 0.0, sum_se2 = 0.0, sum_white2 = 0.0;
  for (int d = 0; d < draws; ++d) {
    const LineFit f = fit_line(J, ar1(n, 0.6, rng));
    const auto b = error_budget(J, f.r, {ResidualBlock{0, n}}, Eigen::MatrixXd(n, 0), Eigen::MatrixXd());
    sum_b += f.u[1];
    sum_b2 += f.u[1] * f.u[1];
    sum_se2 += b.covariance(1, 1);
    sum_white2 += b.white_covariance(1, 1);
  }
  const double sd = std::sqrt(sum_b2 / draws - (sum_b / draws) * (sum_b / draws));
  const double se = std::sqrt(sum_se2 / draws), white = std::sqrt(sum_white2 / draws);
  EXPECT_NEAR(se / sd, 1.0, 0.10);
  EXPECT_NEAR(white / sd, 0.5, 0.07);  // the textbook SE: half the truth
}

// An input error common to all residuals (a nuisance with prior SD 0.3
// moving every y by x_i times it: a scale error of the abscissa) widens the
// slope's SE by its propagated share: sqrt(white^2 + 0.3^2) for a slope of
// 1 per unit scale; and the cross-covariance with the nuisance is that
// share.
TEST(ErrorBudget, NuisancePropagatesIntoTheSlope) {
  const int n = 100, draws = 3000;
  const Eigen::MatrixXd J = design(n);
  Eigen::MatrixXd K(n, 1);
  // The data move by x eta: at the true line and eta = 0 the residual is
  // -(e + K eta) (error_budget.h's convention), so K = x.
  K.col(0) = J.col(1);
  Eigen::MatrixXd P(1, 1);
  P(0, 0) = 0.3 * 0.3;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> z(0.0, 1.0);
  double sum_b2 = 0.0, sum_se2 = 0.0, sum_cross = 0.0;
  for (int d = 0; d < draws; ++d) {
    const double eta = 0.3 * z(rng);
    Eigen::VectorXd y = ar1(n, 0.0, rng) + eta * J.col(1);
    const LineFit f = fit_line(J, y);
    const auto b = error_budget(J, f.r, {ResidualBlock{0, n}}, K, P);
    sum_b2 += f.u[1] * f.u[1];
    sum_se2 += b.covariance(1, 1);
    sum_cross += b.nuisance_cross(1, 0);
  }
  const double sd = std::sqrt(sum_b2 / draws), se = std::sqrt(sum_se2 / draws);
  EXPECT_NEAR(se / sd, 1.0, 0.06);
  EXPECT_NEAR(sum_cross / draws, 0.09, 0.005);  // cov(b_hat, eta) = 0.3^2
}

// A coordinate the data cannot see (a zero column) is reported lost.
TEST(ErrorBudget, UnseenCoordinateIsLost) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(10, 2);
  J.col(0).setOnes();
  Eigen::VectorXd r = Eigen::VectorXd::LinSpaced(10, -1.0, 1.0);
  const auto b = error_budget(J, r, {}, Eigen::MatrixXd(10, 0), Eigen::MatrixXd());
  EXPECT_FALSE(b.lost[0]);
  EXPECT_TRUE(b.lost[1]);
}

}  // namespace
