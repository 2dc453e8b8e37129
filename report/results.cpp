#include "report/results.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "report/export.h"

namespace dropfit::report {

using nlohmann::json;

std::string csv_number(double value, int significant) {
  if (std::isnan(value)) return "NaN";
  return fmt::format("{:.{}g}", value, significant);
}

namespace {
json vec3(const Eigen::Vector3d& v, double scale = 1.0) { return json::array({v.x() * scale, v.y() * scale, v.z() * scale}); }
}  // namespace

std::string calibration_json(const calibration::CalibrationResult& result) {
  bool distorted = false;
  json cameras = json::array();
  for (const auto& fit : result.cameras) {
    distorted = distorted || !fit.camera.distortion.empty();
    json dlt = json::array();
    for (int i = 0; i < 11; ++i) dlt.push_back(fit.camera.dlt[i]);
    cameras.push_back({{"name", fit.camera.name},
                       {"dlt", dlt},
                       {"distortion", fit.camera.distortion},
                       {"principal_point_px", {fit.camera.principal_point_px.x(), fit.camera.principal_point_px.y()}},
                       {"focal_px", fit.camera.focal_px},
                       {"fit_rms_px", fit.fit_rms_px},
                       {"n_fit_points", fit.n_fit_points}});
  }
  json checks = json::array();
  for (const auto& c : result.check_points) checks.push_back({{"id", c.id}, {"error_mm", vec3(c.error_m, 1e3)}});
  json loo = json::array();
  for (const auto& l : result.leave_one_out) loo.push_back({{"id", l.id}, {"residual_mm", l.residual_m * 1e3}});
  json doc = {{"model", distorted ? "dlt16" : "dlt11"},
              {"cameras", cameras},
              {"check_points", checks},
              {"check_rms_mm", vec3(result.check_rms_m, 1e3)},
              {"check_max_mm", result.check_max_m * 1e3},
              {"leave_one_out", loo},
              {"outlier_markers", result.outliers}};
  return doc.dump(2) + "\n";
}

calibration::Dlt11 dlt_bottom_left(const calibration::Dlt11& L, double H) {
  calibration::Dlt11 out = L;
  out[4] = H * L[8] - L[4];
  out[5] = H * L[9] - L[5];
  out[6] = H * L[10] - L[6];
  out[7] = H - L[7];
  return out;
}

std::string dlt_coefficients_csv(const std::vector<calibration::Camera>& cameras, double bottom_left_height_px) {
  std::vector<calibration::Dlt11> dlts;
  for (const auto& camera : cameras) {
    dlts.push_back(bottom_left_height_px > 0.0 ? dlt_bottom_left(camera.dlt, bottom_left_height_px) : camera.dlt);
  }
  std::string out;
  for (int i = 0; i < 11; ++i) {
    for (size_t c = 0; c < dlts.size(); ++c) {
      if (c) out += ',';
      out += fmt::format("{:.15g}", dlts[c][i]);
    }
    out += '\n';
  }
  return out;
}

std::string xyzpts_csv(const reconstruction::Trajectories& trajectories) {
  const int n_points = trajectories.n_points();
  std::string out;
  for (int p = 0; p < n_points; ++p) {
    if (p) out += ',';
    out += fmt::format("pt{0}_X,pt{0}_Y,pt{0}_Z", p + 1);
  }
  out += '\n';
  for (Eigen::Index f = 0; f < trajectories.lab_m.rows(); ++f) {
    for (Eigen::Index c = 0; c < trajectories.lab_m.cols(); ++c) {
      if (c) out += ',';
      out += csv_number(trajectories.lab_m(f, c));
    }
    out += '\n';
  }
  return out;
}

namespace {
// The per-frame reprojection residuals (px), one row per frame, one column
// per point, 6 significant digits ("NaN" when unknown): the body shared by
// residuals_csv and xyzres_csv.
std::string residual_rows_csv(const reconstruction::Trajectories& trajectories) {
  std::string out;
  for (Eigen::Index f = 0; f < trajectories.residual_px.rows(); ++f) {
    for (int p = 0; p < trajectories.n_points(); ++p) {
      if (p) out += ',';
      out += csv_number(trajectories.residual_px(f, p), 6);
    }
    out += '\n';
  }
  return out;
}
}  // namespace

std::string residuals_csv(const reconstruction::Trajectories& trajectories) {
  const int n_points = trajectories.n_points();
  std::string out;
  for (int p = 0; p < n_points; ++p) {
    if (p) out += ',';
    out += fmt::format("pt{}_res_px", p + 1);
  }
  out += '\n';
  return out + residual_rows_csv(trajectories);
}

std::string xyzres_csv(const reconstruction::Trajectories& trajectories,
                       const std::vector<std::string>& point_names) {
  const int n_points = trajectories.n_points();
  std::string out;
  for (int p = 0; p < n_points; ++p) {
    if (p) out += ',';
    const bool named = p < static_cast<int>(point_names.size()) && !point_names[p].empty();
    out += (named ? point_names[p] : fmt::format("pt{}", p + 1)) + "_dltres";
  }
  out += '\n';
  return out + residual_rows_csv(trajectories);
}

namespace {
// JSON has no NaN: unknown numbers are null.
json number_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }
}  // namespace

