#pragma once
// Simulated annealing for continuous, bounded minimisation, as Corana,
// Marchesi, Martini & Ridella (1987), "Minimizing multimodal functions of
// continuous variables with the simulated annealing algorithm", ACM TOMS
// 13:262, and as Mills, Pain & Yeadon (2006) used it to fit their mat
// models:
//   - one coordinate at a time: x_h' = x_h + (2u - 1) VM_h; a trial point
//     outside the bounds is drawn uniformly within them;
//   - Metropolis acceptance of an uphill move with probability exp(-df / T);
//   - after NS cycles over the coordinates, each step VM_h is adapted to
//     its acceptance ratio r_h: r > 0.6: VM *= 1 + c (r - 0.6) / 0.4;
//     r < 0.4: VM /= 1 + c (0.4 - r) / 0.4; VM at most the bound width;
//   - after NT step adjustments, T *= RT and the walk restarts from the best
//     point; stop when the last NEPS end-of-temperature values and the best
//     agree within EPS (relative to the best value).
// Deterministic for a given seed.
#include <Eigen/Core>
#include <cstdint>
#include <functional>

namespace dropfit::fitting {

struct AnnealOptions {
  double initial_temperature = -1.0;  // <= 0: from the spread of f over random points in the bounds
  double rt = 0.85;                   // temperature reduction factor
  int ns = 20;                        // cycles between step adjustments
  int nt = -1;                        // step adjustments per temperature; <= 0: max(100, 5 n)
  double eps = 1e-7;                  // relative tolerance of the stopping test
  int neps = 4;                       // end-of-temperature values compared
  double c = 2.0;                     // step adaptation factor
  long max_evaluations = 2000000;
  std::uint64_t seed = 12345;
};

struct AnnealResult {
  Eigen::VectorXd x;
  double f = 0.0;
  long evaluations = 0;
  int temperatures = 0;
  bool converged = false;  // false: stopped by max_evaluations
};

// Minimises f over lower <= x <= upper from x0 (clamped into the bounds).
// Throws Error if the bounds are inconsistent or f(x0) is not finite.
// Non-finite f at a trial point counts as +infinity (never accepted).
AnnealResult anneal(const std::function<double(const Eigen::VectorXd&)>& f, const Eigen::VectorXd& x0,
                    const Eigen::VectorXd& lower, const Eigen::VectorXd& upper,
                    const AnnealOptions& options = {});

}  // namespace dropfit::fitting
