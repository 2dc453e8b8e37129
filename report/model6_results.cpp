#include "report/model6_results.h"

#include <fmt/format.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "report/results.h"

namespace dropfit::report {

const char* const kModel6NoMjcf =
    "Model 6 has no MJCF export: MuJoCo has no continuum foam element that maps to it (its plateau, densification "
    "and Prony memory, and the stress crossing the column's elements, have no counterpart among MuJoCo's joints, "
    "tendons and contact parameters); a lumped chain written in its place would not be this model";

std::vector<std::pair<std::string, double>> model6_parameters(const fitting::Model6Params& p) {
  std::vector<std::pair<std::string, double>> out;
  auto law = [&](const std::string& layer, const fitting::FoamLaw& l) {
    out.emplace_back(layer + "_plateau_pa", l.plateau_pa);
    out.emplace_back(layer + "_modulus_pa", l.modulus_pa);
    out.emplace_back(layer + "_hardening_pa", l.hardening_pa);
    out.emplace_back(layer + "_densification_pa", l.densification_pa);
    out.emplace_back(layer + "_densification_strain", l.densification_strain);
    out.emplace_back(layer + "_densification_exponent", l.densification_exponent);
  };
  law("top", p.top);
  law("base", p.base);
  out.emplace_back("prony_g1", p.prony_g1);
  out.emplace_back("prony_tau1_s", p.prony_tau1_s);
  out.emplace_back("prony_g2", p.prony_g2);
  out.emplace_back("prony_tau2_s", p.prony_tau2_s);
  out.emplace_back("viscosity_pa_s", p.viscosity_pa_s);
  out.emplace_back("top_mass_kg", p.top_mass_kg);
  out.emplace_back("base_mass_kg", p.base_mass_kg);
  return out;
}

fitting::FitResult model6_as_fit(const fitting::Model6FitResult& fit) {
  fitting::FitResult shared;
  shared.train_ids = fit.train_ids;
  shared.estimates = fit.estimates;
  shared.trials = fit.trials;
  shared.cost = fit.cost;
  shared.n_residuals = fit.n_residuals;
  shared.seconds = fit.seconds;
  shared.warnings = fit.warnings;
  shared.optimizer = "ceres Levenberg-Marquardt, exact derivatives (Jets through the implicit integrator)";
  shared.evaluations = fit.iterations;
  shared.channels = {{"force", 0, 0.0, fit.force_rms_sigma, 0.0, fit.force_rms_sigma > 2.0},
                     {"impactor", 0, 0.0, fit.impactor_rms_sigma, 0.0, fit.impactor_rms_sigma > 2.0}};
  return shared;
}

std::string model6_fit_json(const fitting::Model6FitResult& fit, const fitting::Model6FitOptions& options,
                            double impactor_mass_kg, const Model6Choice& choice, const std::string& label) {
  // The fields Model 6 shares with Models 1-5, written by fit_json.
  const fitting::FitResult shared = model6_as_fit(fit);
  nlohmann::ordered_json doc = nlohmann::ordered_json::parse(fit_json(shared, impactor_mass_kg, label));
  doc["model"] = "model6";
  nlohmann::ordered_json params = nlohmann::ordered_json::object();
  for (const auto& [name, value] : model6_parameters(fit.params)) params[name] = value;
  doc["parameters"] = params;
  const fitting::Model6Geometry& g = options.geometry;
  doc["geometry"] = {{"area_m2", g.area_m2},         {"top_thickness_m", g.top_thickness_m},
                     {"base_thickness_m", g.base_thickness_m}, {"n_top", g.n_top},
                     {"n_base", g.n_base},           {"max_step_s", g.max_step_s}};
  // What Model 1-5 fits carry and Model 6's fitter does not compute.
  doc.erase("sensitivity");
  doc.erase("leave_one_out");
  doc.erase("alternatives");
  doc.erase("identifiable");
  doc.erase("evaluations");
  doc["iterations"] = fit.iterations;
  // How far each trial drives each foam, and whether its prediction
  // extrapolates a foam's law beyond the training trials' reach.
  nlohmann::ordered_json reach = nlohmann::ordered_json::array();
  for (const auto& r : fit.reach)
    reach.push_back({{"id", r.id},
                     {"train", r.train},
                     {"max_top_strain", r.max_top_strain},
                     {"max_base_strain", r.max_base_strain},
                     {"extrapolated", r.extrapolated}});
  doc["strain_reach"] = reach;
  doc["strain_reach_ratio"] = options.extrapolation_ratio;
  // The model's discrepancy each trial's prediction interval holds beside
  // the parameters' and the velocity's part (SDs), in its prediction; an
  // infinite dof (the normal's quantile) is written as null.
  for (auto& t : doc["trials"])
    for (const auto& d : fit.discrepancy)
      if (t["id"] == d.id)
        t["prediction"]["discrepancy"] = {{"growth", d.growth},
                                          {"peak_force_sd_n", d.peak_force_n},
                                          {"time_to_peak_sd_s", d.time_to_peak_s},
                                          {"max_deformation_sd_m", d.max_deformation_m},
                                          {"peak_force_scale", d.peak_force_scale},
                                          {"time_to_peak_scale", d.time_to_peak_scale},
                                          {"max_deformation_scale", d.max_deformation_scale},
                                          {"peak_force_dof", d.peak_force_dof},
                                          {"time_to_peak_dof", d.time_to_peak_dof},
                                          {"max_deformation_dof", d.max_deformation_dof}};
  // The common timing discrepancy of the contact instants (widens every
  // trial's clock-offset SE alike).
  doc["timing_discrepancy_s"] = fit.timing_discrepancy_s;
  doc["choice"] = {{"against", choice.rival},
                   {"chosen", choice.chosen},
                   {"evidence", choice.evidence},
                   {"heldout_force_rms_noise_sd", choice.heldout_force_rms_noise_sd},
                   {"heldout_impactor_rms_noise_sd", choice.heldout_impactor_rms_noise_sd},
                   {"reaches_noise", choice.reaches_noise}};
  doc["mjcf"] = nullptr;
  doc["mjcf_note"] = kModel6NoMjcf;
  return doc.dump(2) + "\n";
}

bool is_model6_fit_json(const std::string& text) {
  const auto doc = nlohmann::json::parse(text, nullptr, false);
  return doc.is_object() && doc.contains("model") && doc["model"] == "model6";
}

Model6FitFile parse_model6_fit_json(const std::string& text, const std::string& path) {
  const auto doc = nlohmann::json::parse(text, nullptr, false);
  if (!doc.is_object()) throw InputError(path, 0, 0, "", "expected a JSON object");
  auto number = [&](const nlohmann::json& obj, const std::string& section, const std::string& key) {
    if (!obj.contains(key) || !obj[key].is_number())
      throw InputError(path, 0, 0, section + "." + key, "missing or not a number");
    return obj[key].get<double>();
  };
  for (const char* section : {"parameters", "geometry"})
    if (!doc.contains(section) || !doc[section].is_object())
      throw InputError(path, 0, 0, section, "missing or not an object");
  Model6FitFile file;
  const auto& p = doc["parameters"];
  for (const auto& [name, value] : p.items())
    if (!value.is_number()) throw InputError(path, 0, 0, "parameters." + name, "not a number");
  auto law = [&](const std::string& layer) {
    return fitting::FoamLaw{number(p, "parameters", layer + "_plateau_pa"),
                            number(p, "parameters", layer + "_modulus_pa"),
                            number(p, "parameters", layer + "_hardening_pa"),
                            number(p, "parameters", layer + "_densification_pa"),
                            number(p, "parameters", layer + "_densification_strain"),
                            number(p, "parameters", layer + "_densification_exponent")};
  };
  file.params.top = law("top");
  file.params.base = law("base");
  file.params.prony_g1 = number(p, "parameters", "prony_g1");
  file.params.prony_tau1_s = number(p, "parameters", "prony_tau1_s");
  file.params.prony_g2 = number(p, "parameters", "prony_g2");
  file.params.prony_tau2_s = number(p, "parameters", "prony_tau2_s");
  file.params.viscosity_pa_s = number(p, "parameters", "viscosity_pa_s");
  file.params.top_mass_kg = number(p, "parameters", "top_mass_kg");
  file.params.base_mass_kg = number(p, "parameters", "base_mass_kg");
  const auto& g = doc["geometry"];
  file.geometry.area_m2 = number(g, "geometry", "area_m2");
  file.geometry.top_thickness_m = number(g, "geometry", "top_thickness_m");
  file.geometry.base_thickness_m = number(g, "geometry", "base_thickness_m");
  const double n_top = number(g, "geometry", "n_top"), n_base = number(g, "geometry", "n_base");
  if (n_top < 1 || n_top > 1000 || n_top != std::floor(n_top))
    throw InputError(path, 0, 0, "geometry.n_top", "must be a whole number of elements, 1 to 1000");
  if (n_base < 0 || n_base > 1000 || n_base != std::floor(n_base))
    throw InputError(path, 0, 0, "geometry.n_base", "must be a whole number of elements, 0 to 1000");
  file.geometry.n_top = static_cast<int>(n_top);
  file.geometry.n_base = static_cast<int>(n_base);
  file.geometry.max_step_s = number(g, "geometry", "max_step_s");
  if (doc.contains("impactor_mass_kg")) file.impactor_mass_kg = number(doc, "", "impactor_mass_kg");
  return file;
}

}  // namespace dropfit::report
