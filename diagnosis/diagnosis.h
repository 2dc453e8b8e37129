#pragma once
// Closing the loop: from a stage's residual to the effect it is missing, with
// the error before and after (docs/formats.md, OUT/diagnosis.json).
//
// The loop, the same for every stage:
//   1. compute the stage's residual and test it for structure
//      (diagnosis/structure.h: whiteness, candidate regression, periodogram);
//   2. rank the candidate effects by how much of that structure each explains;
//   3. add the best one and refit; keep it only when the held-out error drops
//      by more than noise would explain (a paired test over held-out units)
//      AND an information criterion agrees (structure.h's compare_models);
//      otherwise leave the model as it was and try the next;
//   4. repeat until nothing more helps, then say whether structured residual
//      remains that no known effect explains (`unexplained`).
//
// Stages, candidate effects (names as in the spec's table) and held-out tests:
//
//   calibration  every hypothesis judged by leave-one-out cross-validation
//                on ALL markers (fit and check alike): each marker held out in
//                turn, every camera that sees it refitted on the others, the
//                marker triangulated; its 3-D error is the held-out error.
//                outlier_marker   the markers with the largest held-out errors
//                                 (beyond 2 x the median and min_outlier_m),
//                                 dropped alone or in pairs (a label slip
//                                 swaps two markers, and both then stand
//                                 out); a dropped pair is also tested as a
//                                 label swap (its images exchanged in one
//                                 camera) and named so when that fits.
//                                 Information criterion: the mean-shift
//                                 outlier model (two free coordinates per
//                                 camera for each dropped marker).
//                lens_distortion  Bouguet's radial k1 alone first (one
//                                 parameter per camera), then p1 p2, each only
//                                 while every camera keeps twice as many
//                                 equations as parameters; k1 with its
//                                 jackknife SE over the leave-one-out refits.
//                Forward selection: each round every candidate is scored, the
//                passing one (paired held-out drop over the markers both
//                models judge, and BIC on the all-marker reprojection RSS)
//                with the lowest held-out RMS is kept. The chosen model
//                (markers dropped, distortion terms) is then fitted on the fit
//                markers (the protocol) and used by every later stage and
//                command (pipeline::calibrate_session). Errors: cv_rms_mm,
//                cv_max_mm, fit_rms_px per step; check_rms_mm, check_max_mm of
//                the baseline against the chosen calibration.
//   sync         time_offset      the declared relation (video frame
//                                 trigger_frame at the plate trigger, offset 0)
//                                 against the trial stage's per-trial estimates
//                                 from the contact instant. Held out: the
//                                 independent estimate from the contact-phase
//                                 trajectory (video face heights against the
//                                 plate force integrated twice), each trial
//                                 judged with the offset estimated from the
//                                 others (ms); AICc on the contact-instant
//                                 disagreements. The contact instant reads
//                                 the plate's onset lag as offset, so below
//                                 2 x onset_lag_s an offset counts only when
//                                 the trajectory estimate shows it too.
//                                 Once the mat model explains the mat, sync
//                                 is judged again on the contact instants it
//                                 fits, with the trajectory estimate less its
//                                 bias from the mat's inertia and the plate's
//                                 gain and drift (trajectory_estimate_bias_s).
//   forceplate   baseline_drift   the zeroed Fz where it must be flat: the quiet
//                                 pre-trigger part (0) and, after the contact,
//                                 stretches where it holds still (0 with the
//                                 impactor in the air, m g with it at rest on
//                                 the mat); structure: regression of that
//                                 residual on time and on a ramp from the
//                                 contact. Held out: the later half of the
//                                 post-contact quiet data, predicted from the
//                                 rest (N).
//                force_scale      impulse-momentum: from the contact to an
//                                 instant t_e in the impactor's free flight
//                                 after separation, seen by the video (the
//                                 video often ends before the plate is still):
//                                   integral Fz dt = m (v_in + v_e) + m g (t_e - t_c) + P_mat(t_e)
//                                 (v_e: the impactor's upward speed at t_e from
//                                 a free-flight fit of the video frames above
//                                 the mat top). The mat's momentum P_mat is 0
//                                 before the contact and small in flight; the
//                                 ratio is averaged over every t_e in the
//                                 flight window and its spread there bounds
//                                 P_mat (reported, and in the uncertainty).
//                                 Without a flight in the video: a still plate
//                                 later in the record (impactor at rest, or in
//                                 flight with the video fit). The plate's gain
//                                 is the ratio. Held out: leave-one-trial-out
//                                 ratio error (%).
//   mat          stiffness_nonlinearity (k1_cubic_n_m3), hysteresis
//                (k1_unload_ratio: elastic asymmetry; r1_unload_n_s_m:
//                damping asymmetry), rate_dependence (maxwell_k_n_m,
//                maxwell_tau_s), layer_mass (masses free, total fixed):
//                fitting/models.h's effect terms. Forward selection: every
//                candidate is refitted with fitting::fit (the fitter's own
//                objective: plate force and impactor travel over their
//                measured noise, clock shifts fitted), then judged on the
//                held-out trials (train on the median-velocity trial, the
//                paper's protocol, predict the others): kept when a channel
//                above the noise gate (gate_noise_sd) falls by a paired
//                test, the other stays within noise, and AIC on the training
//                residuals with the AR(1) effective N agrees (layer_mass also
//                needs the masses beyond wald_sd SE of the declared split);
//                of those that pass the one with the lowest held-out error is
//                added, and the search repeats. Structure left beyond
//                unexplained_noise_sd is reported with its frequency.
//
// Table mode (only per-trial peak force, maximum deformation and velocity,
// as the paper's Table 1): the linear model's leave-one-trial-out peak-force
// errors are tested for a trend with impact velocity; stiffening is added to
// a Model 1 fit of the table (done here with fitting::simulate, since
// fitting::fit_table does not fit effect terms yet). Each trial's velocity,
// measured to 0.1 m/s, may carry a correction with a prior (errors in
// variables; TableStageOptions::velocity_sd_m_s).
//
// Everything is numeric: plain values in, a DiagnosisResult out, no file
// I/O. diagnosis_json formats the result as OUT/diagnosis.json.
#include <Eigen/Core>
#include <functional>
#include <optional>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "diagnosis/structure.h"
#include "fitting/fit.h"
#include "fitting/table_fit.h"
#include "forceplate/forceplate.h"
#include "reconstruction/reconstruction.h"
#include "trial/trial.h"

