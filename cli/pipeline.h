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

// Simulates an impact with a fitted parameter file's model (Models 1-5;
// Model 5 with its default geometry).
fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact);

}  // namespace dropfit::pipeline
