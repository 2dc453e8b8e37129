#pragma once
// The wiring between stages: from what capture read to what each stage
// takes, and on to the results. No numerics here (they live in the stages)
// and no file writing (the commands commit an OutputSet).
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "core/session.h"
#include "diagnosis/diagnosis.h"
#include "reconstruction/reconstruction.h"
#include "fitting/fit.h"
#include "fitting/model5.h"
#include "fitting/models.h"
#include "report/export.h"
#include "core/progress.h"
#include "report/output.h"
#include "report/session_report.h"
#include "trial/trial.h"

namespace dropfit::pipeline {

// Calibration markers and camera views of a session, as calibration takes them.
std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame);
std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images);

// The session's camera model as every stage and command uses it: the
// calibration stage's choice (outliers, lens distortion, decided by
// cross-validation on every marker; diagnosis.h), its `.after`.
diagnosis::CalibrationDiagnosis choose_calibration(const Session& session);
calibration::CalibrationResult calibrate_session(const Session& session);
// A plain calibration with the given options (no choice made).
calibration::CalibrationResult calibrate_session(const Session& session, const calibration::CalibrationOptions& options);

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result);

// calibration.json and dlt_coefficients.csv (the latter in the image origin
// of `video`: bottom-left coefficients for Argus / DLTdv 7 sessions).
void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result,
                             const VideoSpec& video = {});

// trials/T/xyzpts.csv, residuals.csv and xyzres.csv (NAME_dltres, names from
// `point_names`) for one trial.
void add_reconstruction_outputs(report::OutputSet& out, const std::string& trial_id,
                                const reconstruction::Trajectories& trajectories,
                                const std::vector<std::string>& point_names = {});

// Trial extraction: the force record through forceplate/, the tracks
// through reconstruction/, both into trial/. Never throws for a bad trial:
// a bad force record or missing markers give a rejected trial with its
// reason. `max_tilt_deg` <= 0 keeps the trial stage's default.
struct TrialOutcome {
  reconstruction::Trajectories trajectories;
  trial::TrialResult result;
  trial::TrialOptions options;                 // what the trial was analysed with (names, clocks)
  std::optional<forceplate::ForceTrial> force;  // the zeroed plate record, when it could be processed
};
trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id);
forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record);
forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record);
TrialOutcome process_trial(const Manifest& manifest, const TrialRecording& trial,
                           const std::vector<calibration::Camera>& cameras, double max_tilt_deg = 0.0);

// trial.json, series.csv, the trial's 3-D trajectories, and the OpenSim
// files markers.trc (force clock) and grf.mot (when the force was processed).
void add_trial_outputs(report::OutputSet& out, const TrialOutcome& outcome);

// The fitter's view of a processed trial: times from contact, the plate's
// Fz, the impactor face travel below the undeformed mat top and the mat
// surface travel (both NaN in gaps).
fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result);
// The calibration's own quality (trial.h) with the calibration frame's
// markers' height span: what the trial gates and the velocity's
// calibration term use.
trial::CalibrationQuality session_calibration_quality(const Session& session,
                                                      const calibration::CalibrationResult& calibration);
// The trial's video_offset_s from the contact instant `fit` placed on the
// force clock (its contact_shift_s), with its SE; the plate-onset estimate
// moves to video_offset_onset_s. Unchanged when the fit has no shift for it.
void apply_fitted_offset(trial::TrialResult& result, const fitting::FitResult& fit);

// Model 5's geometry from the manifest (mat and impactor footprint).
fitting::Model5Geometry model5_geometry(const Manifest& manifest);

// Fitter options for `model` with the manifest's layer masses (top = every
// layer above the last, bottom = the last) and Model 5's simulator.
fitting::FitOptions fit_options(const Manifest& manifest, fitting::ModelKind model);

// fit.json (model's canonical parameters) and the measured-vs-simulated
// series of every trial, under `prefix` ("" or "fits/model3/").
void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const std::vector<fitting::TrialData>& trials, double impactor_mass_kg);

// The mat's layers as the MJCF export takes them (top = all but the last).
report::MatGeometry mat_geometry(const Manifest& manifest);

// The session state the loop runs on (diagnosis.h), built once: the
// calibration stage's choice, every trial reconstructed with it and
// analysed, the fits' data. No fits yet (fit_models adds them). `say`
// reports progress (may be empty).
diagnosis::SessionState session_state(const Session& session,
                                      const std::function<void(const std::string&)>& say = {});

// Fits `models` on state.fit_data into state.fits: the point-mass models in
// parallel (`threads`), then Model 5 from Model 4's optimum with one start.
// Returns one note per failed fit and per fit warning.
std::vector<std::string> fit_models(diagnosis::SessionState& state, const Manifest& manifest,
                                    const std::vector<fitting::ModelKind>& models, int threads = 1,
                                    const std::function<void(const std::string&)>& say = {});

// The main run of one session: calibrate, process every trial, fit every
// model, close the loop, write the report. Results go into `out` (nothing
// is written here). Throws dropfit::Error when the session as a whole
// cannot be processed (unreadable, no calibration); a bad trial is
// rejected with its reason and the rest goes on.
struct RunOptions {
  std::vector<fitting::ModelKind> models = {fitting::ModelKind::Model1, fitting::ModelKind::Model2,
                                            fitting::ModelKind::Model3, fitting::ModelKind::Model4,
                                            fitting::ModelKind::Model5};
  bool diagnose = true;
  int threads = 1;  // models fitted in parallel
};
struct RunSummary {
  std::string session;
  int trials = 0, accepted = 0;
  int failed_fits = 0;  // models whose fit threw (each named in notes)
  std::vector<std::string> notes;
};
RunSummary run_session(const std::string& session_dir, const RunOptions& options, report::OutputSet& out,
                       Progress* progress = nullptr);

// Simulates an impact with a fitted parameter file's model (Models 1-5;
// Model 5 with its default geometry).
fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact,
                                    const fitting::Model5Geometry& geometry = {});

}  // namespace dropfit::pipeline
