#pragma once
// Views of a session state as result files: each adds its files to an
// OutputSet (report/output.h), which the command commits whole. Which files
// a command writes is which views it takes; the numbers in them come from
// the one state, so every command says the same of a trial.
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "pipeline/pipeline.h"
#include "report/export.h"
#include "report/output.h"

namespace dropfit::pipeline {

// calibration.json and dlt_coefficients.csv (the latter in the image origin
// of `video`: bottom-left coefficients for Argus / DLTdv 7 sessions).
void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result,
                             const VideoSpec& video = {});

// Every trial's xyzpts.csv, residuals.csv and xyzres.csv (trials/T/).
void add_reconstruction_outputs(report::OutputSet& out, const SessionState& state);

// Every trial's trial.json, series.csv, 3-D trajectories, markers.trc and
// grf.mot, and summary.csv (the paper's Table 1 of the session).
void add_trial_outputs(report::OutputSet& out, const SessionState& state);

// fit.json and the measured-vs-simulated series of every trial, under
// `prefix` ("" or "fits/model3/"); `label` names the fit in the file
// (its model name, or "closed_loop").
void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const SessionState& state, const std::string& label = "");

// The mat's layers as the MJCF export takes them (top = all but the last).
report::MatGeometry mat_geometry(const Manifest& manifest);

// Everything `run` writes: calibration, trials, every fit under fits/, the
// final model as the canonical fit.json and mat.mjcf.xml, diagnosis.json,
// report.html.
void add_run_outputs(report::OutputSet& out, const SessionState& state);

}  // namespace dropfit::pipeline
