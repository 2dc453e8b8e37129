#pragma once
// The covariance of a least-squares estimate when the residuals are not the
// independent, unit-variance noise the weights assume (numeric core of the
// fitter's uncertainty; plain Eigen in and out).
//
// The fit minimises |r(u)|^2 over u with the inputs (impact velocities,
// contact instants, the travel reference, the calibration's scale) held at
// their measured values. Linearised at the optimum, the estimate's error is
//   u_hat - u_true = B J^T (e + K eta),   B = (J^T J)^-1,
// where e is the noise as it is and eta the inputs' errors (nuisance
// parameters with priors: zero mean, covariance P from their own
// measurements), K = d r / d eta. So
//   cov(u_hat) = B J^T (S + K P K^T) J B,
// a sandwich whose meat holds both:
// - Noise as it is: S is block diagonal, one block per channel of a trial
//   (consecutive residuals in time), each an AR(1) process fitted to that
//   block's own residuals at the optimum: variance sigma_b^2 (the block's
//   mean square, scaled by N / (N - p) for the fitted parameters) and lag-1
//   correlation phi_b. A channel whose residual stays above its noise (model
//   discrepancy: rms > 1 noise SD, correlated) widens the interval by what
//   that residual implies instead of being averaged away as white noise.
// - The inputs: K P K^T, low rank (a few nuisances per trial).
// The noise-only covariance (S alone, the white-noise s^2 (J^T J)^-1 of a
// textbook fit when every phi is 0) is returned for comparison, and the
// cross-covariance of u_hat with eta (B J^T K P) for predictions that share
// an input with the fit (a held-out trial measured through the same
// calibration).
#include <Eigen/Core>
#include <vector>

namespace dropfit::fitting {

struct ResidualBlock {
  int first = 0;  // index of the block's first residual
  int count = 0;  // consecutive residuals, in time order
};

struct BlockNoise {
  double sigma = 0.0;  // residual SD in the weights' units (1 = the measured noise)
  double phi = 0.0;    // lag-1 autocorrelation, clamped to [-0.5, 0.98]
};

struct ErrorBudget {
  Eigen::MatrixXd covariance;        // of the fitted coordinates: noise as it is and the inputs
  Eigen::MatrixXd noise_covariance;  // the noise alone (AR blocks)
  Eigen::MatrixXd white_covariance;  // s^2 (J^T J)^-1: the textbook white-noise covariance
  Eigen::MatrixXd nuisance_cross;    // cov(u_hat, eta): fitted x nuisance
  std::vector<BlockNoise> blocks;    // per block, as given
  Eigen::VectorXd eigenvalues;       // of the column-scaled J^T J (ascending)
  Eigen::MatrixXd eigenvectors;      // columns, in the fitted coordinates' order
  std::vector<bool> lost;            // coordinates in a direction the data do not constrain
};

// J: residuals x fitted coordinates; r: the residuals at the optimum;
// blocks: a partition of the residuals (those outside every block are
// taken as white with the overall variance); K: residuals x nuisances (0
// columns: none); P: the nuisances' prior covariance. Directions of J^T J
// with eigenvalue below 1e-14 of the largest (after scaling the columns to
// unit norm) are dropped from the inverse; a coordinate with weight on one
// is `lost` (its variance is not defined).
ErrorBudget error_budget(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, const std::vector<ResidualBlock>& blocks,
                         const Eigen::MatrixXd& K, const Eigen::MatrixXd& P);

}  // namespace dropfit::fitting
