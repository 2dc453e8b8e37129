#pragma once
// The wiring between stages: from what capture read to what each stage
// takes, and on to the results. No numerics here (they live in the stages)
// and no file writing (the commands commit an OutputSet).
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "reconstruction/reconstruction.h"
#include "fitting/models.h"
#include "report/export.h"
#include "report/output.h"
#include "trial/trial.h"

namespace dropfit::pipeline {

// Calibration markers and camera views of a session, as calibration takes them.
std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame);
std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images);

calibration::CalibrationResult calibrate_session(const Session& session,
                                                 const calibration::CalibrationOptions& options = {});

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result);

// calibration.json and dlt_coefficients.csv.
void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result);

// trials/T/xyzpts.csv and residuals.csv for one trial.
void add_reconstruction_outputs(report::OutputSet& out, const std::string& trial_id,
                                const reconstruction::Trajectories& trajectories);

// Trial extraction: the force record through forceplate/, the tracks
// through reconstruction/, both into trial/. Never throws for a bad trial:
// a bad force record or missing markers give a rejected trial with its
// reason. `max_tilt_deg` <= 0 keeps the trial stage's default.
struct TrialOutcome {
  reconstruction::Trajectories trajectories;
  trial::TrialResult result;
};
trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id);
forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record);
forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record);
TrialOutcome process_trial(const Manifest& manifest, const TrialData& trial,
                           const std::vector<calibration::Camera>& cameras, double max_tilt_deg = 0.0);

// trial.json, series.csv, and the trial's 3-D trajectories.
void add_trial_outputs(report::OutputSet& out, const TrialOutcome& outcome);

// Simulates an impact with a fitted parameter file's model (Models 1-5;
// Model 5 with its default geometry).
fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact);

}  // namespace dropfit::pipeline
