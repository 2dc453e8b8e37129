#include "cli/pipeline.h"

#include "report/results.h"

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

fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact) {
  return fitting::simulate(fit.model, fit.params, impact);
}

}  // namespace dropfit::pipeline
