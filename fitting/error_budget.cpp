// The sandwich covariance of fitting/error_budget.h.
#include "fitting/error_budget.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace dropfit::fitting {

namespace {

// The AR(1) part of J^T S J for one block: sigma^2 sum_l phi^l (sum_i
// J_i J_{i+l}^T + its transpose), lags until phi^l is negligible.
void add_ar_block(const Eigen::MatrixXd& J, const ResidualBlock& b, const BlockNoise& noise, Eigen::MatrixXd* meat) {
  const auto rows = J.middleRows(b.first, b.count);
  const double s2 = noise.sigma * noise.sigma;
  *meat += s2 * rows.transpose() * rows;
  double w = 1.0;
  for (int lag = 1; lag < b.count; ++lag) {
    w *= noise.phi;
    if (std::abs(w) < 1e-4) break;
    const Eigen::MatrixXd c = rows.topRows(b.count - lag).transpose() * rows.bottomRows(b.count - lag);
    *meat += s2 * w * (c + c.transpose());
  }
}

}  // namespace

ErrorBudget error_budget(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, const std::vector<ResidualBlock>& blocks,
                         const Eigen::MatrixXd& K, const Eigen::MatrixXd& P) {
  ErrorBudget out;
  const int n = static_cast<int>(J.cols());
  const Eigen::Index m = J.rows();
  // The bread: (J^T J)^-1 with the columns scaled to unit norm, so that the
  // dropped directions reflect correlation rather than units.
  Eigen::VectorXd colnorm = J.colwise().norm().transpose();
  for (int j = 0; j < n; ++j)
    if (!(colnorm[j] > 0.0)) colnorm[j] = 1.0;
  const Eigen::MatrixXd Js = J * colnorm.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Js.transpose() * Js);
  out.eigenvalues = es.eigenvalues();
  out.eigenvectors = es.eigenvectors();
  const double evmax = n > 0 ? out.eigenvalues.maxCoeff() : 0.0;
  Eigen::MatrixXd inv = Eigen::MatrixXd::Zero(n, n);
  out.lost.assign(n, false);
  for (int i = 0; i < n; ++i) {
    const double lam = out.eigenvalues[i];
    if (lam > 1e-14 * evmax) {
      inv += out.eigenvectors.col(i) * out.eigenvectors.col(i).transpose() / lam;
    } else {
      for (int j = 0; j < n; ++j)
        if (std::abs(out.eigenvectors(j, i)) > 0.1) out.lost[j] = true;
    }
  }
  const Eigen::MatrixXd B = colnorm.cwiseInverse().asDiagonal() * inv * colnorm.cwiseInverse().asDiagonal();

  // The noise: each block an AR(1) fitted to its own residuals; the
  // variances carry the degrees of freedom the fit used (N / (N - p)).
  const double dof_scale = m > n ? static_cast<double>(m) / static_cast<double>(m - n) : 1.0;
  Eigen::MatrixXd meat = Eigen::MatrixXd::Zero(n, n);
  std::vector<char> covered(static_cast<size_t>(m), 0);
  for (const ResidualBlock& b : blocks) {
    BlockNoise noise;
    if (b.count > 0) {
      const auto seg = r.segment(b.first, b.count);
      const double ss = seg.squaredNorm();
      noise.sigma = std::sqrt(dof_scale * ss / b.count);
      if (b.count > 2 && ss > 0.0) {
        const double lag = seg.head(b.count - 1).dot(seg.tail(b.count - 1));
        noise.phi = std::clamp(lag / ss, -0.5, 0.98);
      }
      add_ar_block(J, b, noise, &meat);
      for (int i = 0; i < b.count; ++i) covered[static_cast<size_t>(b.first + i)] = 1;
    }
    out.blocks.push_back(noise);
  }
  // Residuals outside every block: white, with the overall variance.
  const double s2 = m > n ? r.squaredNorm() / static_cast<double>(m - n) : 0.0;
  for (Eigen::Index i = 0; i < m; ++i)
    if (!covered[static_cast<size_t>(i)]) meat += s2 * J.row(i).transpose() * J.row(i);

  out.noise_covariance = B * meat * B;
  out.white_covariance = s2 * B;
  out.covariance = out.noise_covariance;
  if (K.cols() > 0 && K.rows() == m) {
    const Eigen::MatrixXd JtK = J.transpose() * K;
    out.nuisance_cross = B * JtK * P;
    out.covariance += B * JtK * P * JtK.transpose() * B;
  } else {
    out.nuisance_cross = Eigen::MatrixXd::Zero(n, 0);
  }
  return out;
}

}  // namespace dropfit::fitting