std::vector<std::string> trial_source_notes(const std::vector<std::pair<std::string, TrialSource>>& trials) {
  // What each trial's source says, then one line per text naming its trials.
  std::vector<std::pair<std::string, std::vector<std::string>>> by_text;
  auto add = [&](const std::string& text, const std::string& id) {
    auto it = std::find_if(by_text.begin(), by_text.end(), [&](const auto& e) { return e.first == text; });
    if (it == by_text.end()) it = by_text.insert(by_text.end(), {text, {}});
    it->second.push_back(id);
  };
  for (const auto& [id, source] : trials) {
    if (source.trigger_from_data) add(fmt::format("the force export has no trigger mark: trigger {}", source.trigger), id);
    if (!source.cop_unavailable.empty())
      add(fmt::format("no centre of pressure ({}); grf.mot's point and torque columns are NaN, not the plate centre",
                      source.cop_unavailable),
          id);
    if (!source.markers_file.empty())
      add(fmt::format("3-D markers as an optoelectronic system gave them ({}): no camera calibration or "
                      "reconstruction, no reprojection residual; the impact velocity's interval holds the free-fall "
                      "fit's error only (the system's own scale error is not known here)",
                      source.markers_file),
          id);
  }
  std::vector<std::string> notes;
  for (const auto& [text, ids] : by_text)
    notes.push_back(fmt::format("{} {}: {}", ids.size() == 1 ? "trial" : "trials", fmt::join(ids, ", "), text));
  return notes;
}

