#pragma once
// Many results folders gathered into one archive table (`dropfit gather`).
//
// A results folder is what `dropfit run` wrote (summary.csv, fits/*/fit.json)
// or what `dropfit table` wrote (fit.json and predictions.csv, no
// summary.csv). Each becomes one row per fitted model: trials, accepted, the
// model's parameters and how well it reproduces the force. A model is
// labelled as the run labelled it: its folder under fits/ ("model4",
// "closed_loop"), with the model it was fitted as beside it; a table's fit
// is labelled "table:modelN". The results folders are only read.
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "report/output.h"

namespace dropfit::report {

struct ArchiveModel {
  std::string label;  // the folder under fits/, or "table:<model>"; "" for a session without fits
  std::string model;  // fit.json's "model"
  std::map<std::string, double> parameters;
  double mean_rms_force_pct = std::numeric_limits<double>::quiet_NaN();
  double max_rms_force_pct = std::numeric_limits<double>::quiet_NaN();
  double heldout_peak_pct_max = std::numeric_limits<double>::quiet_NaN();  // a table's leave-one-out
  int trials = 0;  // fit.json's trials (a table's impacts)
  int warnings = 0;
};

struct ArchiveSession {
  std::filesystem::path dir;
  std::string source = "session";  // or "table"
  int trials = 0, accepted = 0;
  std::vector<ArchiveModel> models;
};

// The results folders an argument names: itself when it holds results, else
// its sub-folders that do (one level down, sorted). Throws dropfit::Error
// when there are none, InputError naming the file and field for a summary.csv
// or fit.json that is not dropfit's.
std::vector<std::filesystem::path> result_folders(const std::string& arg);
ArchiveSession read_results_folder(const std::filesystem::path& dir);

// Every argument's results folders, each once however it was reached (given
// twice, or given and inside another given folder), as archive.csv and
// archive.html (each session linked to its report.html relative to out_dir).
struct Archive {
  std::vector<ArchiveSession> sessions;
  OutputSet files;
};
Archive gather_results(const std::vector<std::string>& args, const std::filesystem::path& out_dir);

}  // namespace dropfit::report
