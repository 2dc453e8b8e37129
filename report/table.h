#pragma once
// Impact tables: only per-impact summaries, as in the paper's Table 1
// (samples/paper/table1.csv). The reader of the table, and the results of
// fitting a mat model to it (fit.json, predictions.csv, report.html).
//
// The table (comma or tab separated, UTF-8, one header line, '#' comment
// lines and blank lines skipped):
//
//   trial,impact_velocity_m_s,max_deformation_m,peak_force_n
//   1,4.30,0.088,5593
//
// Columns are found by name, in any order: `trial` (or `id`; text, unique),
// `impact_velocity_m_s` (> 0, downward), `peak_force_n` (> 0) and optionally
// `max_deformation_m` (> 0; empty or NaN = not measured). Other columns are
// an error (a typo must not silently drop a measurement).
#include <string>
#include <utility>
#include <vector>

#include "fitting/fit.h"
#include "fitting/table_fit.h"
#include "fitting/models.h"
#include "report/session_report.h"

namespace dropfit::report {

// Throws dropfit::InputError naming `path`, the line (1-based), the column
// and the field on any bad row; an error when fewer than 2 rows.
std::vector<fitting::TableTrial> parse_impact_table(const std::string& text, const std::string& path);

// One held-out impact: the model fitted to every other row, then asked for
// this one's peak force from its velocity.
using TableHeldOut = fitting::TableHeldOut;

struct TableRun {
  std::string table_path;
  fitting::ModelKind model = fitting::ModelKind::Model1;
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  std::vector<std::string> free;            // fitted parameters
  std::vector<fitting::TableTrial> trials;  // as read
  fitting::TableFitResult fit;              // trained on `train_ids`, every impact predicted
  std::vector<std::string> train_ids;
  std::vector<TableHeldOut> leave_one_out;  // one per impact, table order
  // The fitted model's peak force over a range of velocities (the curve of
  // the report's figure).
  std::vector<double> curve_velocity_m_s, curve_peak_force_n;
  // Closing the loop (diagnosis' table stage), as the session report shows it.
  bool loop_run = false;
  std::string loop_baseline_model;
  std::vector<LoopEffect> loop_effects;
  bool loop_unexplained = false;
  std::vector<std::string> notes;
};

// Largest |held-out peak force % difference| and their RMS.
double heldout_peak_pct_max(const TableRun& run);
double heldout_peak_pct_rms(const TableRun& run);

// fit.json of a table: "model", "train", "impactor_mass_kg", "parameters"
// (named with units, report/export.h, so `dropfit simulate --params` reads
// it), "trials" with the spec's keys (rms_force_pct_peak and
// time_to_peak_ms_diff null: a table has no curves) plus measured and
// simulated peak force and deformation, "leave_one_out" [{held_out,
// parameters, peak_force_n, simulated_peak_force_n, peak_force_pct_diff}],
// "heldout_peak_force_pct_max" and "_rms", "alternatives", "warnings".
std::string table_fit_json(const TableRun& run);

// predictions.csv: trial,train,impact_velocity_m_s,peak_force_n,
// simulated_peak_force_n,peak_force_pct_diff,heldout_simulated_peak_force_n,
// heldout_peak_force_pct_diff,max_deformation_m,simulated_max_deformation_m
std::string table_predictions_csv(const TableRun& run);

// report.html: the table with each impact's prediction, the fitted
// parameters, the leave-one-out peak errors (table and figure), closing the
// loop.
std::string table_report_html(const TableRun& run);

}  // namespace dropfit::report