namespace dropfit::diagnosis {

// ---- The result (OUT/diagnosis.json) --------------------------------------

// Named error values in the paper's terms (rms_force_pct_peak,
// heldout_peak_force_pct_max, check_rms_mm, ...), in insertion order.
using ErrorSet = std::vector<std::pair<std::string, double>>;

struct Effect {
  std::string stage;     // calibration, sync, forceplate, mat
  std::string name;      // results-format effect name
  std::string evidence;  // one sentence, numbers included
  ErrorSet error_before, error_after;
  // Beyond the spec's minimum: what was estimated (e.g. k1_cubic_n_m3, gain).
  ErrorSet estimate;
};

// A candidate effect that was tried and not kept, with why.
struct Rejected {
  std::string stage, name, reason;
};

// Structure left in a stage's residual after the loop.
struct Remaining {
  std::string stage;
  std::string name;         // a descriptive name, e.g. "periodic_oscillation"
  std::string description;  // one sentence, numbers included
  double frequency_hz = std::numeric_limits<double>::quiet_NaN();  // its strongest period, when periodic
};

// A plate correction the force-plate stage keeps (see ForceplateDiagnosis).
struct PlateCorrection {
  double gain = 1.0;               // the plate reads gain x the true force
  // Drift (N) = drift_n_s * (t - drift_origin_s) for t >= drift_origin_s when
  // drift_from_contact, else drift_offset_n + drift_n_s * t over the record.
  bool drift = false;
  bool drift_from_contact = false;
  double drift_n_s = 0.0, drift_offset_n = 0.0;
  // Corrected force: (fz - drift(t)) / gain; contact_time_s is the trial's.
  Eigen::VectorXd apply(const Eigen::VectorXd& t_s, const Eigen::VectorXd& fz_n, double contact_time_s) const;
};

// The held-out residual's form (model_choice.h: map_residual, which fills it).
struct ResidualAxis {
  std::string name;
  std::vector<double> centre, mean_sd, count;  // per bin: centre (SI), mean residual (noise SDs), samples
  double r2 = 0.0;
};
struct ResidualMap {
  std::vector<ResidualAxis> axes;  // deflection_m, deflection_rate_m_s, time_since_contact_s, recording_order
  double loading_unloading_r2 = 0.0;  // deflection binned separately while loading and unloading
  double order_slope_sd = 0.0, order_slope_t = 0.0;  // per-trial mean residual against recording order
  std::string form;      // elastic, viscous, memory, trial_to_trial or none
  std::string proposal;  // the term it calls for, one sentence
};

struct DiagnosisResult {
  std::string baseline_model;    // the mat model the loop started from, "model4"
  std::vector<Effect> effects;   // in the order they were added
  bool unexplained = false;      // structured residual remains that no known effect explains
  std::vector<Remaining> remaining;
  std::vector<Rejected> rejected;
  std::vector<std::string> notes;  // stages skipped, fallbacks used
  // Stages not assessed because an earlier stage's residual stayed
  // unexplained ("upstream unresolved"; a note says which).
  std::vector<std::string> not_assessed;
  // The mat fit with the kept mat effects, on the force as the plate stage
  // corrected it (absent when the mat stage did not run, or kept no effect
  // and the plate needed no correction): the closed loop's model of the mat.
  std::optional<fitting::FitResult> mat_fit;
  // The plate correction the force-plate stage kept (identity when none);
  // the pipeline applies it to the trial results and every fit.
  PlateCorrection plate_correction;
  // When the mat changes between trials (mat_change_between_trials named):
  // each accepted trial's stiffness scale as the recording-order trend
  // fitted without it predicts (OrderDiagnosis::trend_scale), by trial id.
  // The pipeline predicts each trial with the final model's stiffnesses
  // times its scale over the training trial's.
  std::vector<std::pair<std::string, double>> trial_stiffness_scale;
  // The held-out residual's form (model_choice.h, map_residual) of the
  // session's final models, as the pipeline maps them once the loop and
  // Model 6 are done: model label ("closed_loop", "model4", "model6") and map.
  std::vector<std::pair<std::string, ResidualMap>> residual_maps;
  std::string report() const;    // a few human lines
  const Effect* find(const std::string& name) const;
};

// OUT/diagnosis.json: baseline_model, effects[{stage, name, evidence,
// error_before, error_after, estimate}], unexplained, and beyond the minimum
// remaining[], rejected[], notes[], residual_maps[{model, form, proposal,
// loading_unloading_r2, order_slope_sd, order_slope_t, axes[{name, r2,
// centre, mean_sd, count}]}]. NaN numbers are written as null.
std::string diagnosis_json(const DiagnosisResult& result);

// ---- Decision thresholds shared by the stages -----------------------------

struct DecisionOptions {
  double t_critical = 2.0;      // paired held-out test: mean drop over its SE
  double min_relative = 0.2;    // ... and at least this share of the error before
  double ic_min_drop = 2.0;     // information criterion: more than weak support
  double alpha = 0.01;          // whiteness / periodogram significance
};

// ---- Calibration ------------------------------------------------------------

struct CalibrationStageOptions {
  calibration::CalibrationOptions calibration;  // the baseline (dlt11 unless asked)
  DecisionOptions decision;
  Criterion criterion = Criterion::BIC;  // 10 markers, 11-15 parameters per camera: AICc is undefined
  int max_outliers = 2;                  // markers that may be dropped
};

struct CalibrationDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;  // what could not be judged, and why
  calibration::CalibrationResult before, after;  // after: with the kept effects
  calibration::CalibrationOptions options_after;
  std::vector<std::string> dropped_markers;
};

