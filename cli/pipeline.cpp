#include "cli/pipeline.h"

#include "report/results.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace dropfit::pipeline {

std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame) {
  std::vector<calibration::Marker> markers;
  markers.reserve(frame.size());
  for (const auto& m : frame) markers.push_back({m.id, m.lab_m, m.role == MarkerRole::Check});
  return markers;
}

std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images) {
  std::vector<calibration::CameraView> views;
  views.reserve(images.size());
  for (const auto& image : images) {
    calibration::CameraView view{image.camera, {}};
    for (const auto& o : image.observations) view.observations.emplace_back(o.id, o.image_px);
    views.push_back(std::move(view));
  }
  return views;
}

calibration::CalibrationResult calibrate_session(const Session& session,
                                                 const calibration::CalibrationOptions& options) {
  return calibration::calibrate(calibration_markers(session.frame), camera_views(session.images), options);
}

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result) {
  std::vector<calibration::Camera> cameras;
  for (const auto& fit : result.cameras) cameras.push_back(fit.camera);
  return cameras;
}

void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result) {
  out.add("calibration.json", report::calibration_json(result));
  out.add("dlt_coefficients.csv", report::dlt_coefficients_csv(cameras_of(result)));
}

void add_reconstruction_outputs(report::OutputSet& out, const std::string& trial_id,
                                const reconstruction::Trajectories& trajectories) {
  out.add("trials/" + trial_id + "/xyzpts.csv", report::xyzpts_csv(trajectories));
  out.add("trials/" + trial_id + "/residuals.csv", report::residuals_csv(trajectories));
}

trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id) {
  auto index_of = [&](const std::string& name) {
    const auto& points = manifest.video.points;
    return static_cast<int>(std::find(points.begin(), points.end(), name) - points.begin());
  };
  trial::TrialOptions options;
  options.id = trial_id;
  options.impactor_mass_kg = manifest.impactor.mass_kg;
  options.gravity_m_s2 = manifest.gravity_m_s2;
  options.frame_rate_hz = manifest.video.frame_rate_hz;
  options.trigger_frame = manifest.video.trigger_frame;
  for (const auto& name : manifest.impactor.base_markers) options.base_markers.push_back(index_of(name));
  for (const auto& name : manifest.mat.surface_markers) options.surface_markers.push_back(index_of(name));
  options.point_names = manifest.video.points;
  options.base_marker_height_m = manifest.impactor.base_marker_height_m;
  options.mat_top_z_m = manifest.forceplate.mat_top_z_m;
  return options;
}

forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record) {
  forceplate::ProcessOptions options;
  options.trigger_threshold_n = manifest.forceplate.trigger_threshold_n;
  options.pretrigger_fraction = manifest.forceplate.pretrigger_fraction;
  options.pretrigger_samples = record.pretrigger_samples > 0 ? record.pretrigger_samples : -1;
  options.sample_rate_hz = manifest.forceplate.sample_rate_hz;
  return options;
}

forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record) {
  if (record.layout == ForceLayout::EightChannel) {
    return forceplate::from_eight_channels(record.t_s, record.data,
                                           {manifest.forceplate.a_m, manifest.forceplate.b_m, manifest.forceplate.az0_m});
  }
  return forceplate::from_resultant_columns(record.t_s, record.data, 50.0, manifest.forceplate.az0_m);
}

TrialOutcome process_trial(const Manifest& manifest, const TrialData& trial,
                           const std::vector<calibration::Camera>& cameras, double max_tilt_deg) {
  TrialOutcome outcome;
  outcome.trajectories = reconstruction::reconstruct(cameras, trial.tracks.uv_px, trial.tracks.n_points());
  auto options = trial_options(manifest, trial.spec.id);
  if (max_tilt_deg > 0.0) options.max_tilt_deg = max_tilt_deg;
  forceplate::Resultants raw;
  try {
    raw = raw_resultants(manifest, trial.force);
  } catch (const Error& e) {
    // A force record that cannot even be converted: the trial is rejected
    // with the reason; the video-only numbers are still measured.
    outcome.result = trial::analyse(forceplate::Resultants{}, force_options(manifest, trial.force),
                                    outcome.trajectories, options);
    outcome.result.accepted = false;
    outcome.result.reject_reason = std::string("force record: ") + e.what();
    return outcome;
  }
  outcome.result = trial::analyse(raw, force_options(manifest, trial.force), outcome.trajectories, options);
  return outcome;
}

