#pragma once
// Fitting the mat models (fitting/models.h) to drop-test trials, as Mills,
// Pain & Yeadon (2006) did and a little further:
//
// Objective (least squares over every training trial's contact window):
//   force:    w_t (F_sim - F_meas) / force_noise_n,   w_t = loading_weight
//             up to the measured peak, 1 after it;
//   impactor: kinematics_weight (y_sim - y_meas) / marker_noise_m wherever
//             the impactor's face travel was measured (NaN = gap);
//   surface:  the paper's penalty: surface_weight max(|s_sim - s_meas| -
//             surface_tolerance_m, 0) / marker_noise_m (zero inside the 1 cm
//             band), or, with surface_as_residual, a plain residual like the
//             impactor's. The simulated surface is Simulation::surface_m.
// Force alone does not identify Models 3-4 (the springs in series trade
// places), which is why the impactor's travel is in by default; the result
// lists the parameters the data still do not pin down.
//
// Parameters: stiffness and damping are fitted as logarithms (bounded); the
// layer masses are fixed to the manifest, or free with their total fixed
// (fitted as the top layer's fraction, as the paper's re-optimisation);
// Model 2's m_eff is free in [0, total layer mass] unless fixed.
// Optimisers: Ceres (Levenberg-Marquardt, automatic differentiation through
// the templated simulation, multi-start from quasi-random points in
// physically sensible ranges) or simulated annealing (Corana et al. 1987,
// fitting/anneal.h) on the same objective. Model 5 (or any model given as a
// simulate callback) is fitted with central numeric differences.
//
// Uncertainty: J^T J at the optimum, inverted and scaled by the residual
// variance (RSS / (N - p)); standard errors of log-parameters are relative
// standard errors. Residuals of a time series are correlated, so these are
// optimistic; held-out trials are the stronger test.
//
// Validation: the fitted parameters predict every trial from its own
// impact velocity; key characteristics (fitting/characteristics.h) for
// measured and simulated curves; optional leave-one-trial-out; sensitivity
// of the peak force to +-10 % on each stiffness and damping.
//
// Table mode: when only per-trial summaries exist (velocity, maximum
// deformation, peak force: the paper's Table 1), fit_table matches the
// simulated peak force and maximum impactor travel.
#include <Eigen/Core>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "fitting/anneal.h"
#include "fitting/characteristics.h"
#include "fitting/models.h"

namespace dropfit::fitting {

// One trial as the fitter needs it. Times from first contact, uniformly
// spaced (the force plate's clock); samples before contact (t < 0) are
// ignored.
struct TrialData {
  std::string id;
  bool accepted = true;
  double impact_velocity_m_s = 0.0;  // downward
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  Eigen::VectorXd t_s;
  Eigen::VectorXd grf_n;             // measured ground reaction force (zeroed plate)
  Eigen::VectorXd impactor_m;        // optional: impactor face travel below first contact, NaN gaps
  Eigen::VectorXd surface_m;         // optional: mat top-surface travel, NaN gaps
};

// A custom simulator (Model 5, or a user's own); the fitter asks it for the
// samples of Impact (first_output_s, output_dt_s, duration_s).
using Simulator = std::function<Simulation(const MatParams&, const Impact&)>;

enum class Optimizer { Ceres, Annealing };

struct FitOptions {
  ModelKind model = ModelKind::Model4;
  Simulator simulator;                // required for Model 5; optional override otherwise

  // Which trials train: ids; empty = the accepted trial with the median
  // impact velocity. Several ids = a joint fit.
  std::vector<std::string> train_ids;

  // Mat masses: the manifest's layers, top (stiff, incl. carpet) and bottom.
  double m1_kg = 2.44, m2_kg = 3.66;
  bool masses_free = false;            // free with m1 + m2 fixed (Models 3, 4, 5)
  double m_eff_kg = -1.0;              // Model 2: < 0 = fitted in [0, m1 + m2]
  MatParams effects;                   // effect fields taken from here (off by default)
  std::vector<std::string> free_effects;  // effect parameters to fit ("k1_cubic_n_m3", ...)

  // Objective.
  double force_noise_n = 20.0;
  double marker_noise_m = 0.0005;
  double loading_weight = 1.0;         // extra weight on force samples up to the measured peak
  double kinematics_weight = 1.0;      // impactor travel residuals (0 = force only)
  double surface_weight = 1.0;
  double surface_tolerance_m = 0.01;
  bool surface_as_residual = false;
  double contact_threshold_n = 25.0;   // the contact ends when the measured force stays below this
  double window_margin_s = 0.01;       // fitted past the measured contact's end
  double window_end_s = -1.0;          // > 0: fixed window end instead