// markers, views as calibration::calibrate takes them.
CalibrationDiagnosis diagnose_calibration(const std::vector<calibration::Marker>& markers,
                                          const std::vector<calibration::CameraView>& views,
                                          const CalibrationStageOptions& options = {});

// ---- Synchronisation --------------------------------------------------------

struct SyncStageOptions {
  DecisionOptions decision;
  // Below this the offset is not worth a correction (the paper: synchronised
  // to within 1 ms; one frame at 1 kHz).
  double min_offset_s = 0.5e-3;
  // Added in quadrature to the spread of the per-trial estimates: the
  // systematic uncertainty of the contact-instant method (1 mm of mat-top
  // height is 0.2 ms at 5 m/s).
  double systematic_s = 0.2e-3;
  // The plate's force onset lags the video contact on a mat with mass
  // (0.4-0.55 ms on layered mats; trial.h), and the contact-instant method
  // reads that lag as clock offset. So an offset counts on the contact
  // instant alone only beyond twice this; below, the contact-phase
  // trajectory estimate (which does not use the onset) must show it too:
  // beyond max(min_offset_s, 3 SE), with the same sign.
  double onset_lag_s = 1.0e-3;
};

struct SyncDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;  // what could not be judged, and why
  double declared_offset_s = 0.0;
  double offset_s = 0.0;         // kept: the estimate; else the declared relation
  double offset_se_s = 0.0;
};

// Accepted trials with a finite video_offset_s are used.
SyncDiagnosis diagnose_sync(const std::vector<trial::TrialResult>& trials, const SyncStageOptions& options = {});

// ---- Force plate ------------------------------------------------------------

