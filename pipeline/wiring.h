#pragma once
// From what capture read to what each stage takes: the manifest's constants
// as stage options, the calibration inputs, one trial through the force
// plate, reconstruction and trial stages, a trial as the fitter sees it.
// No numerics here (they live in the stages) and no file I/O.
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "diagnosis/diagnosis.h"
#include "fitting/fit.h"
#include "fitting/model5.h"
#include "forceplate/forceplate.h"
#include "reconstruction/reconstruction.h"
#include "trial/trial.h"

namespace dropfit::pipeline {

// Calibration markers and camera views of a session, as calibration takes them.
std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame);
std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images);

// The session's camera model as every stage and command uses it: the
// calibration stage's choice (outliers, lens distortion, decided by
// cross-validation on every marker; diagnosis.h), or the manifest's DLT
// coefficients checked on the frame's check markers.
diagnosis::CalibrationDiagnosis choose_calibration(const Session& session);
// A plain calibration with the given options (no choice made), for
// `dropfit calibrate --distortion`.
calibration::CalibrationResult calibrate_session(const Session& session, const calibration::CalibrationOptions& options);
std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result);

// The trial stage's options from the manifest (names, clocks, geometry).
trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id);
forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record);
forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record);

// One trial's force record through forceplate/ and its trajectories into
// trial/. Never throws for a bad trial: a force record that cannot be
// processed gives a rejected trial with its reason (the video-only numbers
// still measured).
struct TrialOutcome {
  trial::TrialResult result;
  std::optional<forceplate::ForceTrial> force;  // the zeroed plate record, when it could be processed
};
TrialOutcome analyse_trial(const Manifest& manifest, const TrialRecording& trial,
                           const reconstruction::Trajectories& trajectories, const trial::TrialOptions& options);

// The fitter's view of a processed trial: times from contact, the plate's
// Fz, the impactor face travel below the undeformed mat top and the mat
// surface travel (both NaN in gaps).
fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result);

// The trial's video_offset_s from the contact instant `fit` placed on the
// force clock (its contact_shift_s), with its SE; the plate-onset estimate
// moves to video_offset_onset_s. Unchanged when the fit has no shift for it.
void apply_fitted_offset(trial::TrialResult& result, const fitting::FitResult& fit);

// A mat that changes between trials: each held-out report in `reports`
// replaced by `predict(its trial, scale)`, scale its stiffness scale
// (`scale_of(id)`, NaN: left as it is) over the training trial's; a
// trial that cannot be predicted keeps its report and gets a note.
// Returns the fit's warning that says so (`scaled`: what the scale
// multiplies), empty when no trial was predicted.
std::string predict_with_stiffness_scales(
    std::vector<fitting::TrialReport>& reports, const std::vector<fitting::TrialData>& data,
    const std::string& train_id, const std::function<double(const std::string& id)>& scale_of,
    const std::function<fitting::TrialReport(const fitting::TrialData& trial, double scale)>& predict,
    const std::string& scaled, std::vector<std::string>& notes);

// Model 5's geometry from the manifest (mat and impactor footprint).
fitting::Model5Geometry model5_geometry(const Manifest& manifest);

}  // namespace dropfit::pipeline
