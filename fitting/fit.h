#pragma once
// Fitting the mat models (fitting/models.h) to drop-test trials, as Mills,
// Pain & Yeadon (2006) did and a little further.
//
// Objective: a likelihood over what the instruments measure, each channel
// over its own measured noise (least squares over every training trial's
// contact window):
//   force:    (F_sim(t - dt_c) - F_meas(t)) / force_noise_n   at every plate
//             sample from contact_search_s before the trial's contact
//             estimate to the contact's end (+ window_margin_s);
//   impactor: (y_sim(t) - y_meas(t)) / marker_noise_m   wherever the
//             impactor's face travel was measured (NaN = gap), t >= 0.
// Clocks: t is the plate's clock shifted so that t = 0 is the trial's
// contact estimate; the impactor's travel is placed there by the video's own
// contact instant (the free fall reaching the mat top), so its model time is
// t itself. The plate's force onset on a layered mat lags the contact (the
// mat's masses accelerate first), so each trial's contact instant on the
// force clock, dt_c, is a fitted parameter, started at 0 and bounded by
// physics: the plate cannot read the mat's force before the contact (up to
// the onset detector's own error, contact_shift_max_s) and the layers delay
// it by at most contact_shift_min_s; the video-force clock offset follows as
// offset_estimate - dt_c (TrialReport::contact_shift_s and its SE).
// The mat-surface markers are NOT in the objective: they sit beside the
// footprint and see the top layer through an unknown dish factor (a few
// millimetres while the face travels 100), never the face itself.
// Noise: TrialData carries each trial's measured noise (plate: the quiet
// pre-trigger SD; markers: the free-fall fit's RMS); FitOptions' values are
// the fallback. Each channel's share of the cost at the optimum is reported,
// with a warning when one channel carries structured residual the others do
// not.
//
// Parameters: stiffness and damping are fitted as logarithms, bounded by
// physics: each series spring is at least a fraction of the effective
// stiffness F_peak / travel_max measured on the training trials (a
// stiffening top element with its secant k1 + k1_cubic x^2: with k1_cubic
// free, k1 alone keeps only the absolute floor) and at most
// a multiple of it beyond which it is rigid for this mat; damping between
// ~0 and several times critical. Layer masses are fixed to the manifest, or
// free with their total fixed (fitted as the top layer's fraction, as the
// paper's re-optimisation); Model 2's m_eff is free in [0, total layer mass]
// unless fixed.
// Search: quasi-random starts spanning the bounds in log space plus, for the
// chains (Models 3-5), every ordering of the series springs (soft, medium,
// stiff), each with a freed effect absent and present (a quarter into its
// start range); all starts are screened by cost, and Levenberg-Marquardt (Ceres,
// automatic differentiation through the templated simulation) runs from the
// best start of every ordering and the best overall, spread over threads.
// Model 4 also runs from the conjugate of its best optimum: the layers' two
// natural frequencies are met by two pairs (k2, k3) (and (r2, r3)), the one
// fitted and one with the layers' roles exchanged in part, and drops of one
// kind often do not tell them apart (fitting/detail/identify.h). Simulated
// annealing (Corana et al. 1987, fitting/anneal.h) runs on the same
// objective with the contact shifts profiled out. Model 5 has exact
// derivatives too (fitting/model5_impl.h, dual numbers through its implicit
// integrator, the derivative directions split over `threads`); only a
// model given as a simulate callback is fitted with central differences.
//
// Uncertainty (fitting/error_budget.h): the sandwich covariance of the
// estimate, linearised at the optimum, from
// - the noise as it is: each channel of each trial an AR(1) process fitted
//   to its own residuals (variance and lag-1 correlation), so that
//   correlated residuals and a channel that stays above its noise (a model
//   that misses something) widen the intervals by what they imply;
// - the inputs as measured (the error budget): each training trial's impact
//   velocity, video contact instant and travel reference, and the session's
//   calibration scale, are nuisance parameters with priors from their own
//   measurements (TrialData's *_se fields: the free-fall fit's covariance,
//   the contact height's error, the calibration's vertical scale), carried
//   through d residuals / d input into the parameters' covariance (the
//   estimate is the one at the measured inputs; their errors widen it).
// 95 % intervals are symmetric in the optimiser's coordinates (log
// stiffness and damping: value x exp(+-1.96 relative SE)) where the model is
// linear enough there; where it is not (the cost at a Wald end departs from
// the linear prediction), and for a parameter at its bound or weakly
// determined, the interval is the profile likelihood's, calibrated to the
// error budget (fitting/detail/identify.h): asymmetric, or reaching the
// search bound (then the parameter is not identifiable: the bound limits
// it). Another optimum the data do not reject (likelihood ratio under the
// AR(1) noise at most 3.84: chi-square, one degree of freedom, 95 %) makes
// each parameter whose value there lies outside its interval not
// identifiable, its interval spanning both basins (the reason in note).
// A basin the test rejects keeps its posterior share in the SE (the spread
// over the basins; basin_se the best optimum's own), not in the interval.
// A direction the data do not constrain leaves no interval at all.
// A parameter is `model_limited` when a channel's residual stays above its
// noise (RMS over 1.5 noise SDs with lag-1 correlation over 0.5): its
// interval then holds the residual's structure, not the noise alone.
// Every trial's predicted peak force, time to peak, largest travel and
// force-time curve carry 95 % intervals from the parameters' covariance, the
// trial's own velocity error and the shared calibration scale (central
// differences of the model's prediction), against the true (noise-free)
// quantity.
//
// Validation: the fitted parameters predict every trial from its own
// impact velocity (only its clock shift is fitted); key characteristics
// (fitting/characteristics.h) for measured and simulated curves; optional
// leave-one-trial-out; sensitivity of the peak force to +-10 % on each
// stiffness and damping (from the exact derivatives: the peak's elasticity
// carried as a power law; a custom simulator is re-run instead).
//
// Table mode (per-trial summaries only: the paper's Table 1) is
// fitting/table_fit.h.
#include <Eigen/Core>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "fitting/anneal.h"
#include "fitting/characteristics.h"
#include "fitting/model5.h"
#include "fitting/models.h"