void add_trial_outputs(report::OutputSet& out, const TrialOutcome& outcome) {
  const std::string dir = "trials/" + outcome.result.id + "/";
  out.add(dir + "trial.json", report::trial_json(outcome.result));
  out.add(dir + "series.csv", report::series_csv(outcome.result.series));
  add_reconstruction_outputs(out, outcome.result.id, outcome.trajectories);
}

fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result) {
  fitting::TrialData data;
  data.id = result.id;
  data.accepted = result.accepted;
  data.impact_velocity_m_s = result.impact_velocity_m_s;
  data.impactor_mass_kg = manifest.impactor.mass_kg;
  data.gravity_m_s2 = manifest.gravity_m_s2;
  const auto& s = result.series;
  // The surface markers' height at rest: their mean before contact.
  double rest_sum = 0.0;
  int rest_n = 0;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] < result.contact_time_s && std::isfinite(s.surface_z_m[i])) {
      rest_sum += s.surface_z_m[i];
      ++rest_n;
    }
  }
  const double surface_rest_m = rest_n > 0 ? rest_sum / rest_n : manifest.forceplate.mat_top_z_m;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] >= result.contact_time_s) keep.push_back(i);
  }
  const auto n = static_cast<Eigen::Index>(keep.size());
  data.t_s.resize(n);
  data.grf_n.resize(n);
  data.impactor_m.resize(n);
  data.surface_m.resize(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Index i = keep[k];
    data.t_s[k] = s.t_s[i] - result.contact_time_s;
    data.grf_n[k] = s.fz_n[i];
    data.impactor_m[k] = s.deformation_m[i];
    data.surface_m[k] = surface_rest_m - s.surface_z_m[i];
  }
  return data;
}

fitting::Model5Geometry model5_geometry(const Manifest& manifest) {
  fitting::Model5Geometry g;
  g.mat_length_m = manifest.mat.length_m;
  g.mat_width_m = manifest.mat.width_m;
  g.footprint_length_m = manifest.impactor.footprint_m.x();
  g.footprint_width_m = manifest.impactor.footprint_m.y();
  return g;
}

fitting::FitOptions fit_options(const Manifest& manifest, fitting::ModelKind model) {
  fitting::FitOptions options;
  options.model = model;
  const auto& layers = manifest.mat.layers;
  if (layers.size() >= 2) {
    options.m2_kg = layers.back().mass_kg;
    options.m1_kg = manifest.mat.mass_kg() - options.m2_kg;
  } else if (layers.size() == 1) {
    options.m1_kg = options.m2_kg = layers.front().mass_kg / 2;
  }
  if (model == fitting::ModelKind::Model5) {
    const auto geometry = model5_geometry(manifest);
    options.simulator = [geometry](const fitting::MatParams& p, const fitting::Impact& impact) {
      return fitting::simulate_model5(p, geometry, impact);
    };
  }
  return options;
}

void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const std::vector<fitting::TrialData>& trials, double impactor_mass_kg) {
  out.add(prefix + "fit.json", report::fit_json(fit, impactor_mass_kg));
  for (const auto& report : fit.trials) {
    for (const auto& data : trials) {
      if (data.id == report.id) out.add(prefix + "series/" + data.id + ".csv", report::fit_series_csv(data, report));
    }
  }
}

fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact,
                                    const fitting::Model5Geometry& geometry) {
  if (fit.model == fitting::ModelKind::Model5) return fitting::simulate_model5(fit.params, geometry, impact);
  return fitting::simulate(fit.model, fit.params, impact);
}

}  // namespace dropfit::pipeline
