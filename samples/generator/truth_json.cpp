// The truth JSON of a synthetic session (write_truth_json in
// samples/generator/synth.h): the only file the generator's library writes.
#include <fmt/format.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "core/atomic_file.h"
#include "samples/generator/synth_internal.h"

namespace dropfit::synth {
namespace {

using Json = nlohmann::ordered_json;

double rounded(double v, double unit) { return std::isfinite(v) ? std::round(v / unit) * unit : v; }

Json vec(const Eigen::VectorXd& v, double unit = 0.0) {
  Json a = Json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(unit > 0.0 ? rounded(v(i), unit) : v(i));
  return a;
}
Json num(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

Json params_json(const MatParams& p) {
  return Json{{"k1_n_m", p.k1_n_m},
              {"k2_n_m", p.k2_n_m},
              {"k3_n_m", p.k3_n_m},
              {"r1_n_s_m", p.r1_n_s_m},
              {"r2_n_s_m", p.r2_n_s_m},
              {"r3_n_s_m", p.r3_n_s_m},
              {"m_eff_kg", p.m_eff_kg},
              {"m1_kg", p.m1_kg},
              {"m2_kg", p.m2_kg},
              {"k1_cubic_n_m3", p.k1_cubic_n_m3},
              {"r1_unload_n_s_m", p.r1_unload_n_s_m},
              {"maxwell_k_n_m", p.maxwell_k_n_m},
              {"maxwell_tau_s", p.maxwell_tau_s},
              {"k1_hysteresis", p.k1_hysteresis},
              {"hysteresis_transition_m_s", p.hysteresis_transition_m_s}};
}

// The foam column's layers and relaxation (the foam world).
Json foam_json(const FoamColumn& f) {
  auto layer = [](const FoamLayer& l) {
    return Json{{"thickness_m", l.thickness_m},       {"mass_kg", l.mass_kg},
                {"plateau_pa", l.plateau_pa},         {"modulus_pa", l.modulus_pa},
                {"hardening_pa", l.hardening_pa},     {"densification_pa", l.densification_pa},
                {"densification_strain", l.densification_strain},
                {"densification_exponent", l.densification_exponent}};
  };
  return {{"top", layer(f.top)},     {"base", layer(f.base)},         {"g1", f.g1},
          {"tau1_s", f.tau1_s},      {"g2", f.g2},                    {"tau2_s", f.tau2_s},
          {"viscosity_pa_s", f.viscosity_pa_s}, {"area_m2", f.area_m2}, {"n_top", f.n_top},
          {"n_base", f.n_base},
          {"law", "s_p (1 - exp(-E e / s_p)) + H e + D ((e_d / (e_d - e))^n - 1); "
                  "dq_i/dt = g_i ds_e/dt - q_i / tau_i; + eta de/dt"}};
}

// Each point's place: base markers in the impactor's frame, mat markers' lab x, y.
Json marker_layout_json(const SynthTruth& t) {
  Json layout = Json::object();
  for (std::size_t i = 0; i < t.base_markers_impactor_m.size() && i < t.points.size(); ++i) {
    const Eigen::Vector3d& b = t.base_markers_impactor_m[i];
    layout[t.points[i]] = {{"impactor_frame_m", {b.x(), b.y(), b.z()}}};
  }
  for (std::size_t i = 0; i < t.mat_markers_xy_m.size(); ++i) {
    const std::size_t p = t.base_markers_impactor_m.size() + i;
    if (p < t.points.size()) layout[t.points[p]] = {{"lab_xy_m", {t.mat_markers_xy_m[i].x(), t.mat_markers_xy_m[i].y()}}};
  }
  return layout;
}

Json effects_json(const std::vector<InjectedEffect>& injected) {
  Json effects = Json::array();
  for (const InjectedEffect& e : injected)
    effects.push_back(
        {{"stage", e.stage}, {"name", e.name}, {"magnitude", e.magnitude}, {"unit", e.unit}, {"detail", e.detail}});
  return effects;
}

Json cameras_json(const std::vector<TrueCamera>& cameras) {
  Json cams = Json::array();
  for (const TrueCamera& c : cameras) {
    std::vector<double> dlt(c.camera.dlt.data(), c.camera.dlt.data() + 11);
    Json r = Json::array();
    for (int i = 0; i < 3; ++i) r.push_back({c.cam_from_lab_r(i, 0), c.cam_from_lab_r(i, 1), c.cam_from_lab_r(i, 2)});
    cams.push_back({{"name", c.camera.name},
                    {"dlt", dlt},
                    {"distortion", c.camera.distortion},
                    {"principal_point_px", {c.camera.principal_point_px.x(), c.camera.principal_point_px.y()}},
                    {"focal_px", c.camera.focal_px},
                    {"image_size_px", {c.width_px, c.height_px}},
                    {"cam_from_lab_r", r},
                    {"cam_from_lab_t_m", {c.cam_from_lab_t.x(), c.cam_from_lab_t.y(), c.cam_from_lab_t.z()}},
                    {"centre_lab_m", {c.centre_lab_m.x(), c.centre_lab_m.y(), c.centre_lab_m.z()}}});
  }
  return cams;
}

Json calibration_markers_json(const SynthTruth& t) {
  Json markers = Json::array();
  for (const TrueCalibrationMarker& mk : t.calibration_markers) {
    Json px = Json::object();
    for (std::size_t c = 0; c < mk.image_px.size() && c < t.cameras.size(); ++c)
      px[t.cameras[c].camera.name] = {mk.image_px[c].x(), mk.image_px[c].y()};
    markers.push_back({{"id", mk.id},
                       {"lab_m", {mk.lab_m.x(), mk.lab_m.y(), mk.lab_m.z()}},
                       {"role", mk.role == MarkerRole::Fit ? "fit" : "check"},
                       {"image_px_noise_free", px}});
  }
  return markers;
}

// One trial's truth: its summary numbers, gaps and the series at the force samples.
Json trial_json(const TrialTruth& tr) {
  Json gaps = Json::array();
  for (const Gap& g : tr.gaps)
    gaps.push_back({{"point", g.point}, {"camera", g.camera}, {"first_frame", g.first_frame}, {"n_frames", g.n_frames}});
  std::vector<double> offsets(tr.channel_offsets_n.data(), tr.channel_offsets_n.data() + 8);
  return {{"id", tr.id},
          {"impact_velocity_m_s", tr.impact_velocity_m_s},
          {"max_deformation_m", tr.max_deformation_m},
          {"max_surface_travel_m", tr.max_surface_travel_m},
          {"peak_force_n", tr.peak_force_n},
          {"time_to_peak_s", tr.time_to_peak_s},
          {"tilt_deg", tr.tilt_deg},
          {"tilt_about_y_deg", tr.tilt_about_y_deg},
          {"contact_time_s", tr.contact_time_s},
          {"separation_time_s", num(tr.separation_time_s)},
          {"video_offset_s", tr.video_offset_s},
          {"drop_height_m", tr.drop_height_m},
          {"trigger_index", tr.trigger_index},
          {"cop_m", {tr.cop_m.x(), tr.cop_m.y()}},
          {"impact_point_m", {tr.impact_point_m.x(), tr.impact_point_m.y()}},
          {"shear_fraction", {tr.shear_fraction.x(), tr.shear_fraction.y()}},
          {"channel_offsets_n", offsets},
          {"model", detail::model_key(tr.model)},
          {"parameters", params_json(tr.params)},
          {"gaps", gaps},
          {"impact_velocity_after_m_s", num(tr.impact_velocity_after_m_s)},
          {"tilt_axis_deg", tr.tilt_axis_deg},
          {"dish_factors", tr.dish_factors},
          {"digitised_frames", {tr.digitised_first_frame, tr.digitised_last_frame}},
          {"series",
           {{"t_s", vec(tr.t_s, 1e-9)},
            {"grf_n", vec(tr.grf_n, 1e-6)},
            {"impactor_travel_m", vec(tr.impactor_travel_m, 1e-9)},
            {"surface_travel_m", vec(tr.surface_travel_m, 1e-9)},
            {"layer1_travel_m", vec(tr.layer1_travel_m, 1e-9)},
            {"layer2_travel_m", vec(tr.layer2_travel_m, 1e-9)},
            {"plate_fz_noise_free_n", vec(tr.plate_fz_noise_free_n, 1e-6)}}}};
}

}  // namespace

void write_truth_json(const std::string& path, const SynthTruth& t) {
  Json j;
  j["generator"] = "dropfit-synth";
  j["seed"] = t.seed;
  j["model"] = detail::model_key(t.model);
  j["parameters"] = params_json(t.params);
  if (t.foam) {
    j["model"] = "foam column";
    j["foam"] = foam_json(*t.foam);
  }
  j["mat_top_z_m"] = t.mat_top_z_m;
  j["world"] = t.world;
  j["physics"] = "samples/generator/physics.h (own equations, Dormand-Prince 5(4); no fitting/ code)";
  j["pixel_noise_px"] = t.pixel_noise_px;
  j["calibration_pixel_noise_px"] = t.calibration_pixel_noise_px;
  j["channel_noise_n"] = t.channel_noise_n;
  j["points"] = t.points;
  j["marker_layout"] = marker_layout_json(t);
  j["effects"] = effects_json(t.effects);
  j["cameras"] = cameras_json(t.cameras);
  j["calibration_markers"] = calibration_markers_json(t);
  Json trials = Json::array();
  for (const TrialTruth& tr : t.trials) trials.push_back(trial_json(tr));
  j["trials"] = trials;

  // Whole or not at all (core/atomic_file.h), into a folder that must exist.
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  if (!parent.empty() && !std::filesystem::is_directory(parent))
    throw Error(fmt::format("cannot write {}: no folder {}", path, parent.string()));
  try {
    write_file_atomic(path, j.dump(1) + '\n');
  } catch (const Error& e) {
    throw Error(fmt::format("cannot write {}: {}", path, e.what()));
  }
}

}  // namespace dropfit::synth