namespace dropfit::fitting {

// One trial as the fitter needs it. Times uniformly spaced (the force
// plate's clock), t = 0 at the trial's contact estimate (the video's contact
// instant placed on the force clock); samples before contact_search_s ahead
// of it are ignored.
struct TrialData {
  std::string id;
  bool accepted = true;
  double impact_velocity_m_s = 0.0;  // downward
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  Eigen::VectorXd t_s;
  Eigen::VectorXd grf_n;             // measured ground reaction force (zeroed plate)
  Eigen::VectorXd impactor_m;        // optional: impactor face travel below the mat top (video), NaN gaps
  Eigen::VectorXd surface_m;         // optional: mat-surface marker travel (reported, not fitted), NaN gaps
  // Measured noise of each channel (NaN: FitOptions' fallback).
  double force_noise_n = std::numeric_limits<double>::quiet_NaN();   // plate Fz SD, quiet pre-trigger
  double marker_noise_m = std::numeric_limits<double>::quiet_NaN();  // face height SD, free-fall fit
  // The error budget of the inputs (one sigma; NaN: taken as exact):
  // the free-fall fit's impact velocity and video contact instant (with
  // their covariance), the travel reference (contact height), and the
  // calibration's relative vertical scale error (common to the session).
  double impact_velocity_se_m_s = std::numeric_limits<double>::quiet_NaN();
  double contact_time_se_s = std::numeric_limits<double>::quiet_NaN();
  double velocity_contact_time_cov = std::numeric_limits<double>::quiet_NaN();
  double travel_reference_se_m = std::numeric_limits<double>::quiet_NaN();
  double calibration_scale_sd = std::numeric_limits<double>::quiet_NaN();
};

// A custom simulator (a user's own model); the fitter asks it for the
// samples of Impact (first_output_s, output_dt_s, duration_s) and
// differentiates it by central differences. It is called from several
// threads at once (the parallel starts and predictions): it must be safe to
// call concurrently (no unguarded shared state).
using Simulator = std::function<Simulation(const MatParams&, const Impact&)>;

enum class Optimizer { Ceres, Annealing };

struct FitOptions {
  ModelKind model = ModelKind::Model4;
  Simulator simulator;                // optional override of the model (central differences)
  Model5Geometry model5_geometry;     // Model 5's mat, face and grid (from the manifest)

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
  double force_noise_n = 20.0;         // fallbacks when a trial carries no measured noise
  double marker_noise_m = 0.0005;
  double min_force_noise_n = 0.5;      // floors on measured noise (a quantised or noiseless record)
  double min_marker_noise_m = 1e-4;
  double loading_weight = 1.0;         // extra weight on force samples up to the measured peak
  double kinematics_weight = 1.0;      // impactor travel residuals (0 = force only)
  bool fit_contact_time = true;        // each trial's contact instant on the force clock is fitted
  double contact_shift_min_s = -0.002;  // dt_c in [min, max]: the plate's onset lags the contact by
  double contact_shift_max_s = 0.0005;  //   up to 2 ms, and its detector may read up to 0.5 ms early
  double contact_search_s = 0.004;     // force samples this long before t = 0 are in the window
  int oversample = 2;                  // simulated samples per plate sample (for the clock shift)
  double contact_threshold_n = 25.0;   // the contact ends when the measured force stays below this
  double window_margin_s = 0.01;       // fitted past the measured contact's end
  double window_end_s = -1.0;          // > 0: fixed window end instead
  // A 2nd-order Butterworth low-pass (Hz) on the force channel between the
  // mat and the plate's samples (fitting/force_lowpass.h): the model's force
  // passes it before it is compared with the record (0: none). The mat's own
  // predictions (peak force, intervals, sensitivity) stay the mat's.
  double force_lowpass_hz = 0.0;

