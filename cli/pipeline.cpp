#include "cli/pipeline.h"

#include "report/results.h"

#include <algorithm>

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

fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact) {
  return fitting::simulate(fit.model, fit.params, impact);
}

}  // namespace dropfit::pipeline