std::string trial_json(const trial::TrialResult& r, const TrialSource* source) {
  json doc = {{"id", r.id},
              {"accepted", r.accepted},
              {"reject_reason", r.reject_reason},
              {"impact_velocity_m_s", number_or_null(r.impact_velocity_m_s)},
              {"impact_velocity_ci_m_s", number_or_null(r.impact_velocity_ci_m_s)},
              {"impact_velocity_se_m_s", number_or_null(r.impact_velocity_se_m_s)},
              {"calibration_scale_sd", number_or_null(r.calibration_scale_sd)},
              {"calibration_uncertainty", r.calibration_uncertainty},
              {"video_contact_time_se_s", number_or_null(r.video_contact_time_se_s)},
              {"contact_height_se_m", number_or_null(r.contact_height_se_m)},
              {"max_deformation_m", number_or_null(r.max_deformation_m)},
              {"tilt_deg", number_or_null(r.tilt_deg)},
              {"peak_force_n", number_or_null(r.peak_force_n)},
              {"time_to_peak_s", number_or_null(r.time_to_peak_s)},
              {"contact_time_s", number_or_null(r.contact_time_s)},
              {"contact_height_m", number_or_null(r.contact_height_m)},
              {"surface_rest_z_m", number_or_null(r.surface_rest_z_m)},
              {"video_offset_s", number_or_null(r.video_offset_s)},
              {"video_offset_se_s", number_or_null(r.video_offset_se_s)},
              {"video_offset_onset_s", number_or_null(r.video_offset_onset_s)},
              {"video_offset_trajectory_s", number_or_null(r.video_offset_trajectory_s)},
              {"video_contact_time_s", number_or_null(r.video_contact_time_s)},
              {"max_deformation_time_s", number_or_null(r.max_deformation_time_s)},
              {"end_time_s", number_or_null(r.end_time_s)},
              {"freefall_rms_m", number_or_null(r.freefall_rms_m)},
              {"freefall_frames", r.freefall_frames},
              {"fall_accel_m_s2", number_or_null(r.fall_accel_m_s2)},
              {"fall_accel_se_m_s2", number_or_null(r.fall_accel_se_m_s2)},
              {"impulse_ratio", number_or_null(r.impulse_ratio)}};
  doc["force_lowpass_hz"] = number_or_null(r.force_lowpass_hz);
  doc["force_lowpass_source"] = r.force_lowpass_source.empty() ? json(nullptr) : json(r.force_lowpass_source);
  if (!r.force_correction.empty()) {
    doc["force_correction"] = r.force_correction;
    doc["peak_force_uncorrected_n"] = number_or_null(r.peak_force_uncorrected_n);
  }
  if (source) {
    doc["trigger"] = source->trigger;
    doc["trigger_from_data"] = source->trigger_from_data;
    doc["centre_of_pressure"] = source->cop_unavailable.empty() ? json(nullptr) : json(source->cop_unavailable);
    doc["markers"] = source->markers_file.empty() ? std::string("reconstructed from the cameras") : source->markers_file;
  }
  return doc.dump(2) + "\n";
}

std::string series_csv(const trial::Series& s) {
  std::string out = "t_s,fz_n,impactor_z_m,deformation_m,surface_z_m\n";
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    out += fmt::format("{},{},{},{},{}\n", csv_number(s.t_s[i]), csv_number(s.fz_n[i]), csv_number(s.impactor_z_m[i]),
                       csv_number(s.deformation_m[i]), csv_number(s.surface_z_m[i]));
  }
  return out;
}

std::string summary_csv(const std::vector<trial::TrialResult>& trials) {
  std::string out =
      "trial,accepted,impact_velocity_m_s,impact_velocity_ci_m_s,max_deformation_m,peak_force_n,time_to_peak_s,"
      "tilt_deg,video_offset_ms,reject_reason\n";
  for (const auto& r : trials) {
    std::string reason = r.reject_reason;
    std::replace(reason.begin(), reason.end(), '"', '\'');
    out += fmt::format("{},{},{},{},{},{},{},{},{},\"{}\"\n", r.id, r.accepted ? "yes" : "no",
                       csv_number(r.impact_velocity_m_s, 5), csv_number(r.impact_velocity_ci_m_s, 3),
                       csv_number(r.max_deformation_m, 5), csv_number(r.peak_force_n, 6),
                       csv_number(r.time_to_peak_s, 5), csv_number(r.tilt_deg, 3), csv_number(r.video_offset_s * 1e3, 4),
                       reason);
  }
  return out;
}

