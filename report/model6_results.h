#pragma once
// OUT/fit.json for Model 6, the foam column (fitting/model6_fit.h): the same
// file as report/results.h's fit_json (label, training trials, estimates
// with standard errors and bound warnings, per-trial errors, characteristics)
// with Model 6's own parameters, the column's geometry, how it was chosen
// and why it has no MJCF export.
#include <string>
#include <utility>
#include <vector>

#include "fitting/model6_fit.h"

namespace dropfit::report {

// How Model 6 was judged against the lumped model it may replace.
struct Model6Choice {
  std::string rival;  // "closed_loop" or a model name
  std::string evidence;
  bool chosen = false;
  double heldout_force_rms_noise_sd = 0.0, heldout_impactor_rms_noise_sd = 0.0;
  bool reaches_noise = false;
};

// Why a Model 6 result carries no mat.mjcf.xml (also in fit.json).
extern const char* const kModel6NoMjcf;

// The canonical parameters, named with units (fit.json's "parameters").
std::vector<std::pair<std::string, double>> model6_parameters(const fitting::Model6Params& params);

// The fields a Model 6 fit shares with Models 1-5 (training trials,
// estimates, trial reports, cost, training RMS per channel) in a FitResult,
// as fit_json and the report's headline take a fit.
fitting::FitResult model6_as_fit(const fitting::Model6FitResult& fit);

std::string model6_fit_json(const fitting::Model6FitResult& fit, const fitting::Model6FitOptions& options,
                            double impactor_mass_kg, const Model6Choice& choice, const std::string& label = "model6");

// A Model 6 fit.json read back for simulation (its "parameters", "geometry"
// and optional "impactor_mass_kg"). Throws dropfit::InputError naming `path`
// and the key.
struct Model6FitFile {
  fitting::Model6Params params;
  fitting::Model6Geometry geometry;
  double impactor_mass_kg = 24.0;
};
Model6FitFile parse_model6_fit_json(const std::string& text, const std::string& path);
// True when `text` is a JSON object whose "model" is "model6".
bool is_model6_fit_json(const std::string& text);

}  // namespace dropfit::report