// One trial's whole zeroed vertical force and the video's face height, both
// on the force clock.
struct PlateTrial {
  std::string id;
  Eigen::VectorXd t_s, fz_n;        // zeroed Fz (forceplate::ForceTrial), trigger at 0
  double noise_n = 0.0;             // SD in the quiet pre-trigger part
  double contact_time_s = 0.0;      // force clock
  double end_time_s = 0.0;          // Fz back in the noise band after the peak
  double quiet_end_s = 0.0;         // the pre-trigger quiet part ends here (forceplate's guard)
  double impact_velocity_m_s = std::numeric_limits<double>::quiet_NaN();  // downward, from video
  Eigen::VectorXd video_t_s, face_z_m;  // contact face height, force clock; NaN gaps
  double mat_top_z_m = std::numeric_limits<double>::quiet_NaN();  // undeformed mat top (lab z)
  double max_deformation_time_s = std::numeric_limits<double>::quiet_NaN();  // force clock
  // The video's free fall before contact, acceleration free (trial.h).
  double fall_accel_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double fall_accel_se_m_s2 = std::numeric_limits<double>::quiet_NaN();
};


// The clock offset the contact-phase trajectory estimate (trial.h,
// video_offset_trajectory_s) reads on the model's own impact, where the
// clocks agree; the loop subtracts it before that estimate checks a clock
// offset. The estimate matches the face's departure from its free-fall path
// with the double integral of the plate force over the impactor's mass. But
// the plate force is not the force on the impactor: it includes the mat's
// accelerated mass, and the plate's gain and drift, which the force-plate
// stage finds after the trial was analysed. So the model's plate force is
// read through `plate` (the trial's contact at contact_time_s on the force
// clock; NaN: gain only) and through the force channel's low-pass when one
// was named (force_lowpass_hz; 0: none), and the same least squares over the shift (+-5 ms,
// 0.01 ms grid, then a parabola) runs on the model's samples every 0.1 ms
// over the contact. Blind test, trajectory estimate minus the true offset:
// 274 trials with a clean plate -0.20 +- 0.07 ms, after subtracting this
// +0.01 +- 0.03 ms; 159 with plate gain or drift 0.03 +- 0.82 ms, after
// 0.10 +- 0.23 ms. NaN when the model cannot be simulated.
double trajectory_estimate_bias_s(fitting::ModelKind model, const fitting::MatParams& params, double velocity_m_s,
                                  double mass_kg, double gravity_m_s2, const PlateCorrection& plate = {},
                                  double contact_time_s = std::numeric_limits<double>::quiet_NaN(),
                                  double force_lowpass_hz = 0.0);

// The impulse-momentum balance of one trial ending in the impactor's free
// flight after separation (see the top of this file): the ratio's mean over
// every force sample in the free-flight window, and how much it moves across
// that window (the mat's own momentum, which the balance leaves out, bounds
// the error: the mat is at rest before the contact and nearly at rest in the
// impactor's flight, and whatever it still carries shows as that spread).
struct ImpulseBalance {
  double ratio = std::numeric_limits<double>::quiet_NaN();   // plate impulse / impactor momentum change
  double spread = std::numeric_limits<double>::quiet_NaN();  // SD of the ratio over the window
  double mat_momentum_n_s = std::numeric_limits<double>::quiet_NaN();  // RMS of the unexplained momentum
  double window_start_s = 0.0, window_end_s = 0.0;             // force clock
  int flight_frames = 0;
  std::string method;  // "free flight" or "still plate"
};
ImpulseBalance impulse_balance(const PlateTrial& trial, const PlateCorrection& correction, double impactor_mass_kg,
                               double gravity_m_s2);

struct ForceplateStageOptions {
  DecisionOptions decision;
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double still_window_s = 0.040;   // a stretch counts as still when its SD is within
  double still_sd_factor = 3.0;    //   this many noise SDs
  double settle_s = 0.030;         // after the contact's end before stillness is sought
  double min_scale_error = 0.01;   // gain errors below 1 % are not worth a correction
  double frame_rate_hz = 0.0;      // the declared video rate (named when the time base is wrong)
};

struct ForceplateDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;  // what could not be judged, and why
  PlateCorrection correction;
  std::vector<double> impulse_ratios;  // per trial, after the kept drift correction
};

ForceplateDiagnosis diagnose_forceplate(const std::vector<PlateTrial>& trials,
                                        const ForceplateStageOptions& options = {});

// The impulse-momentum ratio of one trial (see the top of this file); NaN
// when no instant after the contact has the mat at rest with the impactor
// either resting or in free flight in the video.
double impulse_ratio(const PlateTrial& trial, const PlateCorrection& correction, double impactor_mass_kg,
                     double gravity_m_s2);

// ---- Mat ------------------------------------------------------------------

enum class HeldOut {
  TrainOnOne,      // train on the median-velocity trial, predict the others (the paper)
  LeaveOneOut,     // train on all but one, predict it; every trial in turn
};