namespace {
json interval_json(const fitting::PredictionInterval& p) {
  return {{"value", number_or_null(p.value)}, {"se", number_or_null(p.se)}, {"low", number_or_null(p.low)},
          {"high", number_or_null(p.high)}};
}

// A trial's predicted quantities with their 95 % intervals (the force-time
// band is in the trial's series CSV).
json prediction_json(const fitting::Prediction& p) {
  return {{"peak_force_n", interval_json(p.peak_force_n)},
          {"time_to_peak_s", interval_json(p.time_to_peak_s)},
          {"max_deformation_m", interval_json(p.max_deformation_m)}};
}

json characteristics_json(const fitting::Characteristics& c) {
  return {{"peak_force_n", number_or_null(c.peak_force_n)},
          {"time_to_peak_s", number_or_null(c.time_to_peak_s)},
          {"first_peak_n", number_or_null(c.first_peak_n)},
          {"first_peak_s", number_or_null(c.first_peak_s)},
          {"second_peak_n", number_or_null(c.second_peak_n)},
          {"second_peak_s", number_or_null(c.second_peak_s)},
          {"min_between_n", number_or_null(c.min_between_n)},
          {"min_between_s", number_or_null(c.min_between_s)},
          {"max_loading_rate_n_s", number_or_null(c.max_loading_rate_n_s)},
          {"max_loading_rate_s", number_or_null(c.max_loading_rate_s)}};
}
}  // namespace

std::string fit_json(const fitting::FitResult& fit, double impactor_mass_kg, const std::string& label) {
  json parameters = json::object();
  for (const auto& [name, value] : named_parameters(fit.model, fit.params)) parameters[name] = value;
  json estimates = json::array();
  for (const auto& e : fit.estimates) {
    estimates.push_back({{"name", e.name},
                         {"value", e.value},
                         {"se", number_or_null(e.se)},
                         {"rel_se", number_or_null(e.rel_se)},
                         {"free", e.free},
                         {"identifiable", e.identifiable},
                         {"at_bound", e.at_bound},
                         {"ci_low_95", number_or_null(e.ci_low)},
                         {"ci_high_95", number_or_null(e.ci_high)},
                         {"interval", e.interval.empty() ? json(nullptr) : json(e.interval)},
                         {"note", e.note},
                         {"ci_low_95_this_basin", number_or_null(e.basin_ci_low)},
                         {"ci_high_95_this_basin", number_or_null(e.basin_ci_high)},
                         {"se_this_basin", number_or_null(e.basin_se)},
                         {"se_white_noise", number_or_null(e.se_white)},
                         {"model_limited", e.model_limited}});
  }
  // A parameter the search box stopped, not the data, is said in the file
  // a simulator loads, whatever the fit's own warnings say.
  std::vector<std::string> warnings = fit.warnings;
  for (const auto& e : fit.estimates) {
    if (!e.at_bound || !e.free) continue;
    const std::string w = fmt::format("{} = {:.6g} sits at the bound of its search range: the bound, not the data, "
                                      "sets it",
                                      e.name, e.value);
    if (std::find(warnings.begin(), warnings.end(), w) == warnings.end()) warnings.push_back(w);
  }
  json trials = json::array();
  for (const auto& t : fit.trials) {
    trials.push_back({{"id", t.id},
                      {"train", t.train},
                      {"impact_velocity_m_s", t.impact_velocity_m_s},
                      {"rms_force_pct_peak", number_or_null(t.comparison.rms_force_pct_peak)},
                      {"peak_force_pct_diff", number_or_null(t.comparison.peak_force_pct_diff)},
                      {"time_to_peak_ms_diff", number_or_null(t.comparison.time_to_peak_ms_diff)},
                      {"max_deformation_mm_diff", number_or_null(t.max_deformation_mm_diff)},
                      {"rms_impactor_mm", number_or_null(t.rms_impactor_mm)},
                      {"contact_shift_s", t.contact_shift_s},
                      {"contact_shift_se_s", number_or_null(t.contact_shift_se_s)},
                      {"offset_se_s", number_or_null(t.offset_se_s)},
                      {"prediction", prediction_json(t.prediction)},
                      {"measured", characteristics_json(t.measured)},
                      {"simulated", characteristics_json(t.simulated)}});
  }
  json sensitivity = json::array();
  for (const auto& s : fit.sensitivity) {
    sensitivity.push_back({{"name", s.name}, {"peak_pct_minus10", s.peak_pct_minus10}, {"peak_pct_plus10", s.peak_pct_plus10}});
  }
  json loo = json::array();
  for (const auto& l : fit.leave_one_out) {
    json p = json::object();
    for (const auto& [name, value] : named_parameters(fit.model, l.params)) p[name] = value;
    loo.push_back({{"held_out", l.held_out},
                   {"parameters", p},
                   {"rms_force_pct_peak", number_or_null(l.comparison.rms_force_pct_peak)},
                   {"peak_force_pct_diff", number_or_null(l.comparison.peak_force_pct_diff)}});
  }
  json channels = json::array();
  for (const auto& c : fit.channels) {
    channels.push_back({{"name", c.name},
                        {"residuals", c.n},
                        {"cost_share", c.share},
                        {"rms_noise_sd", c.rms_sigma},
                        {"lag1_autocorrelation", c.lag1_autocorrelation},
                        {"structured", c.structured}});
  }
  json alternatives = json::array();
  for (const auto& a : fit.alternatives) {
    json p = json::object();
    for (const auto& [name, value] : named_parameters(fit.model, a.params)) p[name] = value;
    alternatives.push_back({{"parameters", p}, {"cost", a.cost}, {"delta_chi2", a.delta_chi2}});
  }
  json doc = {{"model", fitting::model_name(fit.model)},
              {"label", label.empty() ? fitting::model_name(fit.model) : label},
              {"train", fit.train_ids},
              {"impactor_mass_kg", impactor_mass_kg},
              {"parameters", parameters},
              {"estimates", estimates},
              {"trials", trials},
              {"sensitivity", sensitivity},
              {"leave_one_out", loo},
              {"channels", channels},
              {"identifiable", fit.alternatives.empty()},
              {"alternatives", alternatives},
              {"warnings", warnings},
              {"optimizer", fit.optimizer},
              {"force_lowpass_hz", fit.force_lowpass_hz > 0.0 ? json(fit.force_lowpass_hz) : json(nullptr)},
              {"evaluations", fit.evaluations},
              {"seconds", fit.seconds}};
  return doc.dump(2) + "\n";
}

