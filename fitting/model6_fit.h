#pragma once
// Fitting Model 6 (fitting/model6.h), the foam column, to drop-test trials
// with the measured-channel objective of fitting/fit.h: plate force over its
// measured noise at every sample from contact_search_s before the contact
// estimate to the contact's end (+ window_margin_s), and impactor face
// travel over its noise wherever measured; each training trial's contact
// instant on the force clock (dt_c) fitted. The plate's delay behind the
// face (the stress crossing the column) is the model's own, so dt_c only
// absorbs the error of the contact estimate t = 0 (the video's contact
// placed on the force clock through the trial stage's offset, which reads
// the column's onset lag, up to 2-3 ms, as clock): dt_c in
// [contact_shift_min_s, contact_shift_max_s].
//
// Free parameters (fitted as logarithms, with the derivatives of
// fitting/model6_impl.h): the top foam's plateau, modulus, hardening and
// densification stress; the base foam's four; one densification strain
// shared by the two foams (both collapse near the same strain: the
// densification of a foam the training impact barely reaches is otherwise
// free to run to its bound); the two Prony terms (g, tau each; tau_1 in
// [0.5, 10] ms, below the plate's resolution a Prony term is a dashpot;
// tau_2 in [10, 300] ms), the viscosity, and the densification exponent n
// shared by the two foams (fitted as log(n - 1), n in [1.3, 4]; the whole
// search runs with n held at densification_exponent and, when that fit is
// short of the noise, again with it free, keeping n free only when that
// halves the cost: see free_exponent_cost_ratio). Start: a generic landing-mat foam pair with
// every stress scaled by the training trials' peak stress; when the search
// from there ends short of the noise, it runs again from the generic pair
// with a stiffer or softer base foam (screened, see start_base_scales) and
// the lower cost is the fit.
//
// This fitter stands beside fitting/fit.h's (which fits Models 1-5 and the
// loop's effects): it returns the same TrialReport per trial, so held-out
// errors read the same; each trial's contact_shift_se_s is from the
// curvature of its force residual in the shift, scaled by the residual's
// RMS in noise SDs when above 1 (a misfit counts as noise) and by its
// lag-1 autocorrelation's AR(1) factor, and widened in quadrature by the
// model's discrepancy in the shift (the shift the loading part alone fits
// against the whole window's: a force shape the column misses pulls them
// apart by about what it biases the shift). The
// derivatives: two 8-wide Jet passes on two threads.
#include <atomic>
#include <limits>
#include <string>
#include <vector>

#include "fitting/fit.h"
#include "fitting/model6.h"