  // Optimiser.
  Optimizer optimizer = Optimizer::Ceres;
  int starts = 6;                      // multi-start (Ceres)
  int max_iterations = 100;
  std::uint64_t seed = 1;
  AnnealOptions anneal;                // for Optimizer::Annealing
  bool polish_annealing = false;       // finish annealing with Ceres
  MatParams initial;                   // if k1_n_m > 0: an extra start (the first)

  // Ranges the starts are drawn from (and the bounds, 10x wider).
  double k_min_n_m = 2e4, k_max_n_m = 3e6;
  double r_min_n_s_m = 30.0, r_max_n_s_m = 3e3;

  // Validation.
  bool leave_one_out = false;
  bool sensitivity = true;
  double identifiability_rel_se = 0.5;  // relative SE above this: not pinned down
  CharacteristicsOptions characteristics;
};

struct ParameterEstimate {
  std::string name;
  double value = 0.0;
  double se = std::numeric_limits<double>::quiet_NaN();      // standard error, parameter units
  double rel_se = std::numeric_limits<double>::quiet_NaN();  // se / |value|
  bool free = true;
  bool identifiable = true;
};

struct TrialReport {
  std::string id;
  bool train = false;
  double impact_velocity_m_s = 0.0;
  Characteristics measured, simulated;
  ForceComparison comparison;                // over the trial's contact window
  double max_deformation_mm_diff = std::numeric_limits<double>::quiet_NaN();  // impactor travel
  double rms_impactor_mm = std::numeric_limits<double>::quiet_NaN();
  double window_end_s = 0.0;
  Simulation simulation;                     // on the trial's samples from contact
};

struct SensitivityEntry {
  std::string name;
  double peak_pct_minus10 = 0.0;  // peak force change (%) for -10 % on the parameter
  double peak_pct_plus10 = 0.0;
};

struct LeaveOneOutEntry {
  std::string held_out;
  MatParams params;
  ForceComparison comparison;
};

struct FitResult {
  ModelKind model = ModelKind::Model4;
  MatParams params;
  std::vector<std::string> train_ids;
  std::vector<ParameterEstimate> estimates;
  std::vector<TrialReport> trials;
  std::vector<SensitivityEntry> sensitivity;
  std::vector<LeaveOneOutEntry> leave_one_out;
  std::vector<std::string> warnings;  // parameters not identifiable, failed starts, ...
  double cost = 0.0;                  // 0.5 * sum of squared residuals at the optimum
  int n_residuals = 0;
  long evaluations = 0;               // simulations run by the optimiser
  double seconds = 0.0;
  std::string optimizer;
  std::string report() const;         // human-readable summary
};

// Fits `options.model` to the training trials and predicts every trial.
// Throws Error for unusable input (no accepted trial, unknown train id,
// missing samples, Model 5 without a simulator).
FitResult fit(const std::vector<TrialData>& trials, const FitOptions& options);

// Predicts one trial from parameters (its own velocity), with the report.
TrialReport predict(const TrialData& trial, const MatParams& params, const FitOptions& options);

// The objective's building blocks, public for tests and diagnosis: the
// residual vector of `params` on `trials` (as the optimiser sees it).
Eigen::VectorXd residuals(const std::vector<TrialData>& trials, const MatParams& params,
                          const FitOptions& options);

// ---------------------------------------------------------------------------
// Table mode.
struct TableTrial {
  std::string id;
  double impact_velocity_m_s = 0.0;
  double max_deformation_m = std::numeric_limits<double>::quiet_NaN();  // NaN = not used
  double peak_force_n = 0.0;
};

struct TableFitOptions {
  ModelKind model = ModelKind::Model1;
  MatParams base;                    // parameters not fitted (masses, other elements)
  std::vector<std::string> free = {"k1_n_m", "r1_n_s_m"};  // fitted (log scale)
  std::vector<std::string> train_ids;  // empty: the median-velocity trial
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double peak_noise_n = 50.0;          // scales of the two residuals
  double deformation_noise_m = 0.002;
  int starts = 6;
  std::uint64_t seed = 1;
};

struct TableTrialReport {
  std::string id;
  bool train = false;
  double impact_velocity_m_s = 0.0;
  double peak_force_n = 0.0, simulated_peak_force_n = 0.0, peak_force_pct_diff = 0.0;
  double max_deformation_m = 0.0, simulated_max_deformation_m = 0.0;
};

struct TableFitResult {
  MatParams params;                  // the best optimum
  std::vector<MatParams> alternatives;  // distinct optima that fit as well (ambiguity)
  std::vector<TableTrialReport> trials;
  std::vector<std::string> warnings;
  double cost = 0.0;
};

TableFitResult fit_table(const std::vector<TableTrial>& trials, const TableFitOptions& options);

}  // namespace dropfit::fitting
