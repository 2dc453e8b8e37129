#pragma once
// The fitter's uncertainty (internal to fitting/): covariance from the
// Jacobian at the optimum, standard errors and identifiability, and the
// sensitivity of the peak force to each stiffness and damping.
#include <string>
#include <vector>

#include "fitting/detail/search.h"
#include "fitting/detail/space.h"
#include "fitting/fit.h"

namespace dropfit::fitting::internal {

// Covariance from the Jacobian (model parameters first, then the fitted
// clock shifts): standard errors and identifiability of the parameters;
// the shifts' standard errors go to `shift_se`.
void covariance(const Optimum& opt, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                std::vector<ParameterEstimate>* est, std::vector<double>* shift_se,
                std::vector<std::string>* warnings);

// The model the options name (or their custom simulator) on `imp`'s samples.
Simulation simulate_model(const FitOptions& o, const MatParams& mp, const Impact& imp);

// Sensitivity of the peak force to -10 % / +10 % on each stiffness and damping.
std::vector<SensitivityEntry> sensitivity_table(const FitOptions& o, const MatParams& mp, const Impact& imp);

}  // namespace dropfit::fitting::internal