struct MatStageOptions {
  fitting::FitOptions fit;  // the baseline: model, masses, objective, optimiser
  HeldOut held_out = HeldOut::TrainOnOne;
  DecisionOptions decision;
  // On the training force residuals with the AR(1) effective N. Not AICc:
  // a fitted force residual at 1 kHz is strongly correlated (N_eff of a
  // 100-sample window can be 10), and AICc then declares any 8-parameter
  // model undefined however well it fits; the held-out test guards against
  // over-fitting instead.
  Criterion criterion = Criterion::AIC;
  // Candidate effects (results-format names), each refitted every round.
  std::vector<std::string> candidates{"stiffness_nonlinearity", "hysteresis", "rate_dependence", "layer_mass"};
  // Each candidate's refit: 0 = the fitter's own full multi-start (every
  // spring ordering; the default), N > 0 = the current optimum plus N
  // screened starts, then the kept model refitted in full. The screened
  // refit is cheaper but judges the candidate in the baseline's basin: on
  // an unseen session with drift, cubic stiffening refitted that way stayed
  // at 9.3e6 N/m^3 (truth 7.0e6) and two false effects were added to make
  // up the difference.
  int refit_starts = 0;
  // The baseline fit when the caller already has it (the main run's Model 4):
  // it is reused, not refitted.
  const fitting::FitResult* baseline = nullptr;
  // A held-out channel counts as explained when its RMS is within this many
  // of its own measured noise SDs (plate: quiet pre-trigger; markers: the
  // free-fall fit's RMS).
  double gate_noise_sd = 2.0;
  // ... and structure counts as unexplained only beyond this many (a
  // prediction from one trial carries that trial's parameter error too).
  double unexplained_noise_sd = 3.0;
  int max_effects = 3;   // forward selection rounds
  // When no single candidate passes a round, pairs of candidates are refitted:
  // each of this many best singles (by held-out error) with every other.
  int pairs = 1;
  // Each pair's refit: the lead's optimum with the partner seeded, plus
  // this many screened starts in all (0: the fitter's full multi-start, as
  // refit_starts). The lead's own refit already searched every spring
  // ordering, and a pair that passes is refitted in full before it is
  // kept. On a foam session the lumped model stays far from the noise and
  // pairs are tried every round, where a full multi-start per pair would
  // be most of the run (BENCHMARKS.md).
  int pair_starts = 2;
  double wald_sd = 3.0;  // an effect's parameter must stand this many SEs from "absent"
  int threads = 2;       // candidate refits in parallel
  // Called after each round that named an effect, with the model the next
  // round starts from and its held-out RMS per channel (noise SDs). The
  // stage's results do not depend on it: the pipeline starts work that
  // waits on the loop's verdict (Model 6) early with it.
  std::function<void(const fitting::FitResult& current, double force_sd, double impactor_sd)> after_round;
};

struct MatDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;  // what could not be judged, and why
  fitting::MatParams params_before, params_after;
  fitting::FitOptions options_after;  // the baseline options with the kept effects
  std::optional<fitting::FitResult> fit_after;  // the fit with the kept effects
  ErrorSet error_before, error_after;
};

MatDiagnosis diagnose_mat(const std::vector<fitting::TrialData>& trials, const MatStageOptions& options = {});

// ---- Force channel --------------------------------------------------------------
//
// An undeclared low-pass between the mat and the plate's samples (a charge
// amplifier's anti-alias filter, a 2nd-order Butterworth) delays the force
// by its group delay, 0.225 ms x 1 kHz / corner, and a pure delay of the
// force reads exactly as a clock offset. What tells them apart is the
// filter's shape beyond the delay (its phase departs from a delay in the
// third order of frequency, fitting/force_lowpass.h): the mat model's plate
// force passed through the filter, with the corner profiled. The profile
// runs over the group delay tau (0: no filter) on a grid: at each point the
// mat model is refitted jointly to every accepted trial (its parameters by
// two Gauss-Newton steps, derivatives by forward differences, each delay
// starting from the optimum of the one before, the first from the joint
// optimum without a filter; each trial's clock shift profiled exactly at
// every evaluation), chi-square = the residual's sum of squares in noise
// units (force and travel) at the parameters reached. Judged as the loop
// judges a term:
//   held out  each trial's chi-square at the delay the other trials' profile
//             chooses, against its chi-square without a filter (paired over
//             trials; the joint fits' parameters include the trial, so this
//             tests the corner's choice, not the mat's);
//   criterion AICc on the joint fits, with the residual's AR(1) effective N
//             (the chi-square differences of the interval shrink alike).
// Only where the lumped model reaches the noise (the mat stage's held-out
// errors within what it counts as explained, and the joint fit with the
// filter at its best not structured): where it does not, a filter term
// would soak up the model's error, and the term is not tried (a note says
// so). The shape a filter leaves grows as the cube of its delay, and a mat
// model's own parameters absorb much of it: at 3 N of plate noise on a
// Model 4 chain a 250 Hz corner is named, while 350 Hz and above fit
// within the noise with no filter (docs/diagnosis.md). When named
// ("force_lowpass", stage forceplate): the corner with its profile-
// likelihood interval (one-sided when the data only bound it), and the fit
// with the filter places each contact, so the clock offset the sync stage
// reports is the clock's. When not named but the profile allows a filter
// (its 95 % set reaches beyond tau = 0 by more than min_ambiguity_s), the
// lag is ambiguous between clock and force channel: the clock offsets it
// allows are reported with the offset.
struct LowpassStageOptions {
  DecisionOptions decision;
  // Group delays profiled (s); 0 is the model without the filter.
  std::vector<double> delays_s{0.0, 0.15e-3, 0.3e-3, 0.45e-3, 0.6e-3, 0.8e-3, 1.0e-3, 1.25e-3};
  double interval_chi2 = 3.84;      // 95 % profile-likelihood interval (one parameter)
  double max_rms_sd = 1.5;          // the joint fit's residual within this many noise SDs ...
  double max_lag1 = 0.5;            //   ... or this lag-1 autocorrelation: the model reaches the noise
  double min_ambiguity_s = 0.1e-3;  // a lag range narrower than this is not worth reporting
};