std::string fit_series_csv(const fitting::TrialData& measured, const fitting::TrialReport& report) {
  std::string out =
      "t_s,measured_fz_n,simulated_fz_n,measured_impactor_m,simulated_impactor_m,measured_surface_m,simulated_surface_m,"
      "simulated_layer1_m,simulated_layer2_m,simulated_fz_low_n,simulated_fz_high_n\n";
  const auto& sim = report.simulation;
  const Eigen::Index n = std::min<Eigen::Index>(measured.t_s.size(), sim.t_s.size());
  auto at = [](const Eigen::VectorXd& v, Eigen::Index i) { return i < v.size() ? v[i] : NAN; };
  for (Eigen::Index i = 0; i < n; ++i) {
    out += fmt::format("{},{},{},{},{},{},{},{},{},{},{}\n", csv_number(measured.t_s[i]), csv_number(measured.grf_n[i]),
                       csv_number(sim.grf_n[i]), csv_number(at(measured.impactor_m, i)), csv_number(sim.impactor_m[i]),
                       csv_number(at(measured.surface_m, i)), csv_number(sim.surface_m[i]), csv_number(at(sim.layer1_m, i)),
                       csv_number(at(sim.layer2_m, i)), csv_number(at(report.prediction.force_low_n, i)),
                       csv_number(at(report.prediction.force_high_n, i)));
  }
  return out;
}

std::string simulation_csv(const fitting::Simulation& sim) {
  std::string out = "t_s,grf_n,impactor_m,surface_m\n";
  for (Eigen::Index i = 0; i < sim.t_s.size(); ++i) {
    out += fmt::format("{},{},{},{}\n", csv_number(sim.t_s[i]), csv_number(sim.grf_n[i]), csv_number(sim.impactor_m[i]),
                       csv_number(sim.surface_m[i]));
  }
  return out;
}

}  // namespace dropfit::report
