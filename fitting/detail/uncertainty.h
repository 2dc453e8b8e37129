#pragma once
// The fitter's uncertainty (internal to fitting/): the error budget at the
// optimum (fitting/error_budget.h: AR(1) noise per channel, the inputs as
// nuisance parameters with priors), standard errors, 95 % intervals and
// identifiability of the parameters, the predictions' 95 % intervals, and
// the sensitivity of the peak force to each stiffness and damping.
#include <Eigen/Core>
#include <string>
#include <vector>

#include "fitting/detail/objective.h"
#include "fitting/detail/search.h"
#include "fitting/detail/space.h"
#include "fitting/error_budget.h"
#include "fitting/fit.h"

namespace dropfit::fitting::internal {

// The inputs' errors as nuisance parameters with priors (fit.h: error
// budget), linearised at the optimum: K = how the (weighted) residuals move
// per unit of each, P their prior covariance.
struct Nuisances {
  Eigen::MatrixXd K, P;
  int scale = -1;             // column of the calibration's scale error, -1: none
  std::vector<int> velocity;  // per prepared trial: its velocity column, -1: none
};

Nuisances nuisance_columns(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                           const MatParams& mp, const std::vector<double>& shifts, Eigen::Index n_res);

// The error budget at the optimum: each prepared trial's force and travel
// residuals as two AR(1) blocks, the nuisances with their priors. Empty
// when the optimum carries no Jacobian.
ErrorBudget budget_at(const std::vector<Prepared>& preps, const Optimum& opt, const Nuisances& nz);

// Standard errors, 95 % intervals and identifiability of the parameters
// from the error budget (coordinates: model parameters first, then the
// fitted clock shifts); the shifts' standard errors go to `shift_se`.
void covariance(const Optimum& opt, const ParamSpace& space, const FitOptions& o, const MatParams& mp,
                const ErrorBudget& budget, std::vector<ParameterEstimate>* est, std::vector<double>* shift_se,
                std::vector<std::string>* warnings);

// A channel above its noise: every free parameter marked model_limited, and
// a warning saying so (its interval holds that residual, see fit.h).
void mark_model_limited(FitResult* res);

// Every reported trial's predicted peak force, time to peak, largest travel
// and force-time band with 95 % intervals (parameters, the trial's own
// velocity, the session's scale), and its offset's SE with the video
// contact instant's own error.
void add_prediction_intervals(const std::vector<TrialData>& trials, const std::vector<Prepared>& preps,
                              const ParamSpace& space, const FitOptions& o, const Eigen::VectorXd& u,
                              const ErrorBudget& budget, const Nuisances& nz, FitResult* res);

// The model the options name (or their custom simulator) on `imp`'s samples.
Simulation simulate_model(const FitOptions& o, const MatParams& mp, const Impact& imp);

// Sensitivity of the peak force to -10 % / +10 % on each stiffness and damping.
std::vector<SensitivityEntry> sensitivity_table(const FitOptions& o, const MatParams& mp, const Impact& imp);

}  // namespace dropfit::fitting::internal
