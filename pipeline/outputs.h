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
#include "report/results.h"

namespace dropfit::pipeline {

// calibration.json and dlt_coefficients.csv (the latter in the image origin
// of `video`: bottom-left coefficients for Argus / DLTdv 7 sessions).
void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result,
                             const VideoSpec& video = {});

// Every trial's xyzpts.csv, residuals.csv and xyzres.csv (trials/T/).
void add_reconstruction_outputs(report::OutputSet& out, const SessionState& state);

// How trial i's force record was triggered and, from the processed record,
// why it has no centre of pressure (trial.json's "trigger" and
// "centre_of_pressure").
report::TrialSource trial_source(const SessionState& state, std::size_t i);

// Every trial's trial.json, series.csv, 3-D trajectories, markers.trc and
// grf.mot, and summary.csv (the paper's Table 1 of the session).
void add_trial_outputs(report::OutputSet& out, const SessionState& state);

// What every fit of the session stands on that the fit itself does not
// say, for each fit.json's warnings and the report: a plate gain closing
// the loop divided out of every force, which a wrong declared impactor
// mass explains as well (then every force and stiffness is off by 1 / gain).
std::vector<std::string> session_caveats(const SessionState& state);

// fit.json (with the session's caveats among its warnings) and the
// measured-vs-simulated series of every trial, under `prefix` ("" or
// "fits/model3/"); `label` names the fit in the file (its model name, or
// "closed_loop").
void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const SessionState& state, const std::string& label = "");

// Model 6's fit.json (report/model6_results.h) and series under `prefix`,
// when the state has a Model 6 fit.
void add_model6_outputs(report::OutputSet& out, const std::string& prefix, const SessionState& state);
// A Model 6 fit as the report's headline takes a fit (training trials,
// estimates, trial reports, bound warnings; no Model 1-5 parameters).
fitting::FitResult model6_headline_fit(const fitting::Model6FitResult& fit);

// The mat's layers as the MJCF export takes them (top = all but the last).
report::MatGeometry mat_geometry(const Manifest& manifest);

// Everything `run` writes: calibration, trials, every fit under fits/ (Model
// 6's under fits/model6/ when it was fitted), the final model as the
// canonical fit.json and mat.mjcf.xml (none for Model 6: fit.json says
// why), diagnosis.json, report.html.
void add_run_outputs(report::OutputSet& out, const SessionState& state);

}  // namespace dropfit::pipeline