namespace dropfit::fitting {

struct Model6FitOptions {
  // The two foams' thicknesses (the manifest's layers); 5 + 3 elements at
  // 0.25 ms steps: within 0.3 % of the peak of a 15 + 11 element column.
  Model6Geometry geometry{0.0625, 0.11, 0.08, 5, 3, 2.5e-4};
  double top_mass_kg = 2.4, base_mass_kg = 3.6;
  // Empty: the accepted trial with the highest impact velocity. A foam's
  // law is nonlinear in strain (a plateau, then densification) and a trial
  // shows it only up to the strain it reaches: trained on the deepest
  // impact, every other trial is predicted inside the strains the law was
  // fitted on. Trained on a mid-range trial, the faster trials extrapolate
  // each foam's densification, and a law of the wrong shape there misses
  // their peaks by several per cent (docs/models.md).
  std::vector<std::string> train_ids;
  double densification_exponent = 2.0;
  double force_noise_n = 20.0;       // fallbacks when a trial carries no measured noise
  double marker_noise_m = 5e-4;
  double min_force_noise_n = 0.5, min_marker_noise_m = 1e-4;
  double contact_search_s = 0.004;   // force samples this long before t = 0 are in the window
  double contact_threshold_n = 25.0; // the contact ends when the measured force stays below this
  double window_margin_s = 0.01;
  double contact_shift_min_s = -3e-3;  // dt_c in [min, max]
  double contact_shift_max_s = 1e-3;
  int oversample = 2;                // simulated samples per plate sample
  int max_iterations = 60;
  // A second start: when the search from the generic start ends short of
  // the noise (RMS residual over both channels above restart_min_rms noise
  // SDs), the generic start with the base foam's four stresses scaled by
  // each of start_base_scales (1: the generic start itself, skipped) is
  // screened for screen_iterations (clock shifts held), the whole search
  // runs again from the lowest, and the lower final cost is the fit.
  // Empty or {1}: no second start.
  std::vector<double> start_base_scales{2.0, 0.5};
  int screen_iterations = 10;
  double restart_min_rms = 3.0;
  // The first stage (clock shifts held, re-profiled between rounds): rounds
  // of stage_iterations each.
  int stage_rounds = 4;
  int stage_iterations = 10;
  // The second stage stops when an iteration lowers the cost by less than
  // this share (Ceres' function tolerance).
  double function_tolerance = 1e-6;
  // The densification exponent: the whole search runs with it held at
  // densification_exponent and, when short of the noise, again with it
  // free; the free exponent is kept when its fit's cost is at most this
  // share of the held fit's (one more parameter lowers a structured
  // misfit's cost a little, and its gain must be the law's shape, not the
  // misfit's).
  double free_exponent_cost_ratio = 0.5;
  // The free path runs only when the held fit's RMS residual (both
  // channels, noise units) exceeds this: a law that already fits the
  // training trial near the noise has no steepness to learn.
  double free_exponent_min_rms = 4.0;
  // A held-out trial is predicted by extrapolating a foam's law
  // (Model6FitResult::warnings) when its fitted column drives that foam
  // deeper than the training trials by more than this ratio in the law's
  // densification coordinate r = e / (e_d - e) (the strain over the
  // compressibility left; the densification term goes as r^n): far below
  // e_d that is about the strain's ratio, near e_d a few hundredths of
  // strain more.
  double extrapolation_ratio = 1.5;
  // Prediction intervals (add_model6_prediction_intervals): with the
  // model's discrepancy (the training trials' own misfit in each quantity,
  // grown with how far a trial drives a foam beyond their reach) beside
  // the parameters' covariance and the trial's velocity; false: those two
  // alone.
  bool model_discrepancy = true;
  // With model_discrepancy: each held-out trial's discrepancy scaled by
  // what the other held-out trials' measured peak, time to peak and travel
  // show against their predictions (fitting/model6_calibration.h); false:
  // the training misfit times its growth alone.
  bool cross_validate_discrepancy = true;
  // Set (by another thread) to stop the fit: fit_model6 then throws Error
  // after the solver iteration under way. Null: runs to the end.
  const std::atomic<bool>* cancel = nullptr;
};

// How far a trial drives each foam in the fitted column: the largest
// compressive strain of the top element and of the bottom one over the
// trial's contact window.
struct Model6Reach {
  std::string id;
  bool train = false;
  double max_top_strain = 0.0, max_base_strain = 0.0;
  // A held-out trial beyond the training trials' reach in either foam by
  // more than extrapolation_ratio: the law there is the fit's
  // extrapolation, not something the training data showed.
  bool extrapolated = false;
};

// The model's discrepancy in one trial's predicted quantities (SDs, added
// in quadrature to the parameters' and the velocity's part of the
// prediction interval): the training trials' misfit in the quantity times
// `growth`, the trial's reach over the training trials' in the
// densification coordinate (1 within their reach), and for a held-out
// trial with cross_validate_discrepancy the cross-validated widening
// (`*_scale`: the interval's SE over the uncalibrated one, at least 1).
// `*_dof`: the interval's degrees of freedom (Student's t; infinite, the
// normal's 1.96, unless the discrepancy was scaled by other trials).
struct Model6Discrepancy {
  std::string id;
  double growth = 1.0;
  double peak_force_n = 0.0, time_to_peak_s = 0.0, max_deformation_m = 0.0;
  double peak_force_scale = 1.0, time_to_peak_scale = 1.0, max_deformation_scale = 1.0;
  double peak_force_dof = std::numeric_limits<double>::infinity();
  double time_to_peak_dof = std::numeric_limits<double>::infinity();
  double max_deformation_dof = std::numeric_limits<double>::infinity();
};

struct Model6FitResult {
  Model6Params params;
  std::vector<std::string> train_ids;
  // The free parameters (14, and the densification exponent when the fit
  // freed it), SEs from (J^T J)^-1 scaled by the residual
  // variance when above the noise (delta method from the logarithms).
  std::vector<ParameterEstimate> estimates;
  // The fit's coordinates (the logarithms of free_names' parameters, the
  // densification exponent as log(n - 1), always 15) and their covariance
  // (kept for the prediction intervals: the held exponent's row is zero).
  Eigen::VectorXd coordinates;
  Eigen::MatrixXd coordinate_covariance;
  bool free_exponent = false;
  // every trial predicted (train: its fitted dt_c), each with its 95 %
  // prediction intervals (TrialReport::prediction)
  std::vector<TrialReport> trials;
  std::vector<Model6Reach> reach;            // every trial's, in the order of trials
  std::vector<Model6Discrepancy> discrepancy;  // every trial's, in the order of trials (empty: none added)
  // One per extrapolated trial: which foam it drives how far beyond the
  // training reach (its prediction's error can exceed the training fit's).
  std::vector<std::string> warnings;
  // The common timing discrepancy of every trial's contact instant: the
  // training force misfit above the noise (RMS) over the RMS rate of the
  // fitted force, by Cauchy-Schwarz the largest clock shift a misfit of
  // that size can bias a least-squares contact by, in quadrature with the
  // shift that best aligns the fitted face travel with the measured one
  // (how far the column's contact stands from the video's); 0 at the noise.
  double timing_discrepancy_s = 0.0;
  double cost = 0.0;                         // 0.5 x sum of squared residuals (noise units)
  int n_residuals = 0;
  double force_rms_sigma = 0.0, impactor_rms_sigma = 0.0;  // training residual RMS per channel
  long iterations = 0;
  double seconds = 0.0;
};

// The accepted trial Model6FitOptions::train_ids defaults to: the highest
// impact velocity (one impactor mass: the deepest impact). nullptr when no
// trial is accepted.
const TrialData* deepest_trial(const std::vector<TrialData>& trials);

// Throws Error for unusable input (no accepted trial, unknown train id).
Model6FitResult fit_model6(const std::vector<TrialData>& trials, const Model6FitOptions& options);

// One trial predicted from its own impact velocity; only dt_c is fitted.
TrialReport predict_model6(const TrialData& trial, const Model6Params& params, const Model6FitOptions& options);

// The parameters at the fit's coordinates (Model6FitResult::coordinates).
Model6Params model6_params_at(const Eigen::VectorXd& coordinates, const Model6FitOptions& options,
                              bool free_exponent);

// Every trial's prediction (res.trials[].prediction): peak force, time to
// peak (from the face's contact), largest face travel and the force band
// on the trial's samples with 95 % intervals from the coordinates'
// covariance (central differences through simulate_model6, one-sided for
// a coordinate at the law's edge, e_d = 1), the trial's
// impact velocity SE (a held-out trial's: a training trial's own velocity
// error is absorbed by the fit) and, with options.model_discrepancy, the
// model's discrepancy (res.discrepancy; with cross_validate_discrepancy a
// held-out trial's scaled by the other held-out trials' measured errors,
// fitting/model6_calibration.h), and res.timing_discrepancy_s. Needs res.reach and the training
// trials' reports; fit_model6 calls it. A trial whose simulation fails
// keeps no intervals and gets a warning. Reads no file.
void add_model6_prediction_intervals(const std::vector<TrialData>& trials, const Model6FitOptions& options,
                                     Model6FitResult& res);

}  // namespace dropfit::fitting
