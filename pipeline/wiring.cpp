#include "pipeline/wiring.h"

#include <fmt/format.h>

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

diagnosis::CalibrationDiagnosis choose_calibration(const Session& session) {
  if (!session.dlt_coefficients.empty()) {
    // A wand calibration's coefficients: nothing to choose; the frame's check
    // markers, when there is a frame, report its accuracy.
    diagnosis::CalibrationDiagnosis given;
    given.before = given.after = calibrate_session(session, calibration::CalibrationOptions{});
    given.notes.push_back("calibration: DLT coefficients given in the manifest; the camera model is not re-chosen");
    return given;
  }
  return diagnosis::diagnose_calibration(calibration_markers(session.frame), camera_views(session.images));
}

calibration::CalibrationResult calibrate_session(const Session& session,
                                                 const calibration::CalibrationOptions& options) {
  // Coefficients given in the manifest ([calibration] dlt_coefficients):
  // used as they are, checked on the frame's check markers when there is one.
  if (!session.dlt_coefficients.empty()) {
    std::vector<calibration::Camera> cameras;
    for (std::size_t c = 0; c < session.dlt_coefficients.size(); ++c) {
      calibration::Camera& camera = cameras.emplace_back();
      camera.name = session.manifest.video.cameras[c];
      camera.dlt = session.dlt_coefficients[c];
    }
    return calibration::given_calibration(cameras, calibration_markers(session.frame), camera_views(session.images));
  }
  try {
    return calibration::calibrate(calibration_markers(session.frame), camera_views(session.images), options);
  } catch (const InputError&) {
    throw;
  } catch (const Error& e) {
    // Geometry failures (too few points, a degenerate frame) name the files.
    throw Error(fmt::format("{}/calibration (frame.csv and the camera files): {}", session.root, e.what()));
  }
}

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result) {
  std::vector<calibration::Camera> cameras;
  for (const auto& fit : result.cameras) cameras.push_back(fit.camera);
  return cameras;
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
  options.mat_mass_kg = manifest.mat.mass_kg();
  return options;
}

forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record) {
  forceplate::ProcessOptions options;
  options.trigger_threshold_n = manifest.forceplate.trigger_threshold_n;
  options.pretrigger_fraction = manifest.forceplate.pretrigger_fraction.value_or(options.pretrigger_fraction);
  options.pretrigger_samples = record.pretrigger_samples > 0 ? record.pretrigger_samples : -1;
  options.sample_rate_hz = manifest.forceplate.sample_rate_hz;
  // A declared amplifier low-pass: its group delay is the plate's, not the clock's.
  options.lowpass_hz = manifest.forceplate.lowpass_hz;
  options.lowpass_order = manifest.forceplate.lowpass_order;
  return options;
}

forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record) {
  // A C3D's FORCE_PLATFORM:ORIGIN replaces the manifest's geometry.
  const Eigen::Vector3d g = record.plate_geometry_m.value_or(
      Eigen::Vector3d(manifest.forceplate.a_m, manifest.forceplate.b_m, manifest.forceplate.az0_m));
  if (record.layout == ForceLayout::EightChannel) {
    return forceplate::from_eight_channels(record.t_s, record.data, {g[0], g[1], g[2]});
  }
  return forceplate::from_resultant_columns(record.t_s, record.data, 50.0, g[2]);
}

TrialOutcome analyse_trial(const Manifest& manifest, const TrialRecording& trial,
                           const reconstruction::Trajectories& trajectories, const trial::TrialOptions& options) {
  TrialOutcome outcome;
  try {
    // A force record that cannot be converted or processed: the trial is
    // rejected with the reason; the video-only numbers are still measured.
    outcome.force = forceplate::process(raw_resultants(manifest, trial.force), force_options(manifest, trial.force));
  } catch (const Error& e) {
    outcome.result = trial::analyse_without_force(trajectories, options, e.what());
    return outcome;
  }
  outcome.result = trial::analyse(*outcome.force, trajectories, options);
  if (manifest.forceplate.lowpass_hz > 0.0) {
    outcome.result.force_lowpass_hz = manifest.forceplate.lowpass_hz;
    outcome.result.force_lowpass_source = "declared";
  }
  return outcome;
}

fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result) {
  fitting::TrialData data;
  data.id = result.id;
  data.accepted = result.accepted;
  data.impact_velocity_m_s = result.impact_velocity_m_s;
  data.impactor_mass_kg = manifest.impactor.mass_kg;
  data.gravity_m_s2 = manifest.gravity_m_s2;
  data.force_noise_n = result.force_noise_n;
  data.marker_noise_m = result.freefall_rms_m;
  // The inputs' error budget: the fit carries them as nuisance parameters.
  data.impact_velocity_se_m_s = result.impact_velocity_se_m_s;
  data.contact_time_se_s = result.video_contact_time_se_s;
  data.velocity_contact_time_cov = result.velocity_contact_time_cov;
  data.travel_reference_se_m = result.contact_height_se_m;
  data.calibration_scale_sd = result.calibration_scale_sd;
  const auto& s = result.series;
  // The surface markers' height at rest: their mean before contact. The
  // impactor's travel is already measured from the mat top the cameras see
  // (trial.h: contact height), which cancels the calibration's height error
  // near the mat.
  double rest_sum = 0.0;
  int rest_n = 0;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] < result.contact_time_s && std::isfinite(s.surface_z_m[i])) {
      rest_sum += s.surface_z_m[i];
      ++rest_n;
    }
  }
  const double surface_rest_m = rest_n > 0 ? rest_sum / rest_n : manifest.forceplate.mat_top_z_m;
  // From a little before the contact estimate: the fit places each trial's
  // contact on the force clock itself (fitting/fit.h).
  const double lead_s = 0.005;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] >= result.contact_time_s - lead_s) keep.push_back(i);
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

void apply_fitted_offset(trial::TrialResult& result, const fitting::FitResult& fit) {
  if (!std::isfinite(result.video_offset_s)) return;
  for (const auto& t : fit.trials) {
    if (t.id != result.id || !std::isfinite(t.contact_shift_se_s)) continue;
    result.video_offset_onset_s = result.video_offset_s;
    result.video_offset_s -= t.contact_shift_s;
    // The fitted contact's SE and the video contact instant's own.
    result.video_offset_se_s = std::isfinite(t.offset_se_s) ? t.offset_se_s : t.contact_shift_se_s;
  }
}

fitting::Model5Geometry model5_geometry(const Manifest& manifest) {
  fitting::Model5Geometry g;
  g.mat_length_m = manifest.mat.length_m;
  g.mat_width_m = manifest.mat.width_m;
  g.footprint_length_m = manifest.impactor.footprint_m.x();
  g.footprint_width_m = manifest.impactor.footprint_m.y();
  return g;
}

std::string predict_with_stiffness_scales(
    std::vector<fitting::TrialReport>& reports, const std::vector<fitting::TrialData>& data,
    const std::string& train_id, const std::function<double(const std::string& id)>& scale_of,
    const std::function<fitting::TrialReport(const fitting::TrialData& trial, double scale)>& predict,
    const std::string& scaled, std::vector<std::string>& notes) {
  const double train_scale = scale_of(train_id);
  std::string used;
  if (!std::isfinite(train_scale)) return used;
  for (fitting::TrialReport& rep : reports) {
    const double s = scale_of(rep.id) / train_scale;
    if (rep.train || !std::isfinite(s)) continue;
    for (const fitting::TrialData& d : data) {
      if (d.id != rep.id) continue;
      try {
        rep = predict(d, s);
        used += fmt::format("{}{} x{:.3f}", used.empty() ? "" : ", ", rep.id, s);
      } catch (const std::exception& e) {
        notes.push_back(fmt::format("trial {}: not predicted with its stiffness scale: {}", rep.id, e.what()));
      }
    }
  }
  if (used.empty()) return used;
  return fmt::format(
      "the mat changes between trials: the parameters are the training trial's ({}); each other trial is predicted "
      "with {} scaled as the recording-order trend fitted without it gives ({}); those predictions carry no interval",
      train_id, scaled, used);
}

}  // namespace dropfit::pipeline