struct LowpassDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;
  bool tried = false;                 // the model reached the noise and the profile ran
  bool named = false;
  double corner_hz = 0.0;             // named: the profile's best corner
  double delay_s = 0.0;               //   and its group delay
  // The group delays within the profile's 95 % set (s); delay_low_s = 0
  // when no filter fits as well (the corner is then only bounded below).
  double delay_low_s = 0.0, delay_high_s = 0.0;
  std::vector<double> profile_delay_s, profile_chi2;  // the profile (chi-square over its minimum)
  // Named: every trial predicted by the joint fit with the filter (its
  // contact shifts place the contacts the sync stage re-judges), and its options.
  std::optional<fitting::FitResult> fit;
  fitting::FitOptions fit_options;
};

// trials: the mat stage's data (accepted ones used); model: the mat stage's
// final options; start: its optimum; held_out_*_sd: its final held-out force
// and travel errors, and explained_sd what it counts as explained (noise SDs).
// Models 1-4 only.
LowpassDiagnosis diagnose_force_lowpass(const std::vector<fitting::TrialData>& trials,
                                        const fitting::FitOptions& model, const fitting::MatParams& start,
                                        double held_out_force_sd, double held_out_impactor_sd,
                                        double explained_sd, const LowpassStageOptions& options = {});

// ---- Between trials ----------------------------------------------------------
//
// A joint fit assumes one mat in every trial. Foams lose stiffness under
// repeated impacts (and recover with rest), so each trial's stiffness scale
// against one model of the mat (every stiffness of the fitted model times
// s, s chosen so the model's peak force at the trial's impact speed is the
// measured one) is regressed on the trial's impact speed (the model's own
// misfit with speed) and on its recording order (the order the trials are
// listed in). A slope with order beyond t_{alpha/2, n-3} SEs and beyond
// min_rate_per_trial is a mat that changes between trials
// ("mat_change_between_trials", with its rate per trial and each trial's
// scale); the mat stage's effects are then not judged (one set of
// parameters does not hold). When order follows speed the two cannot be
// told apart and the question is not judged (a note says so).

struct OrderStageOptions {
  double alpha = 0.01;
  double min_rate_per_trial = 0.01;           // 1 % stiffness per trial
  double scale_sd_floor = 0.003;              // the scale's own precision (model misfit at one speed)
  double max_order_speed_correlation = 0.9;
  double min_scale = 0.25, max_scale = 4.0;  // the bracket each trial's scale is sought in
  int bisection_steps = 30;                   // on the scale's logarithm within it
};

struct OrderDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;
  std::vector<std::string> ids;           // accepted trials, recording order
  std::vector<double> stiffness_scale;    // per id; NaN when it could not be found
  // Per id: the stiffness scale the trend (recording order and speed) fitted
  // without that trial predicts for it; NaN where it cannot be predicted.
  std::vector<double> trend_scale;
  double rate_per_trial = std::numeric_limits<double>::quiet_NaN();  // relative stiffness change per trial
  double rate_se = std::numeric_limits<double>::quiet_NaN();
  bool changed = false;                   // the mat changes between trials
};

// Every stiffness of `params` (the springs, the cubic term, a Maxwell arm's)
// times `scale`: the same mat made uniformly softer or stiffer.
fitting::MatParams scaled_stiffness(fitting::MatParams params, double scale);

