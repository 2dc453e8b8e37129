#pragma once
// Closing the loop: from a stage's residual to the effect it is missing, with
// the error before and after (shared/spec/results-format.md, OUT/diagnosis.json).
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
//   calibration  lens_distortion  residual: each marker's reprojection error
//                                 (fit and check); structure: its radial part
//                                 against the image radius cubed (Bouguet's k1
//                                 r^3). Refit with distortion (dlt16).
//                outlier_marker   a fit marker whose leave-one-out 3-D residual
//                                 stands far beyond the rest (calibrate()'s
//                                 outliers). Drop it, refit. Information
//                                 criterion: the mean-shift outlier model (the
//                                 marker's own 2 free coordinates per camera).
//                held out: the check markers' 3-D errors (check_rms_mm,
//                check_max_mm), paired per check marker; BIC on the fit's
//                reprojection RSS.
//   sync         time_offset      the declared relation (video frame
//                                 trigger_frame at the plate trigger, offset 0)
//                                 against the trial stage's per-trial estimates
//                                 from the contact instant. Held out: the
//                                 independent estimate from the contact-phase
//                                 trajectory (video face heights against the
//                                 plate force integrated twice), each trial
//                                 judged with the offset estimated from the
//                                 others (ms); AICc on the contact-instant
//                                 disagreements.
//   forceplate   baseline_drift   the zeroed Fz where it must be flat: the quiet
//                                 pre-trigger part (0) and, after the contact,
//                                 stretches where it holds still (0 with the
//                                 impactor in the air, m g with it at rest on
//                                 the mat); structure: regression of that
//                                 residual on time and on a ramp from the
//                                 contact. Held out: the later half of the
//                                 post-contact quiet data, predicted from the
//                                 rest (N).
//                force_scale      impulse-momentum: from contact to an instant
//                                 t_e after it where the mat is at rest again,
//                                   integral Fz dt = m (v_in + v_e) + m g (t_e - t_c)
//                                 (v_e: the impactor's upward speed at t_e from
//                                 a free-flight fit of the video, or 0 at rest);
//                                 the plate's gain is the ratio. Held out:
//                                 leave-one-trial-out ratio error (%).
//   mat          stiffness_nonlinearity (k1_cubic_n_m3), hysteresis
//                (r1_unload_n_s_m), rate_dependence (maxwell_k_n_m,
//                maxwell_tau_s), layer_mass (masses free, total fixed):
//                fitting/models.h's effect terms, refitted with fitting::fit.
//                Ranking: a score test (Lagrange multiplier): each effect's
//                sensitivity column (d GRF / d effect parameter at the current
//                fit, by finite differences) with the fitted parameters' own
//                sensitivities projected out; the share of the residual it
//                explains is the first-order gain of adding it, and its
//                coefficient starts the refit. Every candidate explaining at
//                least min_candidate_share is refitted (for Models 3 and 4
//                also from a start with elements 1 and 2 swapped: two springs
//                in series give two basins); of those passing both tests the
//                one with the lowest held-out error is kept (forward
//                selection), stopping early when a refit leaves the residual
//                white or at the noise. Evidence also names the state term
//                (x^3, x while unloading, x xdot, xddot) the residual follows.
//                Held out: train on the median-velocity trial (the paper's
//                protocol) or leave-one-trial-out, predict the others;
//                rms_force_pct_peak and heldout_peak_force_pct_max; AIC on
//                the training force residuals with the AR(1) effective N.
//                The loop refits only while the residual fails the whiteness
//                test and its part above the plate noise is at least
//                min_structured_pct_peak of the peak force.
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
#include <string>
#include <utility>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "diagnosis/structure.h"
#include "fitting/fit.h"
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

struct DiagnosisResult {
  std::string baseline_model;    // the mat model the loop started from, "model4"
  std::vector<Effect> effects;   // in the order they were added
  bool unexplained = false;      // structured residual remains that no known effect explains
  std::vector<Remaining> remaining;
  std::vector<Rejected> rejected;
  std::vector<std::string> notes;  // stages skipped, fallbacks used
  std::string report() const;    // a few human lines
  const Effect* find(const std::string& name) const;
};

// OUT/diagnosis.json: baseline_model, effects[{stage, name, evidence,
// error_before, error_after, estimate}], unexplained, and beyond the minimum
// remaining[], rejected[], notes[]. NaN numbers are written as null.
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
};

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

struct ForceplateStageOptions {
  DecisionOptions decision;
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double still_window_s = 0.040;   // a stretch counts as still when its SD is within
  double still_sd_factor = 3.0;    //   this many noise SDs
  double settle_s = 0.030;         // after the contact's end before stillness is sought
  double min_scale_error = 0.01;   // gain errors below 1 % are not worth a correction
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
  // Candidate effects, tried best-ranked first.
  std::vector<std::string> candidates{"stiffness_nonlinearity", "hysteresis", "rate_dependence", "layer_mass"};
  // Maxwell time constants whose sensitivity columns are scored (the best
  // one starts the refit).
  std::vector<double> maxwell_taus_s{0.003, 0.01, 0.03};
  // A residual counts as structured when, beyond failing the whiteness test,
  // its part above the plate noise is at least this share of the peak.
  double min_structured_pct_peak = 1.0;
  double plate_noise_n = 0.0;  // 0: estimated from the residual's first differences
  // Candidates whose signature explains less of the residual are not refitted.
  double min_candidate_share = 0.1;
  // Multi-start of each refit; the current parameters are always one more
  // start. Fewer is faster but can stay in the baseline's basin: Model 4's
  // springs in series trade places, and an effect's optimum may lie in the
  // other basin.
  int refit_starts = 4;
  // The baseline fit when the caller already has it (the main run's Model 4):
  // it is reused, not refitted.
  const fitting::FitResult* baseline = nullptr;
  // A held-out channel counts as explained when its RMS is within this many
  // of its own measured noise SDs (plate: quiet pre-trigger; markers: the
  // free-fall fit's RMS).
  double gate_noise_sd = 2.0;
  int max_effects = 3;   // forward selection rounds
  int threads = 2;       // candidate refits in parallel
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
  StructureReport structure_before, structure_after;
};

MatDiagnosis diagnose_mat(const std::vector<fitting::TrialData>& trials, const MatStageOptions& options = {});

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

struct DiagnosisOptions {
  bool calibration = true, sync = true, forceplate = true, mat = true;
  CalibrationStageOptions calibration_stage;
  SyncStageOptions sync_stage;
  ForceplateStageOptions forceplate_stage;  // impactor mass and gravity taken from the manifest
  MatStageOptions mat_stage;                // masses taken from the manifest's layers
  double max_tilt_deg = 0.0;                // > 0 overrides trial::TrialOptions::max_tilt_deg
};

// The session as capture read it (or synth made it): calibrates, reconstructs,
// analyses every trial, then runs the stages in order, each on the output of
// the stages before with their kept effects applied (a distortion-corrected
// calibration feeds the reconstruction; drift and gain corrections feed the
// mat fit). Throws dropfit::Error when the session cannot be calibrated or no
// trial is accepted.
DiagnosisResult diagnose(const Session& session, const DiagnosisOptions& options = {});

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