  // Optimiser.
  Optimizer optimizer = Optimizer::Ceres;
  int starts = 6;                      // multi-start (Ceres)
  int max_iterations = 100;
  std::uint64_t seed = 1;
  AnnealOptions anneal;                // for Optimizer::Annealing
  bool polish_annealing = false;       // finish annealing with Ceres
  MatParams initial;                   // if k1_n_m > 0: an extra start (the first)
  // The given start runs to convergence whatever its first stage shows,
  // and its cost does not set the lead that cuts the other starts: a
  // nested model's optimum with a new term seeded (the loop's candidate
  // refits) often leads after the first stage from a basin that is not
  // the best, and would cut the runs heading for the one that is.
  bool protect_initial = false;
  // Levenberg-Marquardt from the best start of every spring ordering (plus
  // the best overall up to `starts`); false: from `initial` and the best
  // `starts` - 1 screened starts only (a refit near a known optimum).
  bool every_ordering = true;
  // The identifiability search (the conjugate basin, basin-spanning and
  // profile-likelihood intervals) runs for a fit from scratch; a single
  // warm start near a known optimum (the loop's refits) skips it unless this
  // is set: a refit whose intervals a lab reads (the session's final model).
  bool search_identifiability = false;

  // Bounds (log space). Stiffness: absolute limits, narrowed by physics
  // around the effective stiffness k_eff = F_peak / travel_max of the
  // training data when it is measured: [k_eff_lower_ratio, k_eff_upper_ratio]
  // times k_eff. Damping: absolute limits.
  double k_min_n_m = 2e3, k_max_n_m = 3e7;
  double k_eff_lower_ratio = 0.3, k_eff_upper_ratio = 1000.0;
  double r_min_n_s_m = 3.0, r_max_n_s_m = 3e4;
  int threads = 2;                     // Levenberg-Marquardt runs in parallel; a single run
                                       //   (Model 5) splits its derivatives over them instead
  int first_stage_iterations = 12;     // every start runs this many iterations first;
  double follow_factor = 30.0;         //   those within this factor of the best cost go on
                                       //   (a run heading for the true basin may still trail
                                       //   the leader by this much after the first stage)
  int follow_chunk_iterations = 10;    // the followed runs go on in chunks of this many iterations;
  double drop_factor = 3.0;            //   after each, a run above this factor of the best cost
  double drop_gain = 0.3;              //   that gained less than this fraction in the chunk stops

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
  bool at_bound = false;  // ended within a thousandth of its searched span from a bound
  // 95 % interval (NaN when not identifiable), and the SE a white-noise fit
  // at the measured inputs would state (for comparison only).
  double ci_low = std::numeric_limits<double>::quiet_NaN();
  double ci_high = std::numeric_limits<double>::quiet_NaN();
  double se_white = std::numeric_limits<double>::quiet_NaN();
  bool model_limited = false;  // a channel's residual stays above its noise (see above)
  // How [ci_low, ci_high] was found: "wald", "profile", "basins" (spanning
  // this optimum's interval and another basin's), "" (none).
  std::string interval;
  std::string note;  // why the parameter is not identifiable, or what limits its interval
  // With interval "basins": the best optimum's own interval.
  double basin_ci_low = std::numeric_limits<double>::quiet_NaN();
  double basin_ci_high = std::numeric_limits<double>::quiet_NaN();
  // When a basin the likelihood-ratio test rejects keeps a posterior share
  // that moves this parameter (fitting/identify.cpp), se holds the spread
  // over the basins and this the best optimum's own SE; NaN otherwise.
  double basin_se = std::numeric_limits<double>::quiet_NaN();
};

// A predicted quantity and its 95 % interval for the true value.
struct PredictionInterval {
  double value = std::numeric_limits<double>::quiet_NaN();
  double se = std::numeric_limits<double>::quiet_NaN();
  double low = std::numeric_limits<double>::quiet_NaN();
  double high = std::numeric_limits<double>::quiet_NaN();
};

struct Prediction {
  PredictionInterval peak_force_n, time_to_peak_s, max_deformation_m;  // time from the contact
  Eigen::VectorXd force_low_n, force_high_n;  // the force-time band on the trial's samples (t_s)
  // The SE the trial's fitted contact instant inherits from the parameters
  // and the inputs (a held-out trial's shift is fitted with them held).
  double contact_shift_se_s = std::numeric_limits<double>::quiet_NaN();
};

struct TrialReport {
  std::string id;
  bool train = false;
  double impact_velocity_m_s = 0.0;
  double contact_shift_s = 0.0;     // fitted contact instant on the force clock minus the estimate
  // Its SE: a training trial's from the joint error budget; a held-out
  // trial's from its own residuals (AR(1), the parameters held) and what it
  // inherits from the parameters and its inputs (Prediction).
  double contact_shift_se_s = std::numeric_limits<double>::quiet_NaN();
  Characteristics measured, simulated;
  ForceComparison comparison;                // over the trial's contact window
  double max_deformation_mm_diff = std::numeric_limits<double>::quiet_NaN();  // impactor travel
  double rms_impactor_mm = std::numeric_limits<double>::quiet_NaN();
  double window_end_s = 0.0;
  Simulation simulation;                     // on the trial's own samples (t_s), force shifted by the fit
  Prediction prediction;                     // with 95 % intervals (see above)
  // The video-force clock offset's correction (contact_shift_s) with its
  // SE including the video contact instant's own error.
  double offset_se_s = std::numeric_limits<double>::quiet_NaN();
};

// One measured channel's part of the cost at the optimum.
struct ChannelShare {
  std::string name;          // "force", "impactor"
  int n = 0;                 // residuals
  double share = 0.0;        // of the total cost
  double rms_sigma = 0.0;    // RMS residual in units of the channel's noise
  double lag1_autocorrelation = 0.0;  // of its residuals, within trials (1 = smooth structure)
  bool structured = false;   // rms_sigma > 2 and autocorrelation > 0.5
};

// Another optimum that fits within noise of the best.
struct Alternative {
  MatParams params;
  double cost = 0.0;
  // The likelihood-ratio statistic against the best optimum under the error
  // budget's noise (each channel AR(1), the inputs' priors): the value the
  // 3.84 threshold was applied to.
  double delta_chi2 = 0.0;
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
  std::vector<ChannelShare> channels;
  std::vector<Alternative> alternatives;  // other basins within noise (not identifiable)
  std::vector<std::string> warnings;  // parameters not identifiable, failed starts, ...
  double cost = 0.0;                  // 0.5 * sum of squared residuals at the optimum
  int n_residuals = 0;
  long evaluations = 0;               // simulations run by the optimiser
  double seconds = 0.0;
  std::string optimizer;
  // The force-channel low-pass the model's plate force passed through
  // (FitOptions::force_lowpass_hz; 0: none): the parameters are the mat's.
  double force_lowpass_hz = 0.0;
  std::string report() const;         // human-readable summary
};

// Fits `options.model` to the training trials and predicts every trial.
// Throws Error for unusable input (no accepted trial, unknown train id,
// missing samples, an impossible Model 5 geometry).
FitResult fit(const std::vector<TrialData>& trials, const FitOptions& options);

// Predicts one trial from parameters (its own velocity), with the report;
// only the trial's clock shift is fitted (when options.fit_contact_time).
TrialReport predict(const TrialData& trial, const MatParams& params, const FitOptions& options);

// The objective's building blocks, public for tests and diagnosis: the
// residual vector of `params` on `trials` (as the optimiser sees it, each
// trial's clock shift profiled out when options.fit_contact_time).
Eigen::VectorXd residuals(const std::vector<TrialData>& trials, const MatParams& params,
                          const FitOptions& options);

// The derivatives the optimiser uses: residuals x free parameters (in the
// optimiser's coordinates: log stiffness, log damping, ...), each trial's
// clock shift held at its profiled value. Automatic differentiation for
// Models 1-5, central differences for a custom simulator. Also returns the
// free parameters' names in column order.
Eigen::MatrixXd residual_jacobian(const std::vector<TrialData>& trials, const MatParams& params,
                                  const FitOptions& options, std::vector<std::string>* names = nullptr);

}  // namespace dropfit::fitting