// trials in recording order (rejected ones skipped); fit: one model of the
// mat fitted to them (its model and params are used).
OrderDiagnosis diagnose_order(const std::vector<fitting::TrialData>& trials, const fitting::FitResult& fit,
                              const OrderStageOptions& options = {});

// The same with the model given as its mismatch with a trial when every
// stiffness is `scale` times the model's: zero at the trial's own scale,
// growing with the scale (the lumped models: simulated less measured peak
// force; NaN when it cannot be simulated; called from two threads at once):
// any model of the mat, Model 6 included.
using ScaleMismatch = std::function<double(const fitting::TrialData& trial, double scale)>;
OrderDiagnosis diagnose_order(const std::vector<fitting::TrialData>& trials, const ScaleMismatch& mismatch,
                              const OrderStageOptions& options = {});

// ---- Table mode -------------------------------------------------------------

struct TableStageOptions {
  fitting::ModelKind model = fitting::ModelKind::Model1;  // baseline (linear)
  fitting::MatParams base;                                // fixed parameters (masses)
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double peak_noise_n = 50.0;          // the scales of the table's two residuals
  double deformation_noise_m = 0.002;
  // The impact velocity's uncertainty (SD). When positive (errors in
  // variables), each trial's velocity gets a correction with this prior
  // (bounded at 3 SD), fitted with the model in training, and fitted to the
  // held-out trial's own measured deformation before its peak force is
  // predicted. The paper measured velocity "to within 0.1 m/s": SD 0.05.
  // 0: velocities are exact, peak force predicted from velocity alone.
  double velocity_sd_m_s = 0.05;
  DecisionOptions decision;
  // The trend test: |r| of the held-out peak-force errors against velocity.
  double min_trend_r = 0.8;
};

struct TableDiagnosis {
  std::vector<Effect> effects;
  std::vector<Rejected> rejected;
  std::vector<Remaining> remaining;
  std::vector<std::string> notes;  // what could not be judged, and why
  // Held-out (leave-one-trial-out) peak-force % differences per trial.
  std::vector<std::string> ids;
  Eigen::VectorXd heldout_pct_before, heldout_pct_after;
  fitting::MatParams params_before, params_after;  // fitted to every trial
};

TableDiagnosis diagnose_table(const std::vector<fitting::TableTrial>& trials, const TableStageOptions& options = {});

// ---- A whole session ---------------------------------------------------------

// One trial as the pipeline processed it: everything later stages need.
struct TrialState {
  trial::TrialResult result;
  reconstruction::Trajectories trajectories;  // with the calibration stage's chosen camera model
  std::optional<forceplate::ForceTrial> force;  // the processed force record; empty when unreadable
};

// What the loop reads of a session: the measured data and the fits made of
// it. The pipeline (pipeline/pipeline.h) owns the whole session state, which
// extends this, and hands it to the loop, so that diagnosis.json and fit.json
// describe the same data and fits.
struct SessionData {
  std::string name;
  // The manifest's constants the stages use.
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double frame_rate_hz = 0.0;
  int trigger_frame = 0;            // video frame at the plate trigger (declared relation)
  double mat_top_z_m = 0.0;
  double base_marker_height_m = 0.0;
  std::vector<int> base_markers, surface_markers;  // point indices
  double quiet_guard_s = 0.050;     // forceplate::ProcessOptions::quiet_guard_s
  // The calibration stage's decision; calibration.after is the calibration
  // every trial was reconstructed with.
  CalibrationDiagnosis calibration;
  std::vector<TrialState> trials;   // in session order
  // The fits' input (pipeline::fitting_trial of every trial, accepted or
  // not, in session order) and the fits made of it.
  std::vector<fitting::TrialData> fit_data;
  fitting::FitOptions baseline_fit_options;  // Model 4 with the manifest's masses
  std::vector<fitting::FitResult> fits;      // every model fitted, in the order asked
  const fitting::FitResult* fit(fitting::ModelKind model) const {
    for (const auto& f : fits)
      if (f.model == model) return &f;
    return nullptr;
  }
};

struct DiagnosisOptions {
  bool calibration = true, sync = true, forceplate = true, mat = true, order = true;
  bool force_lowpass = true;                // the undeclared force-channel low-pass (after the mat stage)
  LowpassStageOptions lowpass_stage;
  OrderStageOptions order_stage;
  SyncStageOptions sync_stage;
  ForceplateStageOptions forceplate_stage;  // impactor mass and gravity taken from the state
  MatStageOptions mat_stage;                // fit options: the state's baseline unless mat_stage_fit_set
  bool mat_stage_fit_set = false;           // true: mat_stage.fit as given (tests)
  // As MatStageOptions::after_round, with the plate correction the mat
  // stage's data carry (the force stage's, applied before the mat stage).
  std::function<void(const fitting::FitResult& current, double force_sd, double impactor_sd,
                     const PlateCorrection& correction)>
      after_mat_round;
};

