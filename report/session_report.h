#pragma once
// The HTML report of one session: what a biomechanist reads instead of the
// JSON. Sections follow the paper: the session summary (Table 1's shape),
// calibration accuracy, per trial the measured ground reaction force with
// each model overlaid (Figures 3-7) and the key characteristics, the fitted
// parameters with uncertainties (Table 2's shape), predictions across
// trials, sensitivity, and closing the loop.
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "fitting/fit.h"
#include "report/html.h"
#include "trial/trial.h"

namespace dropfit::report {

struct LoopEffect {  // one effect closing the loop added
  std::string stage, name, evidence;
  std::vector<std::pair<std::string, double>> error_before, error_after;
};

// The held-out residual of one final model mapped against the states that
// tell an elastic shape from a viscous one or a memory (the loop's map).
struct ResidualForm {
  struct Axis {
    std::string name;                    // deflection_m, deflection_rate_m_s, time_since_contact_s, recording_order
    std::vector<double> centre, mean_sd;  // per bin (SI; recording order: the trial's place), mean residual in noise SDs
    double r2 = 0.0;                     // share of the residual's sum of squares the bins explain
  };
  std::string model, form, proposal;
  double loading_unloading_r2 = 0.0;
  std::vector<Axis> axes;
};

struct SessionReport {
  std::string session_name;
  std::string session_path;
  const calibration::CalibrationResult* calibration = nullptr;
  std::vector<trial::TrialResult> trials;
  std::vector<fitting::TrialData> fit_data;   // the fitter's view of each trial (measured)
  std::vector<fitting::FitResult> fits;       // one per model, in model order
  // The final model (the result): the closed loop's fit when the loop kept
  // mat effects, else Model 4, or Model 6 when it replaced them (its
  // estimates and trial reports in a FitResult); the report's headline.
  std::optional<fitting::FitResult> final_fit;
  std::string final_label;                    // "closed_loop", "model6" or the model's name
  std::string final_note;                     // how the final model was chosen, when not the loop's way
  // Closing the loop (empty when not run).
  bool loop_run = false;
  std::string loop_baseline_model;
  std::vector<LoopEffect> loop_effects;
  bool loop_unexplained = false;
  std::vector<ResidualForm> residual_forms;   // the final models' held-out residual maps
  std::vector<std::string> notes;             // anything the reader must know (failures, warnings)
};

std::string session_report_html(const SessionReport& report);

// The "Closing the loop" section (effects with evidence, error before and
// after, and a figure), for any report built on HtmlDocument.
void append_loop_section(HtmlDocument& doc, const std::string& baseline_model, const std::vector<LoopEffect>& effects,
                         bool unexplained);

}  // namespace dropfit::report
