#pragma once
// The fitter's search (internal to fitting/): Levenberg-Marquardt (Ceres)
// from the screened starts, followed in chunks while they stay in reach of
// the best, or simulated annealing.
#include <Eigen/Core>
#include <atomic>
#include <limits>
#include <string>
#include <vector>

#include "fitting/detail/objective.h"
#include "fitting/detail/space.h"
#include "fitting/fit.h"

namespace dropfit::fitting::internal {

struct Optimum {
  Eigen::VectorXd u;
  std::vector<double> shifts;  // per prepared trial
  double cost = std::numeric_limits<double>::infinity();
  bool converged = false;    // Ceres stopped on a tolerance, not on the iteration limit
  double radius = 0.0;       // the trust region's radius at the end (0: Ceres' default start)
  Eigen::MatrixXd jacobian;  // at u: residuals x (parameters, then the fitted shifts)
  Eigen::VectorXd residuals;
};

struct Search {
  Optimum best;
  std::vector<Optimum> others;  // every other converged run
};

// Levenberg-Marquardt from u0 (shifts profiled at u0 to start, unless
// given; radius0 > 0: the trust region a continued run keeps; hold >= 0:
// that coordinate stays at u0's value, the others are fitted: a point of
// its profile likelihood).
Optimum run_ceres(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                  const Eigen::VectorXd& u0, std::atomic<long>* evals, bool want_jacobian,
                  const std::vector<double>* shifts0 = nullptr, double radius0 = 0.0, int hold = -1);

// Multi-start: every candidate screened by cost; Levenberg-Marquardt from
// the best candidate of each spring ordering and the best overall, in
// parallel (or annealing, as the options say). `used` names the optimiser.
Search optimise(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o, double k_eff,
                std::atomic<long>* evals, std::vector<std::string>* warnings, std::string* used);

}  // namespace dropfit::fitting::internal