// The loop on a session state: the calibration stage's decision (already
// taken by the pipeline, which reconstructed every trial with it), then
// sync, force plate and mat, in that order, each on the output of the
// stages before with their kept effects applied (drift and gain
// corrections feed the mat data). A stage whose residual stays
// unexplained (remaining structure) leaves every later stage "not
// assessed: upstream unresolved" (a note, and no effects named from bad
// inputs). Throws dropfit::Error when no trial is accepted.
DiagnosisResult diagnose(const SessionData& state, const DiagnosisOptions& options = {});

// ---- The session screen (before any fit) --------------------------------------
//
// Trials that cannot be measurements of the drops they claim, rejected
// (TrialResult::accepted = false with the reason, and the fit data's
// accepted flag, so that no fit and no median-trial choice uses them):
// - a force record identical, sample for sample, to an earlier trial's
//   (one recording under two ids: copied files, a folder read twice);
// - a trial whose impulse-momentum balance in the impactor's free flight
//   (impulse_balance) departs from the other trials' median by more than
//   max(min_tolerance, sd_factor x its own uncertainty): the mat momentum
//   left in its balance and its impact velocity's interval, with the
//   others' scatter. The plate's gain and the declared mass move every
//   trial alike (the loop's force_scale names them); one trial alone off
//   has a fault of its own (a channel, a second impact, a frame count).
// - every accepted trial when one vertical channel's sensitivity is off:
//   the eight channels' twist (forceplate::ForceTrial::twist_fraction)
//   beyond 1 % of Fz over the session and each trial's balance 1 +- its own
//   twist, which a plate's own twist (balance 1) or a gain or mass (every
//   trial alike) does not make; the channel named (screen.cpp);
// - every accepted trial when the clock offsets (video contact minus plate
//   onset) change with 1 / impact speed: offset = c + dh / v, where a clock
//   offset is c alone and a contact height off by dh (the face height's
//   base_marker_height_m, the mat top) adds dh / v. |dh| beyond
//   max(min_height_error_m, height_sd_factor SE) rejects them naming both
//   heights. Before any fit the offsets are the plate-onset ones, whose lag
//   varies with speed on a mat with mass (a few millimetres of apparent dh),
//   so the floor is the 15 mm within which the cameras' and the manifest's
//   mat tops may disagree (trial.h). docs/faults.md has the measured cases.
// The pipeline calls it after building the state and before fitting.
struct ScreenOptions {
  double min_tolerance = 0.03;
  double sd_factor = 4.0;
  double min_height_error_m = 0.015;
  double height_sd_factor = 4.0;
};
struct ScreenResult {
  struct Rejection {
    std::string id, reason;
  };
  std::vector<Rejection> rejected;
  std::vector<std::string> notes;
};
ScreenResult screen_trials(SessionData& state, const ScreenOptions& options = {});

// The accepted trials' clock offsets regressed on 1 / impact speed:
// offset = offset_s + dh_m / v (least squares; SE from the residuals).
// ok = false with fewer than three trials or one speed.
struct ContactHeightCheck {
  bool ok = false;
  double dh_m = 0.0, se_m = 0.0, offset_s = 0.0;
  int n = 0;
};
ContactHeightCheck contact_height_check(const std::vector<TrialState>& trials);
// The reason naming both heights when |dh| exceeds max(floor_m, sd_factor
// SE), else empty (the screen's words; the pipeline asks again once the
// final mat model places each contact, whose offsets carry no onset lag).
std::string contact_height_reason(const SessionData& state, double floor_m, double sd_factor);

// The plate stage's trials from a state, on the force clock with the
// declared clock relation shifted by offset_s (video minus force).
std::vector<PlateTrial> plate_trials(const SessionData& state, double offset_s);

// Merges a stage's diagnosis into the result (unexplained when the stage has
// remaining structure).
template <typename StageDiagnosis>
void append(DiagnosisResult& result, const StageDiagnosis& stage) {
  result.effects.insert(result.effects.end(), stage.effects.begin(), stage.effects.end());
  result.rejected.insert(result.rejected.end(), stage.rejected.begin(), stage.rejected.end());
  result.remaining.insert(result.remaining.end(), stage.remaining.begin(), stage.remaining.end());
  result.notes.insert(result.notes.end(), stage.notes.begin(), stage.notes.end());
  if (!stage.remaining.empty()) result.unexplained = true;
}

}  // namespace dropfit::diagnosis
