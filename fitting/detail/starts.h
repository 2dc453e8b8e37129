#pragma once
// The fitter's starts (internal to fitting/): a start from the data, every
// ordering of the series springs, and quasi-random points over the box.
#include <Eigen/Core>
#include <vector>

#include "fitting/detail/space.h"
#include "fitting/fit.h"

namespace dropfit::fitting::internal {

// Which spring is softest, middle, stiffest: the basin label of a start.
int ordering_of(const ParamSpace& space, const Eigen::VectorXd& u);

// Starts: the given one, the data guess, every ordering of the series
// springs at two spreads and two damping levels, and quasi-random points
// over the whole box (log space).
std::vector<Eigen::VectorXd> candidate_starts(const ParamSpace& space, const FitOptions& o, double k_eff,
                                              const TrialData& first);

}  // namespace dropfit::fitting::internal
